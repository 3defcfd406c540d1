"""acados from the ``comma-deps-acados`` wheel: load it, and where its generated solvers live.

acados (SQP-RTI with HPIPM, the solver the CRS paper's stack uses) is the peer the MHE and the
MPCC are measured against. ``./run.sh``'s set-up installs the wheel into a folder of its own
(``.venv/acados``, on the path through a ``.pth`` file) with the wheel's slimmed casadi removed,
so the pinned casadi is never touched. :func:`acados_template` sets the variables acados's code
generator reads and loads its shared libraries (they carry no RPATH) before importing its
Python interface; :func:`solver_dir` is a folder per problem in the compile cache, so a solver
is generated and compiled once.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import io
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType
from typing import Any

from crs_core.codegen import cache_dir

__all__ = ["AcadosUnavailable", "acados_template", "build_or_load", "solver_dir"]

#: The libraries of the wheel, in the order their dependencies need.
_LIBRARIES = ("libblasfeo.so", "libhpipm.so", "libqpOASES_e.so.3.1", "libacados.so")
_loaded: list[ctypes.CDLL] = []


class AcadosUnavailable(RuntimeError):  # noqa: N818 (reads as the condition it names)
    """acados is not installed (run ``./run.sh setup``) or cannot be loaded."""


def acados_template() -> ModuleType:
    """acados's Python interface (``acados.acados_template``), ready to build solvers.

    Raises
    ------
    AcadosUnavailable
        The wheel is not installed or its libraries do not load.
    """
    try:
        import acados
    except ImportError as error:
        raise AcadosUnavailable(
            "acados is not installed: ./run.sh setup installs comma-deps-acados into .venv/acados"
        ) from error
    os.environ.setdefault("ACADOS_SOURCE_DIR", acados.DIR)
    os.environ.setdefault("ACADOS_PYTHON_INTERFACE_PATH", acados.TEMPLATE_DIR)
    os.environ.setdefault("TERA_PATH", acados.TERA_PATH)
    if not _loaded:
        _load_casadi_hpipm_first()
        try:
            for name in _LIBRARIES:
                path = os.path.join(acados.LIB_DIR, name)
                _loaded.append(ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL))
        except OSError as error:
            raise AcadosUnavailable(f"acados's libraries do not load: {error}") from error
    from acados import acados_template as template

    return template


def _load_casadi_hpipm_first() -> None:
    """Load CasADi's HPIPM plugin (with its own ``libhpipm.so``) before acados's libraries.

    Both wheels ship a ``libhpipm.so`` with that SONAME, of different HPIPM versions. The
    dynamic linker gives a library that needs ``libhpipm.so`` the first one loaded: with
    acados's loaded first, CasADi's ``conic("hpipm")`` (the MPCC's QP solver) ran on acados's
    HPIPM and crashed the process (segmentation fault). Loaded first, CasADi's plugin keeps
    its own HPIPM, and acados, whose libraries are loaded by path, keeps its own (checked with
    ``LD_DEBUG=bindings``)."""
    import casadi

    # has_conic loads the plugin (once; load_conic would warn on a second load); a casadi
    # without it has nothing to protect
    with contextlib.suppress(Exception):
        casadi.has_conic("hpipm")


def solver_dir(name: str) -> Path:
    """The folder of acados solver ``name`` in the compile cache (created)."""
    folder = cache_dir() / "acados" / name
    folder.mkdir(parents=True, exist_ok=True)
    return folder


@contextlib.contextmanager
def _output_to(log: Path) -> Iterator[None]:
    """The process's stdout and stderr (file descriptors 1 and 2: Python's prints,
    ``t_renderer``, ``make``, gcc) into ``log`` for the duration: acados's code generation and
    build talk a lot."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    try:
        with open(log, "w") as handle:
            os.dup2(handle.fileno(), 1)
            os.dup2(handle.fileno(), 2)
            with contextlib.redirect_stdout(handle), contextlib.redirect_stderr(handle):
                yield
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        for fd, copy in zip((1, 2), saved, strict=True):
            os.dup2(copy, fd)
            os.close(copy)


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """Hold an exclusive lock on ``folder`` (processes building the same solver wait)."""
    with open(folder / ".lock", "w") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def build_or_load(ocp: Any, name: str, helper: str | None = None) -> tuple[Any, ctypes.CDLL | None]:
    """acados's OCP solver for ``ocp``, generated and compiled once into ``solver_dir(name)``.

    The first call (per ``name``, across processes: a lock serialises them) generates the
    code, builds the solver's library and, with ``helper`` (C source; ``{name}`` stands for
    the model's name), compiles it into a second library beside it, linked to the solver's;
    a later call loads what is there (``AcadosOcpSolver(..., build=False, generate=False)``,
    milliseconds). ``name`` must change whenever the problem does (e.g. carry a hash of its
    expressions and options): an existing build is reused as it is.

    Returns
    -------
    solver : acados_template.AcadosOcpSolver
        The solver (``ocp.model.name`` and ``ocp.code_export_directory`` are set to ``name``
        and the cache folder).
    helper : ctypes.CDLL or None
        The helper's library (loaded), or None without one.

    Raises
    ------
    AcadosUnavailable
        acados is missing, or the build failed (acados's ``build()`` ignores ``make``'s exit
        status: a missing library is how a compile error shows).
    """
    template = acados_template()
    folder = solver_dir(name)
    code = folder / "c_generated_code"
    json_file = folder / "acados_ocp.json"
    library = code / f"libacados_ocp_solver_{name}.so"
    helper_library = code / f"lib{name}_helper.so"
    done = folder / "built"
    ocp.model.name = name
    ocp.code_export_directory = str(code)
    with _locked(folder):
        if not done.exists():
            log = folder / "build.log"
            with _output_to(log):
                template.AcadosOcpSolver.generate(ocp, json_file=str(json_file))
                template.AcadosOcpSolver.build(str(code), verbose=True)
            if not library.exists():
                raise AcadosUnavailable(f"acados: building {name} failed (see {log})")
            if helper is not None:
                _compile_helper(helper.replace("{name}", name), code, name, helper_library)
            done.write_text("ok\n")
        with contextlib.redirect_stdout(io.StringIO()):  # "compiled without OpenMP"
            solver = template.AcadosOcpSolver(
                ocp, json_file=str(json_file), build=False, generate=False, verbose=False
            )
    loaded = ctypes.CDLL(str(helper_library)) if helper is not None else None
    return solver, loaded


def _compile_helper(source: str, code: Path, name: str, target: Path) -> None:
    import acados

    include = Path(acados.INCLUDE_DIR)
    path = code / f"{name}_helper.c"
    path.write_text(source)
    command = [
        "gcc",
        "-O2",
        "-fPIC",
        "-shared",
        str(path),
        "-o",
        str(target),
        f"-I{include}",
        f"-I{include / 'blasfeo' / 'include'}",
        f"-I{include / 'hpipm' / 'include'}",
        f"-I{code}",
        f"-L{code}",
        f"-lacados_ocp_solver_{name}",
        f"-Wl,-rpath,{code}",
        f"-L{acados.LIB_DIR}",
        f"-Wl,-rpath,{acados.LIB_DIR}",
        "-lacados",
    ]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        raise AcadosUnavailable(f"acados: compiling {path} failed:\n{result.stderr}")
