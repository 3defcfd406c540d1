"""The MPCC, its hold-safety filter and the supervisor's prediction on models other than the
dynamic bicycle: CRS's kinematic bicycle and a model from a file outside crs_core."""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import casadi as ca
import numpy as np
import pytest

from crs_core.control.contingency import HoldSafetyFilter
from crs_core.control.mpcc import Mpcc
from crs_core.control.mpcc_problem import MpccProblem, MpccSettings
from crs_core.control.supervisor import Supervisor, SupervisorSettings
from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.model.kinematic import KinematicBicycle

OWN_MODEL = Path(__file__).resolve().parents[2] / "own_model" / "linear_tyre_car.py"


class Stationary(KinematicBicycle):
    """The kinematic bicycle without a speed state the MPCC could bound (its speed a
    parameter)."""

    name = "stationary"
    states = (("x", "m"), ("y", "m"), ("yaw", "rad"), ("heading_rate", "rad/s"))
    like: ClassVar[dict[str, str]] = {"heading_rate": "omega"}


def test_the_problem_finds_the_speed_by_what_it_is_like_and_a_kinematic_car_never_slides():
    kinematic = MpccProblem(CarModel(model="kinematic"), MpccSettings())
    assert kinematic.speed_index == 3 and kinematic.lateral_index is None
    residuals = kinematic.least_squares.residuals
    assert not ca.depends_on(residuals[-1], kinematic.z_sym)  # the sideslip term is 0
    own = MpccProblem(CarModel(model=f"{OWN_MODEL}:LinearTyreCar"), MpccSettings())
    assert (own.speed_index, own.lateral_index) == (3, 4)
    with pytest.raises(FieldError, match="the MPCC needs a state like vx in stationary"):
        MpccProblem(CarModel(model=Stationary()), MpccSettings())


def test_the_kinematic_mpcc_plans_only_as_fast_as_the_model_holds(track):
    mpcc = Mpcc(track, CarModel(model="kinematic"))
    assert mpcc.settings.progress_speed_max == KinematicBicycle.racing_speed
    slower = Mpcc(track, CarModel(model="kinematic"), MpccSettings(progress_speed_max=0.5))
    assert slower.settings.progress_speed_max == 0.5  # a slower setting is kept


@pytest.mark.parametrize("spec", ["kinematic", f"{OWN_MODEL}:LinearTyreCar"])
def test_the_mpcc_drives_off_from_the_start_on_either_model(track, spec):
    """From the car state at the start line, successive calls plan in the model's own states
    and drive forward along the track within the limits."""
    model = CarModel(model=spec)
    mpcc = Mpcc(track, model)
    car = track.start_state()
    for _ in range(3):
        u = mpcc(car)
        assert np.all(np.isfinite(u)) and mpcc.status.mode == "solved"
        assert abs(u[0]) <= mpcc.settings.steer_max and u[1] > 0
    Z, _ = mpcc.plan
    assert Z.shape[1] == mpcc.problem.nz == model.nx + 4
    assert Z[-1, mpcc.problem.speed_index] > 0.1  # it plans to move
    assert Z[-1, model.nx] > Z[0, model.nx]  # and to make progress


def test_the_hold_safety_filter_reads_the_speed_of_the_car_state():
    from crs_core.track import load_demo_track

    model = CarModel(model="kinematic")
    safety = HoldSafetyFilter(load_demo_track(), model, model.parameters, 0.35, (-1, 1), 1.0)
    states = np.array([[0, 0, 0, 1.5], [0, 0, 0, -0.5]]).T
    np.testing.assert_allclose(safety._speeds(states, [0.3, -0.2]), [1.5, 0.5], rtol=1e-12)


def test_the_supervisor_carries_a_car_state_through_a_kinematic_model():
    """The estimate (a car state) is carried forward in the model's own states and handed to
    the controller as a car state again."""
    model = CarModel(model="kinematic")
    supervisor = Supervisor(lambda now, x, limit: np.array([0.2, 0.3]), SupervisorSettings(), model)
    car = np.array([1.0, 2.0, 0.5, 1.0, 0.0, 0.0])
    supervisor.observe(0.0, car, "ok")
    carried = supervisor.predicted(0.1)
    assert carried.shape == (6,)
    p = model.parameters.vector()
    x = model.numeric.step(model.initial_state(car, [0, 0]), np.zeros(2), p, 0.1)
    np.testing.assert_allclose(carried, model.numeric.car_state(x, np.zeros(2), p), atol=1e-12)
