"""Output folders that never lose a user's files.

Every ``crs`` command that writes a folder (``--out``) goes through :func:`prepare_output` before
it starts any work:

* a folder that does not exist, or is empty, is created and marked as ours (a ``.crs-output``
  file naming the command);
* a folder we made earlier is refused unless ``--overwrite`` is given; then its contents (ours)
  are removed first, so no stale file of an earlier run stays beside the new ones;
* a folder holding anything else, or a path that is a file, is refused: the user's files are
  never touched.

``./run.sh`` applies the same rule to ``$OUT`` (``is_ours`` from the shell).
"""

from __future__ import annotations

import shutil
from pathlib import Path

MARKER = ".crs-output"


def is_ours(path: Path) -> bool:
    """Whether ``path`` is a folder a ``crs`` command made (it holds the marker)."""
    return (path / MARKER).is_file()


def prepare_output(
    path: Path, command: str, overwrite: bool = False, option: str = "--out"
) -> Path:
    """Create ``path`` fresh for ``command``; ``ValueError`` naming ``option`` when refused."""
    path = Path(path)
    if str(path).strip() == "":
        raise ValueError(f"{option}: must name a folder, got an empty string")
    if path.exists() and not path.is_dir():
        raise ValueError(f"{option}: {path} is a file, not a folder")
    if path.is_dir() and any(path.iterdir()):
        if not is_ours(path):
            raise ValueError(
                f"{option}: {path} holds files that crs did not write; choose an empty or new "
                "folder (nothing was changed)"
            )
        if not overwrite:
            raise ValueError(
                f"{option}: {path} holds the output of an earlier crs run; pass --overwrite to "
                "replace it (nothing was changed)"
            )
        for entry in path.iterdir():
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
    try:
        path.mkdir(parents=True, exist_ok=True)
        (path / MARKER).write_text(f"written by crs {command}\n")
    except OSError as error:
        raise ValueError(f"{option}: cannot write to {path} ({error.strerror or error})") from None
    return path


def prepare_output_file(path: Path, overwrite: bool = False, option: str = "--out") -> Path:
    """Check, before any work, that the file ``path`` can be written: its folder is created;
    an existing file is replaced only with ``overwrite``; ``ValueError`` naming ``option``. A
    new file is not left behind (a run that fails later leaves no empty file that the next run
    would then refuse)."""
    path = Path(path)
    if str(path).strip() == "":
        raise ValueError(f"{option}: must name a file, got an empty string")
    if path.is_dir():
        raise ValueError(f"{option}: {path} is a folder; name a file, e.g. {path / 'out.json'}")
    if path.exists() and not overwrite:
        raise ValueError(f"{option}: {path} exists; pass --overwrite to replace it")
    existed = path.exists()
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("a"):
            pass
        if not existed:
            path.unlink()
    except OSError as error:
        raise ValueError(f"{option}: cannot write to {path} ({error.strerror or error})") from None
    return path
