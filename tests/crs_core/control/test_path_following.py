"""Tests of crs_core.control.path_following against a test-only kinematic bicycle."""

from __future__ import annotations

import ast
import inspect
import math

import numpy as np
import pytest

import crs_core.control.path_following as path_following
from crs_core.analysis.laps import LapCounter
from crs_core.control import PathFollower, PathFollowerSettings
from crs_core.errors import FieldError
from crs_core.track import Track

WHEELBASE = 0.093  # m, Chronos lf + lr
# Crude longitudinal model of the test car: v_dot = K_DRIVE * (T - C_DRAG * v); its steady-state
# torque per m/s equals the controller's default feedforward.
K_DRIVE = 5.0  # 1/s (m/s per unit torque)
C_DRAG = 0.15  # torque per m/s


def _bicycle_step(x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
    """Explicit Euler step of a kinematic bicycle referenced at the rear axle (test only)."""
    psi, v = x[2], x[3]
    delta, torque = u
    x_dot = np.array(
        [
            v * math.cos(psi),
            v * math.sin(psi),
            v / WHEELBASE * math.tan(delta),
            K_DRIVE * (torque - C_DRAG * v),
            0.0,
            0.0,
        ]
    )
    out = x + dt * x_dot
    out[5] = v / WHEELBASE * math.tan(delta)  # yaw rate, for completeness
    return out


def test_follows_the_demo_track_for_one_lap(track: Track) -> None:
    settings = PathFollowerSettings()
    controller = PathFollower(track, WHEELBASE, settings)
    x = track.start_state()
    counter = LapCounter(track.length)
    dt, t = 0.005, 0.0
    hint = None
    max_error = 0.0
    speeds, lateral_accels, steers = [], [], []
    while counter.laps_completed < 1:
        assert t < 20.0, "the car did not complete a lap in 20 s"
        u = controller(t, x)
        steers.append(u[0])
        # Measure independently of the controller's own projection.
        projection = track.project(x[0], x[1], s_hint=hint)
        hint = projection.s
        counter.update(t, projection.s)
        max_error = max(max_error, abs(projection.lateral_error))
        _, _, _, kappa = track.interpolate(projection.s)
        speeds.append(x[3])
        lateral_accels.append(x[3] ** 2 * abs(float(kappa)))
        x = _bicycle_step(x, u, dt)
        t += dt

    assert max_error < 0.05
    speeds_arr = np.array(speeds)
    # Reaches the reference on the straights without a large overshoot ...
    assert 0.97 * settings.v_ref <= np.max(speeds_arr) <= 1.05 * settings.v_ref
    # ... and keeps near the lateral-acceleration limit in the 0.3 m bends (v ~ 0.95 m/s).
    assert np.max(lateral_accels) <= 1.1 * settings.a_lat_max
    assert np.max(lateral_accels) >= 0.9 * settings.a_lat_max
    # One lap at about 1 m/s.
    assert counter.lap_times[0] == pytest.approx(track.length / 0.98, rel=0.05)
    assert np.max(np.abs(steers)) <= settings.steer_max
    print(
        f"lap {counter.lap_times[0]:.2f} s, max |lateral error| {max_error * 100:.2f} cm, "
        f"max speed {np.max(speeds_arr):.3f} m/s"
    )


def test_outputs_respect_limits(track: Track) -> None:
    settings = PathFollowerSettings()
    controller = PathFollower(track, WHEELBASE, settings)
    rng = np.random.default_rng(3)
    for k in range(300):
        x = np.array(
            [
                rng.uniform(-1.6, 1.6),
                rng.uniform(-1.2, 1.2),
                rng.uniform(-np.pi, np.pi),
                rng.uniform(-0.5, 3.0),
                rng.uniform(-0.3, 0.3),
                rng.uniform(-5.0, 5.0),
            ]
        )
        u = controller(0.01 * k, x)
        assert u.shape == (2,)
        assert np.all(np.isfinite(u))
        assert -settings.steer_max <= u[0] <= settings.steer_max
        assert settings.torque_min <= u[1] <= settings.torque_max


def test_steering_saturates_when_facing_away(track: Track) -> None:
    controller = PathFollower(track, WHEELBASE)
    # At the start, heading left across the track: steer hard right.
    x = np.array([track.start_x, track.start_y, 0.5 * np.pi, 0.5, 0.0, 0.0])
    u = controller(0.0, x)
    assert u[0] == pytest.approx(-controller.settings.steer_max)


def test_output_order_is_steer_then_torque(track: Track) -> None:
    controller = PathFollower(track, WHEELBASE)
    x = np.array([track.start_x, track.start_y + 0.05, track.start_yaw, 0.0, 0.0, 0.0])
    delta, torque = controller(0.0, x)
    assert delta < 0.0  # left of a straight heading +x: steer right
    assert torque > 0.0  # standing still: accelerate
    assert controller.status is not None
    assert controller.status.lateral_error == pytest.approx(0.05, abs=1e-6)


def test_time_steps_that_are_not_positive_do_not_integrate(track: Track) -> None:
    controller = PathFollower(track, WHEELBASE)
    x = track.start_state(0.2)
    first = controller(0.0, x)
    later = controller(1.0, x)  # integrates one second of speed error
    assert later[1] > first[1]
    np.testing.assert_array_equal(controller(1.0, x), later)  # dt = 0
    np.testing.assert_array_equal(controller(0.5, x), later)  # dt < 0
    controller.reset()
    np.testing.assert_array_equal(controller(5.0, x), first)


def test_integral_is_clamped(track: Track) -> None:
    settings = PathFollowerSettings(torque_max=1.0, integral_limit=0.05)
    controller = PathFollower(track, WHEELBASE, settings)
    x = track.start_state(0.9)
    for k in range(200):
        u = controller(0.1 * k, x)
    error = 1.0 - 0.9
    expected = settings.torque_feedforward_per_speed * 1.0 + settings.kp_speed * error + 0.05
    assert u[1] == pytest.approx(expected)


@pytest.mark.parametrize(
    "bad",
    [
        [0.0, 0.0, np.nan, 1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, np.inf, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0, 0.0],
        np.zeros((6, 1)),
        ["a", 0, 0, 0, 0, 0],
    ],
)
def test_invalid_state_raises(track: Track, bad) -> None:
    controller = PathFollower(track, WHEELBASE)
    with pytest.raises(FieldError, match="x: state") as error:
        controller(0.0, bad)
    assert error.value.field == "x"


def test_nan_state_message_names_the_entry(track: Track) -> None:
    controller = PathFollower(track, WHEELBASE)
    with pytest.raises(ValueError, match="psi"):
        controller(0.0, [0.0, 0.0, np.nan, 1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="t:"):
        controller(float("nan"), np.zeros(6))


@pytest.mark.parametrize(
    ("settings", "field"),
    [
        ({"v_ref": -1.0}, "v_ref"),
        ({"steer_max": 0.0}, "steer_max"),
        ({"steer_max": 2.0}, "steer_max"),
        ({"torque_min": 0.5, "torque_max": 0.5}, "torque_max"),
        ({"kp_speed": math.nan}, "kp_speed"),
        ({"lookahead_min": True}, "lookahead_min"),
    ],
)
def test_invalid_settings_raise_naming_the_field(settings: dict, field: str) -> None:
    with pytest.raises(FieldError, match=rf"^{field}: ") as error:
        PathFollowerSettings(**settings)
    assert error.value.field == field


def test_invalid_wheelbase_and_time_raise_naming_the_field(track: Track) -> None:
    with pytest.raises(FieldError, match="wheelbase") as error:
        PathFollower(track, 0.0)
    assert error.value.field == "wheelbase"
    with pytest.raises(FieldError) as error:
        PathFollower(track, WHEELBASE)(float("nan"), np.zeros(6))
    assert error.value.field == "t"


def test_controller_is_model_free() -> None:
    # Apart from the wheelbase it uses only track geometry: no vehicle model is imported.
    tree = ast.parse(inspect.getsource(path_following))
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            imported.add(node.module or "")
    assert imported <= {
        "__future__",
        "math",
        "dataclasses",
        "numpy",
        "numpy.typing",
        "crs_core.analysis.angles",
        "crs_core.errors",
        "crs_core.settings",  # the declared bounds of the settings, no model
        "crs_core.track",
    }
