"""Tests of the FIE identification: recovery of the truth, uncertainty, Hessian variants."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from crs_core.dataset import Y_CHANNELS, Dataset
from crs_core.errors import FieldError
from crs_core.identification import FieData, FieProblem, FieSettings, identify
from crs_core.identification.data import Y_LAYOUT
from crs_core.identification.models import ROUGH, identification_model
from crs_core.identification.problem import check_fit, substeps_for
from crs_core.identification.uncertainty import MAX_CORRELATION, parameter_uncertainty
from crs_core.measurements import InputSample
from crs_core.model import CarModel
from crs_core.model.car_model import MAX_SUBSTEP
from crs_core.model.chronos import ROUGH_PRIOR
from sim.scenarios import SIM_PROCESS_SCALE, simulate_dataset

#: A subset the data of a short drive determine well, plus two they do not.
FIT = ("Iz", "Df", "Dr", "Br", "Cm1", "Cd0", "Cd1", "r", "b_car")
DURATION = 15.0
#: The simulated truth has no process noise: trust the model more than on real data.


@pytest.fixture(scope="module")
def drives() -> list[Dataset]:
    return [simulate_dataset(DURATION, seed) for seed in (11, 12)]


@pytest.fixture(scope="module")
def results(drives):
    out = []
    for dataset in drives:
        truth = identification_model(dataset, [])
        prior = {n: v for n, v in ROUGH_PRIOR.items() if n in FIT}  # the rest fixed at truth
        model = CarModel(parameters=truth.parameters.updated(prior))
        settings = FieSettings(fit=FIT, process_scale=SIM_PROCESS_SCALE)
        out.append((model, identify(dataset, model, settings)))
    return out


def test_identified_parameters_cover_the_truth(results):
    """From the rough prior, every identifiable parameter lands within 3 sigma of the truth and
    the truth is inside 2 sigma for most (parameter, seed) pairs."""
    truth = CarModel().parameters
    z_all = []
    for _, result in results:
        z = (result.theta - [truth.value(n) for n in result.fit]) / result.uncertainty.std
        ok = result.uncertainty.identifiable
        assert ok.sum() >= 4, result.uncertainty.warnings()
        assert np.all(np.abs(z[ok]) <= 3.0), dict(zip(result.fit, z.round(2), strict=True))
        z_all.extend(z)
        assert result.cost < result.cost_initial
        assert result.iterations > 0
    assert np.mean(np.abs(np.array(z_all)) <= 2.0) >= 0.8


def test_result_is_consistent(results, drives):
    """Shapes, the parameter set carries the identified values, outputs match the data."""
    (model, result), dataset = results[0], drives[0]
    n = len(dataset.t)
    assert result.states.shape == (n, model.nx) and result.outputs.shape == (n, 13)
    for name, value in zip(result.fit, result.theta, strict=True):
        assert result.parameters.value(name) == pytest.approx(value)
        assert model.parameters[name].lower <= value <= model.parameters[name].upper
    lh = result.data.weight[:, :8] > 0
    residual = np.abs(result.outputs[:, :8] - result.data.y[:, :8])[lh]
    assert np.median(residual) < 3e-3  # rad: the fit follows the Lighthouse angles
    assert set(result.cost_terms) == {"theta_prior", "x0_prior", "process", "measurement"}
    assert sum(result.cost_terms.values()) == pytest.approx(result.cost, rel=1e-6)


def test_exact_and_gauss_newton_hessians_reach_the_same_optimum(drives):
    """On a short window both IPOPT variants find the same parameters."""
    dataset = drives[0]
    k = 100
    short = Dataset(
        t=dataset.t[:k], u=dataset.u[:k], y=dataset.y[:k], x=dataset.x[:k], meta=dataset.meta
    )
    model = identification_model(short, [], ROUGH)
    thetas = [
        identify(short, model, FieSettings(fit=("Cm1", "Iz"), hessian=h, tol=1e-9)).theta
        for h in ("gauss-newton", "exact")
    ]
    np.testing.assert_allclose(thetas[0], thetas[1], rtol=2e-3)
    two = identify(short, model, FieSettings(fit=("Cm1", "Iz"), starts=2, tol=1e-9))
    assert len(two.starts) == 2 and two.cost <= min(s["cost"] for s in two.starts) + 1e-9
    np.testing.assert_allclose(two.theta, thetas[0], rtol=2e-3)


def test_nan_channels_drop_out(drives):
    """A sensor missing everywhere gets weight 0; the rest keep 1/sigma."""
    dataset = drives[0]
    y = dataset.y.copy()
    y[:, 8:12] = np.nan
    data = FieData.from_dataset(
        Dataset(t=dataset.t, u=dataset.u, y=y, x=dataset.x), FieSettings().noise
    )
    assert np.all(data.weight[:, 8:12] == 0) and np.all(data.y[:, 8:12] == 0)
    assert "wheel_encoders" not in data.channels_present
    assert np.all(data.weight[:, 12] == pytest.approx(1 / FieSettings().noise.gyro_std))


def test_residual_layout_and_substeps(drives):
    """The residual has one row per prior, defect and measurement; substeps <= MAX_SUBSTEP."""
    dataset = drives[0]
    model = identification_model(dataset, [], ROUGH)
    data = FieData.from_dataset(dataset, FieSettings().noise)
    problem = FieProblem(model, data, FieSettings(fit=("Cm1",)), np.zeros(model.nx))
    n = len(dataset.t)
    assert problem.blocks == {
        "theta_prior": 1,
        "x0_prior": model.nx,
        "process": model.nx * (n - 1),
        "measurement": 13 * n,
    }
    assert sum(cols.stop - cols.start for _, cols in Y_LAYOUT) == 13
    for dt in (0.004, 0.0201, 0.1, 0.37):
        assert dt / substeps_for(dt) <= MAX_SUBSTEP + 1e-12
    z = problem.pack(np.array([0.9]), np.ones((n, model.nx)))
    theta, states = problem.unpack(z)
    assert theta == pytest.approx([0.9]) and states.shape == (n, model.nx)


def test_linear_covariance_matches_the_closed_form():
    """Parameters only: covariance = (I + A'A)^-1 scaled by the prior std."""
    rng = np.random.default_rng(0)
    a = rng.standard_normal((30, 3))
    jac = sp.csc_matrix(np.vstack([np.eye(3), a]))
    std = np.array([2.0, 0.5, 1.0])
    u = parameter_uncertainty(jac, ("a", "b", "c"), np.ones(3), std)
    expected = np.linalg.inv(np.eye(3) + a.T @ a) * np.outer(std, std)
    np.testing.assert_allclose(u.covariance, expected, rtol=1e-9)
    assert np.all(u.identifiable)


def test_states_are_eliminated_by_the_schur_complement():
    """With a state in the problem, the parameter block equals that of the full inverse."""
    rng = np.random.default_rng(1)
    jac = rng.standard_normal((20, 4))
    jac[:2, :2] = np.eye(2)
    u = parameter_uncertainty(sp.csc_matrix(jac), ("a", "b"), np.ones(2), np.ones(2))
    full = np.linalg.inv(jac.T @ jac)[:2, :2]
    np.testing.assert_allclose(u.covariance, full, rtol=1e-9)


def test_unidentifiable_parameters_are_named_with_the_reason():
    """A parameter the data do not see is flat; two the data see only as a sum correlate; a
    parameter on its bound is flagged."""
    data = np.zeros((40, 4))
    data[:20, 0] = 10.0  # a: well determined
    data[20:, 1] = data[20:, 2] = 10.0  # b, c: only b + c is seen
    jac = sp.csc_matrix(np.vstack([np.eye(4), data]))  # d: column of zeros (flat)
    u = parameter_uncertainty(
        jac, ("a", "b", "c", "d"), np.ones(4), np.ones(4), at_bound=np.array([1, 0, 0, 0], bool)
    )
    assert list(u.identifiable) == [False, False, False, False]
    assert u.reasons[0] == "bound active"
    assert u.std[0] < 0.1
    assert (
        "strongly correlated with c" in u.reasons[1] and abs(u.correlation[1, 2]) > MAX_CORRELATION
    )
    assert "flat direction" in u.reasons[3]
    assert any("'d'" in w and "flat" in w for w in u.warnings())


def test_effect_parameters_are_identified_like_any_other():
    """A hidden steering offset (truth 0.06 rad, prior 0.02) is found within 3 sigma."""
    dataset = simulate_dataset(12.0, 21, CarModel({"steering_offset": 0.06}))
    model = identification_model(dataset, ["steering_offset"], ROUGH)
    assert model.parameters.value("steering_offset") == pytest.approx(0.02)
    settings = FieSettings(fit=("steering_offset", "Cm1"), process_scale=SIM_PROCESS_SCALE)
    result = identify(dataset, model, settings)
    value, std = result.theta[0], result.uncertainty.std[0]
    assert result.uncertainty.identifiable[0]
    assert abs(value - 0.06) <= 3 * std and std < 0.02


def test_input_delay_cannot_be_fitted():
    model = CarModel(["input_delay"])
    with pytest.raises(FieldError, match="fit: 'input_delay'") as error:
        check_fit(model, ("input_delay",))
    assert error.value.field == "fit"


@pytest.mark.parametrize(
    ("settings", "field"),
    [
        ({"fit": ()}, "fit"),
        ({"fit": ("m", "m")}, "fit"),
        ({"hessian": "bfgs"}, "hessian"),
        ({"process_scale": 0.0}, "process_scale"),
        ({"max_iter": 0}, "max_iter"),
        ({"starts": 0}, "starts"),
    ],
)
def test_bad_fie_settings_name_the_field(settings: dict, field: str):
    with pytest.raises(FieldError, match=rf"^{field}: ") as error:
        FieSettings(**{"fit": ("m",), **settings})
    assert error.value.field == field


def test_lag_states_run_through_the_commands():
    """An actuator lag's state trails a step of its command as 1 - exp(-t / tau) (analytic),
    not at rest under the new command from the step on."""
    from crs_core.identification.solve import effect_state_trajectory

    tau = 0.08
    model = CarModel({"steering_lag": {"tau_steer": tau}})
    t = np.arange(0.0, 1.0, 0.01)
    u = np.stack([np.where(t >= 0.5, 0.2, 0.0), np.full_like(t, 0.1)], axis=1)
    held = [InputSample(0.0, u[0]), InputSample(0.5, u[-1])]  # the step held from 0.5 s on
    dataset = Dataset(t=t, u=u, y=np.full((len(t), len(Y_CHANNELS)), np.nan), inputs=held)
    at_rest = np.stack([model.initial_state([0, 0, 0, 0.5, 0, 0], c) for c in u])
    states = effect_state_trajectory(dataset, model, at_rest)
    lag = states[:, 6]
    expected = np.where(t > 0.5, 0.2 * (1.0 - np.exp(-(t - 0.5) / tau)), 0.0)
    np.testing.assert_allclose(lag, expected, atol=1e-6)
    np.testing.assert_array_equal(states[:, :6], at_rest[:, :6])
    base = at_rest[:, :6]
    np.testing.assert_array_equal(effect_state_trajectory(dataset, CarModel(), base), base)


def test_sampled_commands_hold_their_interval_middle_held_commands_split_it():
    """Without a command stream ``u`` samples the command signal: an interval holds its value at
    the middle, (u_k + u_k+1) / 2, so a ramp is followed without the half-interval lag of
    holding u_k. With the stream, each command is held from its stamp."""
    from crs_core.identification.data import input_segments

    t = np.array([0.0, 0.02, 0.04, 0.06])
    u = np.stack([t * 10.0, np.full(4, 0.3)], axis=1)  # a steering ramp, 10 rad/s
    y = np.full((4, len(Y_CHANNELS)), np.nan)
    seg_u, seg_dt, count = input_segments(Dataset(t=t, u=u, y=y))
    np.testing.assert_array_equal(count, [1, 1, 1])
    np.testing.assert_allclose(seg_u[:, 0, 0], [0.1, 0.3, 0.5])
    np.testing.assert_allclose(seg_dt[:, 0], 0.02)
    held = [InputSample(0.0, [0.0, 0.3]), InputSample(0.03, [0.5, 0.3])]
    seg_u, seg_dt, count = input_segments(Dataset(t=t, u=u, y=y, inputs=held))
    np.testing.assert_array_equal(count, [1, 2, 1])
    np.testing.assert_allclose(seg_u[1, :2, 0], [0.0, 0.5])
    np.testing.assert_allclose(seg_dt[1, :2], [0.01, 0.01])
    np.testing.assert_allclose(seg_u[2, 0, 0], 0.5)
