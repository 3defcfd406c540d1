"""Fast numeric evaluation of CasADi functions: generated C compiled with gcc, cached.

:func:`compile_functions` turns a set of ``casadi.Function`` objects into
:class:`NumericFunction` callables. With a C compiler the functions are generated into one C
file, compiled to a shared library once (cached by the hash of the generated code under
``$CRS_CACHE_DIR``, default ``~/.cache/crs``), and called through ``ctypes`` with preallocated
buffers (a few microseconds per call). Without a compiler, or with ``CRS_CODEGEN=vm``, the same
functions run in CasADi's virtual machine. Both give the same numbers to rounding.

Callables are not thread-safe: each owns its work buffers.
"""

from __future__ import annotations

import ctypes
import fcntl
import hashlib
import os
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

import casadi as ca
import numpy as np

_CINT = ctypes.c_longlong  # matches the generated code's casadi_int

#: Options for every SX function that is evaluated numerically: common subexpression
#: elimination cuts the RK4 step with its Jacobian from about 20k to 12k instructions.
SX_OPTIONS = {"cse": True}


def cache_dir() -> Path:
    """Where compiled libraries are kept (``$CRS_CACHE_DIR`` or ``~/.cache/crs``)."""
    root = os.environ.get("CRS_CACHE_DIR") or Path.home() / ".cache" / "crs"
    return Path(root) / "codegen"


#: gcc flags of the generated code. -O1, not -O2: on this machine the MPCC's horizon
#: linearisation compiles in 6.5 s instead of 11.1 s, the MHE's in 3.6 s instead of 5.3 s, and
#: each runs within 6 % of its -O2 time (0.85 / 0.80 ms, 0.53 / 0.51 ms); the compiles are
#: most of a fresh clone's first run and of the test suite on a cold cache. -fno-ivopts: with
#: GCC 12's induction-variable optimisation at -O1, the MHE's compiled step for a model of
#: exactly 7 states lost every call of its triangular solve (the normal equations were factored
#: from unsolved blocks and every step failed); without it the step is the reference's at every
#: state count (tests/crs_core/estimation/test_mhe_native.py) and as fast within noise.
COMPILE_FLAGS = ("-O1", "-fno-ivopts", "-fPIC", "-shared")


class NumericFunction:
    """Call a CasADi function with numpy arrays; returns a tuple of numpy arrays.

    Every backend takes and returns the same shapes: each input is any array with the
    input's number of elements, read column-major (a matrix input such as an 8x8 covariance may
    come as that matrix or as its 64 column-major values); outputs come back with their CasADi
    shape (``(n,)`` for column vectors). Subclasses choose the backend.
    """

    def __init__(self, function: ca.Function) -> None:
        self.function = function
        self.name = function.name()
        self._in_shapes = [function.size_in(i) for i in range(function.n_in())]
        self._in_sizes = [function.numel_in(i) for i in range(function.n_in())]
        self._out_shapes = [
            (function.size1_out(i),) if function.size2_out(i) == 1 else function.size_out(i)
            for i in range(function.n_out())
        ]
        for i in range(function.n_in()):
            if not function.sparsity_in(i).is_dense():
                raise ValueError(f"{self.name}: input {i} must be dense")
        for i in range(function.n_out()):
            if not function.sparsity_out(i).is_dense():
                raise ValueError(f"{self.name}: output {i} must be dense (use casadi.densify)")

    backend = "abstract"

    def __call__(self, *args: np.ndarray | float) -> tuple[np.ndarray, ...]:
        raise NotImplementedError

    def _flat_inputs(self, args: Sequence[np.ndarray | float]) -> list[np.ndarray]:
        """Each argument as its column-major values, checked against the input's size."""
        if len(args) != len(self._in_sizes):
            raise TypeError(f"{self.name}: expected {len(self._in_sizes)} inputs, got {len(args)}")
        flats = []
        for value, size in zip(args, self._in_sizes, strict=True):
            flat = np.asarray(value, dtype=float).ravel(order="F")
            if flat.size != size:
                raise ValueError(f"{self.name}: input of size {flat.size}, expected {size}")
            flats.append(flat)
        return flats


class VMFunction(NumericFunction):
    """Evaluation in CasADi's virtual machine (no compiler needed)."""

    backend = "vm"

    def __call__(self, *args: np.ndarray | float) -> tuple[np.ndarray, ...]:
        # CasADi checks each input's shape: a column-major flat buffer (what the compiled code
        # takes) is reshaped back to the input's (rows, columns).
        inputs = [
            flat.reshape(shape, order="F")
            for flat, shape in zip(self._flat_inputs(args), self._in_shapes, strict=True)
        ]
        out = self.function.call(inputs)
        return tuple(
            np.asarray(o, dtype=float).reshape(shape, order="F")
            for o, shape in zip(out, self._out_shapes, strict=True)
        )


class CompiledFunction(NumericFunction):
    """Evaluation of the gcc-compiled generated code through ``ctypes``."""

    backend = "compiled"

    def __init__(self, function: ca.Function, library: ctypes.CDLL) -> None:
        super().__init__(function)
        #: the loaded shared object (kept loaded while the function lives)
        self.library = library
        entry = getattr(library, self.name)
        entry.restype = ctypes.c_int
        entry.argtypes = [ctypes.c_void_p] * 4 + [ctypes.c_int]
        self._entry = entry
        sizes = [_CINT() for _ in range(4)]
        getattr(library, f"{self.name}_work")(*[ctypes.byref(s) for s in sizes])
        n_arg, n_res, n_iw, n_w = (s.value for s in sizes)
        self._inputs = [np.zeros(n) for n in self._in_sizes]
        self._outputs = [np.zeros(int(np.prod(shape))) for shape in self._out_shapes]
        self._iw = np.zeros(max(n_iw, 1), dtype=np.int64)
        self._w = np.zeros(max(n_w, 1))
        arg = (ctypes.c_void_p * max(n_arg, 1))()
        res = (ctypes.c_void_p * max(n_res, 1))()
        for i, buf in enumerate(self._inputs):
            arg[i] = buf.ctypes.data
        for i, buf in enumerate(self._outputs):
            res[i] = buf.ctypes.data
        self._arg, self._res = arg, res
        self._iw_ptr, self._w_ptr = self._iw.ctypes.data, self._w.ctypes.data
        getattr(library, f"{self.name}_incref")()

    def __call__(self, *args: np.ndarray | float) -> tuple[np.ndarray, ...]:
        for buf, flat in zip(self._inputs, self._flat_inputs(args), strict=True):
            buf[:] = flat
        if self._entry(self._arg, self._res, self._iw_ptr, self._w_ptr, 0) != 0:
            raise RuntimeError(f"{self.name}: evaluation failed")
        return tuple(
            buf.reshape(shape, order="F").copy()
            for buf, shape in zip(self._outputs, self._out_shapes, strict=True)
        )


def compiler_available() -> bool:
    return shutil.which(os.environ.get("CC", "gcc")) is not None


def _backend(backend: str | None) -> str:
    """``backend``, else ``$CRS_CODEGEN``, else ``compiled`` when a compiler exists (``vm``
    otherwise); ``ValueError`` for anything but ``compiled`` or ``vm``."""
    backend = (
        backend or os.environ.get("CRS_CODEGEN") or ("compiled" if compiler_available() else "vm")
    )
    if backend not in ("compiled", "vm"):
        raise ValueError(f"backend must be 'compiled' or 'vm', got {backend!r}")
    return backend


def compile_functions(
    functions: Sequence[ca.Function],
    library_name: str,
    backend: str | None = None,
    driver: str = "",
    arguments: Sequence[str] = (),
) -> dict[str, NumericFunction]:
    """Numeric callables for ``functions``, keyed by function name.

    Parameters
    ----------
    functions : sequence of casadi.Function
        SX or MX functions with dense outputs.
    library_name : str
        Stem of the generated C file (a valid C identifier).
    backend : {"compiled", "vm", None}
        ``None`` picks ``$CRS_CODEGEN`` if set, else ``compiled`` when a compiler exists.
    driver : str
        C that calls the generated functions, compiled into the same library (reached through
        :attr:`CompiledFunction.library`; unused in the VM): one compile, not a second library
        of the same generated code.
    arguments : sequence of str
        Compiler arguments added to :data:`COMPILE_FLAGS` (include and link flags a driver
        needs); its undefined symbols come from libraries already loaded into the global scope.

    Raises
    ------
    RuntimeError
        The compiled backend was asked for and there is no compiler, or it failed.
    """
    if _backend(backend) == "vm":
        return {f.name(): VMFunction(f) for f in functions}
    if not compiler_available():
        raise RuntimeError("no C compiler (set CC or install gcc)")
    flags = (*COMPILE_FLAGS, *arguments)
    library = ctypes.CDLL(str(_build_library(functions, library_name, flags, driver)))
    return {f.name(): CompiledFunction(f, library) for f in functions}


def external_functions(
    functions: Sequence[ca.Function], library_name: str, backend: str | None = None
) -> dict[str, ca.Function]:
    """CasADi functions that run the gcc-compiled code of ``functions`` (``casadi.external``),
    to be embedded in a larger CasADi graph (such as one around a QP solver); without a
    compiler (or with ``backend="vm"`` / ``CRS_CODEGEN=vm``) the functions themselves.
    Outputs may be sparse. Keyed by function name."""
    if _backend(backend) == "vm":
        return {f.name(): f for f in functions}
    path = _build_library(functions, library_name, COMPILE_FLAGS)
    return {f.name(): ca.external(f.name(), str(path)) for f in functions}


def _build_library(
    functions: Sequence[ca.Function], library_name: str, flags: Sequence[str], driver: str = ""
) -> Path:
    with tempfile.TemporaryDirectory() as scratch:
        generator = ca.CodeGenerator(
            f"{library_name}.c", {"with_header": False, "casadi_int": "long long int"}
        )
        for f in functions:
            generator.add(f)
        generator.generate(scratch + os.sep)
        source = Path(scratch, f"{library_name}.c").read_text() + driver
    digest = hashlib.sha256((source + " ".join(flags)).encode()).hexdigest()[:20]
    target = cache_dir() / f"{library_name}_{digest}.so"
    if target.exists():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    # one builder per library: a process that finds another compiling it waits and loads its
    # result (the test suite's workers and a launch's nodes ask for the same libraries)
    with open(target.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not target.exists():
            _compile(source, library_name, target, flags)
    return target


def _compile(source: str, library_name: str, target: Path, flags: Sequence[str]) -> None:
    with tempfile.TemporaryDirectory(dir=target.parent) as build:
        c_file = Path(build, f"{library_name}.c")
        c_file.write_text(source)
        built = Path(build, target.name)
        compiler = os.environ.get("CC", "gcc")
        result = subprocess.run(
            [compiler, *flags, str(c_file), "-o", str(built), "-lm"],
            capture_output=True,
            text=True,
            check=False,
        )
        if result.returncode != 0:
            raise RuntimeError(f"compiling {library_name} failed:\n{result.stderr[-2000:]}")
        os.replace(built, target)  # atomic: a reader never sees a half-written library
