"""Tests of crs_core.codegen: the compiled C and the CasADi VM evaluations of the one model
definition agree, take and return the same shapes and give the same estimates
(``CRS_CODEGEN=vm`` is the fallback where no compiler exists); the library is cached."""

from __future__ import annotations

import multiprocessing
import os

import casadi as ca
import numpy as np
import pytest

from crs_core import codegen
from crs_core.codegen import compile_functions, compiler_available
from crs_core.dataset import Dataset
from crs_core.estimation.offline import estimate_dataset
from crs_core.model import CarModel
from crs_core.model.car_model import NumericModel
from sim.scenarios import standard_drive

needs_compiler = pytest.mark.skipif(not compiler_available(), reason="no C compiler")

#: Seconds of the simulated drive the estimators run over.
DURATION = 3.0


@pytest.fixture(scope="module")
def models():
    model = CarModel(["steering_lag", "gyro_bias"], n_base_stations=2)
    return NumericModel(model, backend="compiled"), NumericModel(model, backend="vm"), model


def test_compiled_matches_vm(models):
    """f, RK4 step, sensor outputs and applied input agree to 1e-12 on random points."""
    compiled, vm, model = models
    assert compiled.backend == "compiled" and vm.backend == "vm"
    rng = np.random.default_rng(3)
    p = model.parameters.vector()
    for _ in range(50):
        x = rng.normal(size=model.nx) * [1, 1, 3, 1, 0.2, 2, 0.3]
        u = rng.uniform([-0.34, 0], [0.34, 1])
        np.testing.assert_allclose(compiled.f(x, u, p), vm.f(x, u, p), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(
            compiled.step(x, u, p, 0.013), vm.step(x, u, p, 0.013), rtol=1e-12, atol=1e-12
        )
        yc, yv = compiled.outputs(x, u, p), vm.outputs(x, u, p)
        for name in yc:
            np.testing.assert_allclose(yc[name], yv[name], rtol=1e-12, atol=1e-12)


def test_library_is_cached(models, tmp_path, monkeypatch):
    """A second build of the same functions reuses the cached shared object."""
    monkeypatch.setenv("CRS_CACHE_DIR", str(tmp_path))
    functions = [models[2].dynamics_function]
    compile_functions(functions, "cache_probe", "compiled")
    built = list((tmp_path / "codegen").glob("cache_probe_*.so"))
    assert len(built) == 1
    mtime = built[0].stat().st_mtime_ns
    compile_functions(functions, "cache_probe", "compiled")
    assert built[0].stat().st_mtime_ns == mtime


def _build_probe(cache: str) -> None:
    os.environ["CRS_CACHE_DIR"] = cache
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u")
    compile_functions([ca.Function("probe", [x, u], [ca.sin(x) * u])], "lock_probe", "compiled")


@needs_compiler
def test_processes_asking_for_one_library_at_once_compile_it_once(tmp_path, monkeypatch):
    """Four processes build the same library at the same moment: the compiler runs once (the
    others wait for it and load its result)."""
    log = tmp_path / "compiles.log"
    wrapper = tmp_path / "cc.sh"
    wrapper.write_text(f'#!/bin/sh\necho run >> "{log}"\nsleep 0.5\nexec gcc "$@"\n')
    wrapper.chmod(0o755)
    monkeypatch.setenv("CC", str(wrapper))
    context = multiprocessing.get_context("fork")
    processes = [context.Process(target=_build_probe, args=(str(tmp_path),)) for _ in range(4)]
    for process in processes:
        process.start()
    for process in processes:
        process.join(60)
        assert process.exitcode == 0
    assert log.read_text().splitlines() == ["run"]
    assert len(list((tmp_path / "codegen").glob("lock_probe_*.so"))) == 1


def test_wrong_input_size_is_rejected(models):
    """Calling with a wrongly sized input raises an error naming the function."""
    compiled, _, _ = models
    with pytest.raises(ValueError, match="f: input of size 3"):
        compiled.functions["f"](np.zeros(3), np.zeros(2), np.zeros(1))


def _matrix_function() -> ca.Function:
    """``g(P (3x2), v (2), s) -> (s P v (3,), P^T (2x3))``: matrix inputs and outputs."""
    P, v, s = ca.SX.sym("P", 3, 2), ca.SX.sym("v", 2), ca.SX.sym("s")
    return ca.Function("g", [P, v, s], [s * (P @ v), P.T], ["P", "v", "s"], ["Pv", "Pt"])


@needs_compiler
@pytest.mark.parametrize("backend", ["compiled", "vm"])
def test_matrix_inputs_as_matrix_or_column_major_values(backend, tmp_path, monkeypatch):
    """A 3x2 input is accepted as the matrix or as its 6 column-major values; outputs keep
    their CasADi shape; a wrong size or count is refused with the function's name."""
    monkeypatch.setenv("CRS_CACHE_DIR", str(tmp_path))
    g = compile_functions([_matrix_function()], "backend_probe", backend)["g"]
    assert g.backend == backend
    P = np.arange(6.0).reshape(3, 2)
    v = np.array([1.0, -2.0])
    for matrix in (P, P.ravel(order="F")):
        Pv, Pt = g(matrix, v, 0.5)
        assert Pv.shape == (3,) and Pt.shape == (2, 3)
        np.testing.assert_array_equal(Pv, 0.5 * P @ v)
        np.testing.assert_array_equal(Pt, P.T)
    with pytest.raises(ValueError, match="g: input of size 5, expected 6"):
        g(np.zeros(5), v, 1.0)
    with pytest.raises(TypeError, match="g: expected 3 inputs, got 2"):
        g(P, v)


@pytest.fixture(scope="module")
def drive() -> Dataset:
    """A few seconds of the standard joystick drive (default sensor noise) with its stream."""
    return standard_drive(5, DURATION).to_dataset()


@needs_compiler
@pytest.mark.parametrize("kind", ["ekf", "mhe"])
def test_estimators_agree_on_both_backends(kind, drive, monkeypatch):
    """The EKF and the MHE (blind start: Lighthouse pose solver too) give the same estimates,
    covariances and statuses with the compiled code and in the VM, which does run."""
    calls = {"vm": 0}
    vm_call = codegen.VMFunction.__call__

    def counted(self, *args):
        calls["vm"] += 1
        return vm_call(self, *args)

    monkeypatch.setattr(codegen.VMFunction, "__call__", counted)
    results = {}
    for backend in ("compiled", "vm"):
        monkeypatch.setenv("CRS_CODEGEN", backend)  # read when the functions are built
        before = calls["vm"]
        results[backend] = estimate_dataset(drive, kind, "lh+imu+we")
        ran_in_vm = calls["vm"] > before
        assert ran_in_vm == (backend == "vm")
    compiled, vm = results["compiled"], results["vm"]
    assert (compiled.status != "lost").sum() > 0.8 * drive.t.size
    np.testing.assert_array_equal(vm.status, compiled.status)
    np.testing.assert_allclose(vm.x, compiled.x, rtol=0.0, atol=1e-9)
    np.testing.assert_allclose(vm.covariance_diag, compiled.covariance_diag, rtol=1e-9, atol=1e-12)
