"""Online parameters in the EKF and the MHE: on a simulated car whose motor, grip and gyro are
off the model, both find them; a parameter the drive does not excite stays at its prior with
its prior's uncertainty, one nothing could see is refused; a car that is the model gets no
drift."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.estimation.base import Estimate
from crs_core.estimation.ekf import EkfSettings
from crs_core.estimation.factory import make_estimator
from crs_core.estimation.mhe import MheSettings
from crs_core.measurements import in_stamp_order
from crs_core.model import CarModel
from crs_core.track import load_demo_track
from sim.replay import start_state
from sim.scenarios import JoystickDriver
from sim.sensors import SensorSuite
from sim.simulator import Simulator

from .conftest import KINDS

SETTINGS = {"ekf": EkfSettings, "mhe": MheSettings}
ONLINE = ("Cm1", "gyro_bias", "grip")
CM1_FACTOR, GRIP, BIAS = 0.85, 0.85, 0.06
DURATION_S = 25.0


def _drive(factors: dict[str, float], bias: float, seed: int = 4, duration: float = DURATION_S):
    """A joystick drive of a car whose parameters are the model's times ``factors``."""
    plain = CarModel({"gyro_bias": bias})
    values = {name: plain.parameters.value(name) * f for name, f in factors.items()}
    truth = CarModel({"gyro_bias": bias}, parameters=plain.parameters.updated(values))
    track = load_demo_track()
    wheelbase = truth.parameters.value("lf") + truth.parameters.value("lr")
    simulator = Simulator(truth, SensorSuite(), seed=seed)
    return simulator.run(JoystickDriver(track, wheelbase, seed), duration, track.start_state())


def _estimate(kind: str, result, names, sensors="lh+imu+we") -> list[Estimate]:
    settings = SETTINGS[kind](online_parameters=names)
    estimator = make_estimator(kind, sensors, settings=settings, inputs="commanded")
    estimator.reset(0.0, start_state(result))
    events = in_stamp_order(result.measurements, result.inputs)
    estimates, k = [], 0
    for t in np.arange(1 / 60, result.truth_t[-1] - 0.05, 1 / 60):
        while k < len(events) and events[k].stamp <= t + 0.02:
            estimator.add(events[k])
            k += 1
        estimates.append(estimator.estimate(t))
    return estimates


@pytest.fixture(scope="module")
def changed_car():
    return _drive({"Cm1": CM1_FACTOR, "Df": GRIP, "Dr": GRIP}, BIAS)


@pytest.fixture(scope="module")
def model_car():
    """12 s of a car that is the model."""
    return _drive({}, 0.0, seed=5, duration=12.0)


@pytest.mark.parametrize("kind", KINDS)
def test_a_changed_motor_grip_and_gyro_are_found(kind, changed_car):
    estimates = _estimate(kind, changed_car, ONLINE)
    cm1 = CM1_FACTOR * CarModel().parameters.value("Cm1")
    last = [e.parameters for e in estimates[-5 * 60 :]]  # the last 5 s
    assert all(e.status == "ok" for e in estimates[60:])
    values = {name: np.mean([p[name].value for p in last]) for name in ONLINE}
    assert values["Cm1"] == pytest.approx(cm1, rel=0.05), values
    assert values["grip"] == pytest.approx(GRIP, rel=0.1), values
    assert values["gyro_bias"] == pytest.approx(BIAS, abs=0.025), values
    assert all(last[-1][name].informed for name in ONLINE), last[-1]


def test_the_mhe_keeps_each_samples_information_for_the_parameters(changed_car):
    """The MHE's window discounts a sample to eta^M (0.13) by the time it leaves; its
    marginalisation keeps the whole sample for the online parameters, so their uncertainty at
    the end of the drive is the EKF's (which forgets nothing), within 30 %: 1.06, 1.18, 1.19
    times it for Cm1, gyro_bias, grip (1.55, 1.62, 1.84 times without)."""
    final = {kind: _estimate(kind, changed_car, ONLINE)[-1].parameters for kind in KINDS}
    for name in ONLINE:
        assert final["mhe"][name].std < 1.3 * final["ekf"][name].std, (name, final)


def test_a_parameter_the_drive_does_not_excite_stays_at_its_prior():
    """Driving straight, the tyres carry no side force: the grip factor is not informed and
    keeps its prior and the prior's uncertainty (no drift along the flat direction), while the
    motor constant, informed by the same drive's acceleration, is called informed (the EKF;
    the MHE's parameters follow the same model)."""
    track = load_demo_track()
    simulator = Simulator(CarModel(), SensorSuite(), seed=6)
    straight = simulator.run(lambda t, x: np.array([0.0, 0.12]), 8.0, track.start_state())
    final = _estimate("ekf", straight, ("grip", "Cm1"))[-1].parameters
    assert final["grip"].value == pytest.approx(1.0, abs=0.1 * 0.1)
    assert final["grip"].std == pytest.approx(0.1, rel=0.05) and not final["grip"].informed
    assert final["Cm1"].informed


def test_a_parameter_nothing_can_see_is_refused_naming_it():
    """Without wheel encoders nothing depends on the wheel radius: refused in one line."""
    settings = EkfSettings(online_parameters=("Cm1", "wheel_radius_error"))
    refused = r"^online_parameters: wheel_radius_error: .* imu\+lh read"
    with pytest.raises(ValueError, match=refused):
        make_estimator("ekf", "lh+imu", settings=settings)


@pytest.mark.parametrize("kind", KINDS)
def test_a_car_that_is_the_model_gets_no_drift(kind, model_car):
    estimates = _estimate(kind, model_car, ONLINE)
    final = estimates[-1].parameters
    prior = {"Cm1": CarModel().parameters.value("Cm1"), "gyro_bias": 0.0, "grip": 1.0}
    for name in ONLINE:
        assert abs(final[name].value - prior[name]) < 2 * final[name].std, (name, final[name])
