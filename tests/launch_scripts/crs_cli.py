"""The ``crs`` command line run in the test's process, and its refusal contract: shared by the
command-line tests (fixtures ``crs`` and ``crs_refuses`` in ``conftest.py``) and by the tests of
other packages that have a ``crs`` command (``crs car-emulator``)."""

from __future__ import annotations

import contextlib
import io

from launch_scripts.cli import main


def run_crs(argv: list[str]) -> tuple[int, str, str]:
    """``crs ARGV`` in this process, as the console script runs it: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, out.getvalue(), err.getvalue()


def refused(argv: list[str]) -> str:
    """What ``crs ARGV`` prints when it refuses its input: exit code 2 and one line on stderr,
    ``crs COMMAND: error: ...`` without a traceback (asserted); that line."""
    code, _, err = run_crs(argv)
    assert code == 2, err
    assert err.startswith(f"crs {argv[0]}: error: "), err
    assert err.count("\n") == 1 and err.endswith("\n") and "Traceback" not in err, err
    return err
