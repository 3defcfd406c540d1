"""Output folders never lose a user's files: created fresh, ours replaced only on request."""

import os
import subprocess
from pathlib import Path

import pytest

from launch_scripts.cli import main
from launch_scripts.output_folder import MARKER, prepare_output

ROOT = Path(__file__).resolve().parents[2]


def test_a_new_or_empty_folder_is_created_and_marked(tmp_path: Path):
    empty = tmp_path / "empty"
    empty.mkdir()
    for path in (tmp_path / "new" / "deeper", empty):
        prepare_output(path, "sim")
        assert (path / MARKER).is_file()


@pytest.mark.parametrize(
    ("setup", "overwrite", "message"),
    [
        ("foreign", False, "holds files that crs did not write"),
        ("foreign", True, "holds files that crs did not write"),
        ("ours", False, "pass --overwrite to replace it"),
        ("file", False, "is a file, not a folder"),
    ],
)
def test_refusals_change_nothing(tmp_path: Path, setup: str, overwrite: bool, message: str):
    target = tmp_path / "out"
    if setup == "file":
        target.write_text("my notes")
    else:
        target.mkdir()
        (target / "thesis.tex").write_text("my thesis")
        if setup == "ours":
            (target / MARKER).write_text("written by crs sim\n")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    with pytest.raises(ValueError, match=f"--out: .*{message}"):
        prepare_output(target, "sim", overwrite)
    assert sorted(p.name for p in tmp_path.rglob("*")) == before
    if setup != "file":
        assert (target / "thesis.tex").read_text() == "my thesis"


def test_overwrite_replaces_only_our_own_folder_completely(tmp_path: Path):
    target = tmp_path / "out"
    prepare_output(target, "sim")
    (target / "report").mkdir()
    (target / "report" / "stale.png").write_bytes(b"old")
    prepare_output(target, "sim", overwrite=True)
    assert sorted(p.name for p in target.iterdir()) == [MARKER]


def test_crs_sim_refuses_a_second_run_into_the_same_folder_unless_asked(
    tmp_path: Path, crs_refuses
):
    """The second ``crs sim --out`` is refused (one line, exit 2, nothing changed); with
    ``--overwrite`` the old report does not stay beside the new dataset."""
    out = tmp_path / "run"
    assert main(["sim", "--duration", "1", "--out", str(out), "--report"]) == 0
    assert (out / "report").is_dir()
    err = crs_refuses(["sim", "--duration", "1", "--out", str(out)])
    assert err.startswith(f"crs sim: error: --out: {out} holds the output of an earlier crs run")
    assert (out / "report").is_dir()
    assert main(["sim", "--duration", "1", "--out", str(out), "--overwrite", "--no-report"]) == 0
    assert not (out / "report").exists() and (out / "t.npy").is_file()


def test_crs_sim_never_writes_into_a_folder_of_the_user(tmp_path: Path, capsys):
    (tmp_path / "mine.txt").write_text("keep me")
    assert main(["sim", "--duration", "1", "--out", str(tmp_path), "--overwrite"]) == 2
    assert "holds files that crs did not write" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt"]


def test_run_sh_leaves_a_foreign_file_in_out(tmp_path: Path):
    """``OUT=folder ./run.sh`` with a user's file in the folder refuses and keeps the file
    (it used to ``rm -rf "$OUT"``)."""
    (tmp_path / "mine.txt").write_text("keep me")
    env = {"PATH": "/usr/bin:/bin", "OUT": str(tmp_path), "HOME": str(tmp_path)}
    # the suite's compile cache (run.sh compiles into it before it looks at OUT): without it a
    # CRS_CACHE_DIR elsewhere leaves ROOT/.cache/crs cold and this run compiles for ~15 s
    if "CRS_CACHE_DIR" in os.environ:
        env["CRS_CACHE_DIR"] = os.environ["CRS_CACHE_DIR"]
    result = subprocess.run(
        [str(ROOT / "run.sh")],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert result.returncode == 2, result.stderr
    assert "holds files that crs did not write" in result.stderr
    assert (tmp_path / "mine.txt").read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt"]


@pytest.mark.parametrize(
    ("setup", "overwrite", "message"),
    [
        ("exists", False, "exists; pass --overwrite to replace it"),
        ("folder", False, "is a folder; name a file"),
        ("under_file", True, "cannot write to"),
    ],
)
def test_json_outputs_are_checked_before_any_work(
    tmp_path: Path, setup: str, overwrite: bool, message: str, crs_refuses
):
    """``crs consistency --out`` (and ``crs bench``) refuse a bad --out before running, one
    line, exit code 2; an existing file is left as it was."""
    target = {"exists": tmp_path / "mine.json", "folder": tmp_path, "under_file": None}[setup]
    if setup == "exists":
        target.write_text("my numbers")
    if setup == "under_file":
        (tmp_path / "file").write_text("")
        target = tmp_path / "file" / "out.json"
    argv = ["consistency", "--out", str(target)] + (["--overwrite"] if overwrite else [])
    err = crs_refuses(argv)
    assert err.startswith("crs consistency: error: --out: ") and message in err, err
    if setup == "exists":
        assert target.read_text() == "my numbers"


def test_a_checked_json_output_leaves_no_file_behind(tmp_path: Path):
    """The check writes nothing: a run that fails after it leaves no empty file (which the next
    run would refuse without --overwrite)."""
    from launch_scripts.output_folder import prepare_output_file

    target = tmp_path / "new" / "out.json"
    assert prepare_output_file(target) == target
    assert target.parent.is_dir() and not target.exists()
    prepare_output_file(target)  # and again: nothing there to refuse
