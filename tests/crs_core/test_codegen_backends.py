"""The compiled C and the CasADi VM back-ends of crs_core.codegen take and return the same shapes
and give the same estimates (``CRS_CODEGEN=vm`` is the fallback where no compiler exists)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from crs_core import codegen
from crs_core.codegen import compile_functions, compiler_available
from crs_core.dataset import Dataset
from crs_core.estimation.offline import estimate_dataset
from sim.scenarios import standard_drive

needs_compiler = pytest.mark.skipif(not compiler_available(), reason="no C compiler")

#: Seconds of the simulated drive the estimators run over.
DURATION = 3.0


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
