"""Compiled C and CasADi VM evaluations of the one model definition agree."""

import time

import numpy as np
import pytest

from crs_core.codegen import compile_functions
from crs_core.model import CarModel
from crs_core.model.car_model import NumericModel


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
    start = time.perf_counter()
    compile_functions(functions, "cache_probe", "compiled")
    assert time.perf_counter() - start < 0.5
    assert built[0].stat().st_mtime_ns == mtime


def test_wrong_input_size_is_rejected(models):
    """Calling with a wrongly sized input raises an error naming the function."""
    compiled, _, _ = models
    with pytest.raises(ValueError, match="f: input of size 3"):
        compiled.functions["f"](np.zeros(3), np.zeros(2), np.zeros(1))
