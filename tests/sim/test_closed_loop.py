"""The ROS-free closed loop: the MPCC races the simulated car on the truth and with the MHE."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.control.mpcc import Mpcc
from crs_core.errors import FieldError
from crs_core.estimation.factory import make_estimator
from crs_core.model import CarModel
from crs_core.track import load_demo_track
from sim.closed_loop import CAR_LENGTH, CAR_WIDTH, footprint_outside, run_closed_loop
from sim.sensors import SensorSuite
from sim.simulator import Simulator


@pytest.fixture(scope="module")
def track():
    return load_demo_track()


@pytest.fixture(scope="module")
def mpcc(track) -> Mpcc:
    return Mpcc(track)


def _race(controller: Mpcc, simulator: Simulator, track, **options):
    """``controller`` races two laps (at most 30 s) of ``track`` on ``simulator`` (its modes
    counted); ``options`` go to ``run_closed_loop``."""
    return run_closed_loop(
        simulator,
        track,
        lambda t, x: controller(x),
        controller.stop,
        30.0,
        laps=2,
        status_of=lambda: controller.status.mode,
        **options,
    )


def test_footprint_inside_and_outside(track) -> None:
    half = track.width / 2
    # on the start straight (heading 0), centred: the footprint's side is CAR_WIDTH/2 off
    x, y = track.start_x + 0.3, track.start_y
    assert footprint_outside(track, x, y, 0.0, None) == pytest.approx(
        CAR_WIDTH / 2 - half, abs=1e-6
    )
    # turned by 90 degrees the long side points across the track
    assert footprint_outside(track, x, y, math.pi / 2, None) == pytest.approx(
        CAR_LENGTH / 2 - half, abs=1e-6
    )
    assert footprint_outside(track, x, y + half, 0.0, None) == pytest.approx(
        CAR_WIDTH / 2, abs=1e-6
    )


def test_the_mpcc_races_a_lap_on_the_true_state(mpcc: Mpcc, track) -> None:
    result = _race(mpcc, Simulator(CarModel(), SensorSuite(), seed=5), track)
    summary = result.summary()
    assert summary["laps"] == 2
    # the flying lap is below the centreline's point-mass limit (6.8 s at 6 m/s^2)
    assert summary["lap_times_s"][1] < 6.8
    assert summary["boundary_violations"] == 0
    assert summary["max_contouring_error_m"] < track.width / 2
    assert summary["controller_modes"] == {"solved": result.t.size}
    assert np.all(np.isfinite(result.u))


def test_with_the_mhe_and_a_lighthouse_blackout_every_lap(mpcc: Mpcc, track) -> None:
    mpcc.reset()
    simulator = Simulator(CarModel(), SensorSuite(), seed=6)
    estimator = make_estimator("mhe", "lh+imu+we", CarModel())
    result = _race(mpcc, simulator, track, estimator=estimator, blackout_s=1.127)
    summary = result.summary()
    assert summary["laps"] == 2 and summary["blackouts"] == 2
    assert summary["boundary_violations"] == 0
    assert summary["estimation_rmse"]["position"] < 0.01
    assert summary["lost_ticks"] == 0
    # no Lighthouse sample reached the estimator during a blackout
    start, end = result.blackouts[0]
    assert end - start == pytest.approx(1.127)


def test_a_known_input_delay_is_compensated(track) -> None:
    """A 100 ms transport delay in the car: the MPCC whose model has it races clean laps;
    one that does not know it leaves the track (measured: 9 violations in 60 s)."""
    delayed = CarModel({"input_delay": 0.1})
    controller = Mpcc(track, delayed)
    result = _race(controller, Simulator(delayed, SensorSuite(), seed=2), track)
    summary = result.summary()
    assert summary["laps"] == 2 and summary["boundary_violations"] == 0
    assert summary["lap_times_s"][1] < 6.8


@pytest.mark.parametrize(
    ("arguments", "field"),
    [
        ({"rate_hz": 0.0}, "rate_hz"),
        ({"max_duration": -1.0}, "max_duration"),
        ({"laps": 0}, "laps"),
    ],
)
def test_closed_loop_arguments_name_the_field(arguments: dict, field: str):
    from crs_core.track import load_demo_track
    from sim.closed_loop import run_closed_loop

    arguments = {"rate_hz": 50.0, **arguments}
    with pytest.raises(FieldError) as error:
        run_closed_loop(
            Simulator(CarModel(), SensorSuite()),
            load_demo_track(),
            lambda t, x: np.zeros(2),
            lambda result: False,
            arguments.pop("rate_hz"),
            **arguments,
        )
    assert error.value.field == field
