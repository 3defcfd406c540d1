"""The FIE's assembled Jacobian against CasADi's automatic Jacobian of the same residual."""

from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from crs_core.dataset import Dataset
from crs_core.identification import FieData, FieProblem, FieSettings
from crs_core.model import CarModel
from sim.scenarios import simulate_dataset

REAL_RUN = Path(__file__).parents[3] / ".." / "shared" / "data" / "chronos_real"


def _compare(dataset: Dataset, model: CarModel, fit: tuple[str, ...]) -> None:
    settings = FieSettings(fit=fit)
    data = FieData.from_dataset(dataset, settings.noise)
    problem = FieProblem(model, data, settings, np.zeros(model.nx))
    rng = np.random.default_rng(3)
    z = rng.standard_normal(problem.nz) * 0.3
    z[problem.n_theta :] += np.tile(
        np.r_[0.0, 0.0, 0.2, 1.2, 0.0, 0.5, np.zeros(model.nx - 6)], problem.n
    )
    automatic = ca.Function("ad", [problem.z_sym], [ca.jacobian(problem.residual, problem.z_sym)])
    expected = automatic(z).sparse()
    assembled = problem.jacobian_function()(z).sparse()
    assert assembled.shape == expected.shape == (problem.residual.numel(), problem.nz)
    scale = abs(expected).max()
    assert abs(assembled - expected).max() <= 1e-12 * scale


@pytest.mark.parametrize("effect", [None, "steering_lag", "gyro_scale", "lighthouse_offset"])
def test_matches_automatic_differentiation_with_commands_and_sweep_lag(effect):
    """Simulated data: several held commands per interval and plane-1 sweeps read between
    samples; the base model and models with an actuator state or sensor parameters."""
    model = CarModel({effect: None}) if effect else CarModel()
    dataset = simulate_dataset(3.0, 5, model)
    data = FieData.from_dataset(dataset, FieSettings().noise)
    assert data.segment_count.max() > 1 and np.any(data.plane1_alpha > 0)
    extra = {
        None: (),
        "steering_lag": ("tau_steer",),
        "gyro_scale": ("gyro_scale_error",),
        "lighthouse_offset": ("lh_plane1_offset", "lh_plane2_offset"),
    }[effect]
    _compare(dataset, model, ("Iz", "Df", "Cm1", "Cd0", "r", *extra))


@pytest.mark.skipif(not REAL_RUN.exists(), reason="needs ../shared/data/chronos_real")
def test_matches_automatic_differentiation_on_a_real_recording():
    """The real recordings' layout: one sampled command per interval, missing samples."""
    dataset = Dataset.load(REAL_RUN / "fie_mpc_lighthouse_1")
    _compare(dataset.samples(0, 300), CarModel(), ("m", "Iz", "lf", "Df", "Bf", "Cm1", "b_car"))
