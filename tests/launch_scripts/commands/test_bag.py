"""``crs bag check|repair`` on a complete and a cut-off bag, and its one-line errors."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
from rosbags.rosbag2 import Reader, StoragePlugin, Writer

from launch_scripts.cli import main
from ros4crs.interfaces import typestore

#: Messages in the test bag; large String payloads so that it spans several MCAP chunks.
MESSAGES = 60


def _write_bag(path: Path) -> None:
    store = typestore()
    string = store.types["std_msgs/msg/String"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/car1/note", "std_msgs/msg/String", typestore=store)
        for i in range(MESSAGES):
            data = store.serialize_cdr(string(data=f"{i:04d}" + "x" * 40_000), connection.msgtype)
            writer.write(connection, 1_000_000_000 + i * 10_000_000, data)


@pytest.fixture
def cut_bag(tmp_path: Path) -> Path:
    """A bag whose MCAP file lost its second half (and its metadata.yaml): a killed recorder."""
    bag = tmp_path / "bag"
    _write_bag(bag)
    (mcap,) = bag.glob("*.mcap")
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    (bag / "metadata.yaml").unlink()
    return bag


def _digest(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.iterdir()}


def test_check_a_complete_bag_exits_0(tmp_path: Path, capsys: pytest.CaptureFixture):
    bag = tmp_path / "bag"
    _write_bag(bag)
    assert main(["bag", "check", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "complete" in out and f"/car1/note: {MESSAGES}" in out


def test_check_a_cut_bag_says_what_was_lost_and_exits_1(
    cut_bag: Path, capsys: pytest.CaptureFixture
):
    before = _digest(cut_bag)
    assert main(["bag", "check", str(cut_bag)]) == 1
    out = capsys.readouterr().out
    assert "damaged" in out and "is cut off: read" in out and "metadata.yaml is missing" in out
    assert _digest(cut_bag) == before  # only read


def test_repair_writes_a_complete_prefix_and_leaves_the_original(
    cut_bag: Path, tmp_path: Path, capsys: pytest.CaptureFixture
):
    before = _digest(cut_bag)
    fixed = tmp_path / "fixed"
    assert main(["bag", "repair", str(cut_bag), "--out", str(fixed)]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith("warning: bag.mcap is cut off") and f"wrote {fixed}" in printed
    store = typestore()
    with Reader(fixed) as reader:  # rosbags opens it as it is
        texts = [
            store.deserialize_cdr(bytes(data), c.msgtype).data[:4]
            for c, _, data in reader.messages()
        ]
    assert 0 < len(texts) < MESSAGES
    assert texts == [f"{i:04d}" for i in range(len(texts))]  # a prefix, in order
    assert _digest(cut_bag) == before


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["bag", "check", "{tmp}/missing"], "crs bag: error: {tmp}/missing: not a bag folder"),
        (["bag", "check", "{tmp}/junk"], "crs bag: error: {tmp}/junk"),
        (["bag", "repair", "{tmp}/bag"], "crs bag: error: --out: repair needs --out NEW_BAG"),
        (["bag", "repair", "{tmp}/bag", "--out", "{tmp}/junk"], "--out: {tmp}/junk exists"),
        (["bag", "lint", "{tmp}/bag"], "crs bag: error: argument tool: invalid choice: 'lint'"),
        (["launch", "sim", "--record", "some"], "argument --record: invalid choice: 'some'"),
    ],
)
def test_bad_bag_arguments_are_one_line_errors_and_change_nothing(
    argv: list[str], message: str, tmp_path: Path, crs_refuses
):
    _write_bag(tmp_path / "bag")
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "notes.txt").write_text("not a bag")
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    argv = [a.format(tmp=tmp_path) for a in argv]
    if argv[0] == "launch":
        argv += ["--out", str(tmp_path / "out")]
    assert message.format(tmp=tmp_path) in crs_refuses(argv)
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before


def test_an_mcap_file_is_checked_and_repaired(cut_bag: Path, tmp_path: Path, capsys):
    """The .mcap file alone, as ros2 bag and Foxglove take it: complete it exits 0; cut off, 1,
    and the repair is a complete bag folder."""
    whole = tmp_path / "whole"
    _write_bag(whole)
    assert main(["bag", "check", str(next(whole.glob("*.mcap")))]) == 0
    assert f"/car1/note: {MESSAGES}" in capsys.readouterr().out
    (cut,) = cut_bag.glob("*.mcap")
    assert main(["bag", "check", str(cut)]) == 1
    assert main(["bag", "repair", str(cut), "--out", str(tmp_path / "repaired")]) == 0
    with Reader(tmp_path / "repaired") as reader:
        assert 0 < reader.message_count < MESSAGES
