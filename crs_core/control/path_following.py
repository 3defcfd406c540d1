"""A simple path-following controller: pure-pursuit steering and PI speed control.

The controller drives the car along the centerline of a :class:`~crs_core.track.Track`. It is
model-free apart from the wheelbase: no tire, friction or motor model is used. It is meant as a
baseline, a way to drive the simulator around the track (e.g. to record data for
identification), and a test fixture, not as a racing controller.

Conventions: state ``x = [x_p, y_p, psi, v_x, v_y, omega]`` (position m and yaw rad in the world
frame, velocities m/s and yaw rate rad/s in the body frame, REP 103); input ``u = [delta, T]``
(steering angle rad, positive to the left; normalised motor torque), in that order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from crs_core.analysis.angles import wrap_angle
from crs_core.errors import FieldError
from crs_core.settings import Settings, finite, non_negative, positive
from crs_core.track import Track

__all__ = ["PathFollower", "PathFollowerSettings", "PathFollowerStatus"]

_STATE_SIZE = 6


@dataclass
class PathFollowerSettings(Settings):
    """Tuning of :class:`PathFollower`; defaults suit a 1:28 Chronos car (wheelbase ~0.093 m).

    The default lookahead (0.25 m at 1 m/s, about 2.7 wheelbases) keeps a kinematic bicycle within
    about 2 cm of the demo track's centerline through its 0.3 m-radius bends; longer lookaheads
    are smoother but cut the bends more (0.4 m at 1 m/s cuts them by about 6 cm). The feedforward
    matches the identified Chronos drivetrain, whose steady-state torque is about 0.15 per m/s
    around 1 m/s.

    Attributes
    ----------
    lookahead_min : float
        Lookahead distance at standstill, m. The goal point lies
        ``lookahead_min + lookahead_time * max(v_x, 0)`` ahead along the track.
    lookahead_time : float
        Speed-proportional part of the lookahead, s.
    v_ref : float
        Reference speed on straights, m/s.
    a_lat_max : float
        Lateral-acceleration limit, m/s^2. The speed reference is
        ``min(v_ref, sqrt(a_lat_max / kappa_max))`` with ``kappa_max`` the largest ``|curvature|``
        (1/m) of the centerline over the preview distance ahead of the car.
    preview_distance : float
        Distance ahead of the car's projection over which the curvature is previewed, m (at least
        the current lookahead is always previewed).
    steer_max : float
        Steering limit, rad; ``delta`` is clipped to ``[-steer_max, steer_max]``.
    torque_min, torque_max : float
        Limits of the normalised torque command ``T``.
    torque_feedforward_per_speed : float
        Feedforward torque per m/s of speed reference, 1/(m/s): ``T_ff = this * v_target``.
    kp_speed : float
        Proportional gain from speed error to torque, 1/(m/s).
    ki_speed : float
        Integral gain from integrated speed error to torque, 1/m.
    integral_limit : float
        Anti-windup clamp on the integral torque contribution ``|ki_speed * integral|``
        (normalised torque). The integral also stops growing while the torque saturates in the
        direction of the error.
    projection_window : float
        Half-width of the arc-length window searched around the previous projection, m.
    """

    lookahead_min: float = positive(0.10)
    lookahead_time: float = non_negative(0.15)
    v_ref: float = non_negative(1.0)
    a_lat_max: float = positive(3.0)
    preview_distance: float = non_negative(0.5)
    steer_max: float = positive(0.34)
    torque_min: float = finite(0.0)
    torque_max: float = finite(1.0)
    torque_feedforward_per_speed: float = non_negative(0.15)
    kp_speed: float = non_negative(1.0)
    ki_speed: float = non_negative(0.3)
    integral_limit: float = non_negative(0.1)
    projection_window: float = positive(0.5)

    def _check_relations(self) -> None:
        if self.steer_max >= 0.5 * math.pi:
            raise FieldError("steer_max", f"must be below pi/2 rad, got {self.steer_max!r}")
        if not self.torque_min < self.torque_max:
            raise FieldError(
                "torque_max",
                f"must exceed torque_min ({self.torque_min!r}), got {self.torque_max!r}",
            )


@dataclass(frozen=True)
class PathFollowerStatus:
    """What :class:`PathFollower` computed at its last call.

    Attributes
    ----------
    s : float
        Arc length of the car's projection onto the centerline, m.
    lateral_error : float
        Signed distance of the car from the centerline, m, positive to the left.
    lookahead : float
        Lookahead distance along the track, m.
    goal_x, goal_y : float
        Goal point on the centerline, m, world frame.
    v_target : float
        Speed reference after the curvature limit, m/s.
    """

    s: float
    lateral_error: float
    lookahead: float
    goal_x: float
    goal_y: float
    v_target: float


class PathFollower:
    """Pure-pursuit steering plus PI speed control along a track centerline.

    Steering: the car is projected onto the centerline (a window around the previous projection,
    global on the first call); the goal point lies ``l = lookahead_min + lookahead_time * v_x``
    further along the centerline. With ``alpha`` the angle of the goal point in the body frame
    and ``d`` its straight-line distance from the car position ``(x_p, y_p)``, the command is
    ``delta = atan(2 L sin(alpha) / d)``, the steering of a kinematic bicycle whose arc through
    the goal point is tangent to the current heading (``d`` equals ``l`` on a straight when the
    car is on the centerline).

    Speed: ``v_target = min(v_ref, sqrt(a_lat_max / kappa_max))`` over the preview distance;
    ``T = torque_feedforward_per_speed * v_target + kp_speed * e + ki_speed * integral(e)``
    with ``e = v_target - v_x``, clipped to the torque limits.

    Parameters
    ----------
    track : Track
        Track whose centerline is followed in the direction of increasing arc length.
    wheelbase : float
        Distance between the axles ``L``, m (``lf + lr``; about 0.093 m on a Chronos car).
    settings : PathFollowerSettings, optional
        Tuning; defaults if omitted.

    Raises
    ------
    FieldError
        If the wheelbase is not positive and finite, or the settings are invalid.
    """

    def __init__(
        self, track: Track, wheelbase: float, settings: PathFollowerSettings | None = None
    ) -> None:
        if not isinstance(track, Track):
            raise TypeError(f"track: expected a Track, got {type(track).__name__}")
        wheelbase = float(wheelbase)
        if not (math.isfinite(wheelbase) and wheelbase > 0.0):
            raise FieldError("wheelbase", f"must be positive and finite, got {wheelbase!r}")
        self.track = track
        self.wheelbase = wheelbase
        self.settings = settings if settings is not None else PathFollowerSettings()
        self.settings.validate()
        self._preview_step = float(np.min(np.diff(track.arc_length)))
        self.reset()

    def reset(self) -> None:
        """Forget the projection hint, the speed integrator and the last time."""
        self._s_hint: float | None = None
        self._integral: float = 0.0
        self._t_last: float | None = None
        self._last_torque_saturation: int = 0
        self.status: PathFollowerStatus | None = None

    def __call__(
        self, t: float, x: ArrayLike, speed_limit: float | None = None
    ) -> NDArray[np.float64]:
        """Compute the input for the current state.

        Parameters
        ----------
        t : float
            Time, s. The speed integrator advances by ``t - t_previous``; a step ``<= 0`` (first
            call, repeated or earlier time) does not integrate.
        x : array_like, shape (6,)
            State ``[x_p, y_p, psi, v_x, v_y, omega]``: position m and yaw rad (world frame),
            velocities m/s and yaw rate rad/s (body frame).
        speed_limit : float, optional
            A lower speed than ``v_ref`` for this call, m/s (e.g. while the state estimate is
            degraded); ``None``: ``v_ref``.

        Returns
        -------
        numpy.ndarray, shape (2,)
            Input ``[delta, T]``: steering angle, rad (positive left), within the steering
            limit; normalised torque within the torque limits.

        Raises
        ------
        FieldError
            If ``t`` is not finite or ``x`` is not a finite vector of length 6.
        """
        state = self._validate(t, x)
        cfg = self.settings
        px, py, psi, vx = (float(v) for v in state[:4])
        track = self.track

        projection = track.project(px, py, s_hint=self._s_hint, window=cfg.projection_window)
        self._s_hint = projection.s

        # Pure pursuit.
        lookahead = cfg.lookahead_min + cfg.lookahead_time * max(vx, 0.0)
        gx, gy, _, _ = track.interpolate(projection.s + lookahead)
        goal_x, goal_y = float(gx), float(gy)
        dx, dy = goal_x - px, goal_y - py
        distance = math.hypot(dx, dy)
        if distance > 1e-9:
            alpha = float(wrap_angle(math.atan2(dy, dx) - psi))
            delta = math.atan(2.0 * self.wheelbase * math.sin(alpha) / distance)
        else:
            delta = 0.0
        delta = min(max(delta, -cfg.steer_max), cfg.steer_max)

        # Speed reference from the curvature ahead.
        preview = max(cfg.preview_distance, lookahead)
        count = math.ceil(preview / self._preview_step) + 1
        _, _, _, kappa = track.interpolate(projection.s + np.linspace(0.0, preview, count))
        kappa_max = float(np.max(np.abs(kappa)))
        v_target = cfg.v_ref if speed_limit is None else min(cfg.v_ref, speed_limit)
        if kappa_max > 0.0:
            v_target = min(v_target, math.sqrt(cfg.a_lat_max / kappa_max))

        # PI speed control with feedforward and anti-windup.
        error = v_target - vx
        dt = 0.0 if self._t_last is None else float(t) - self._t_last
        self._t_last = float(t)
        if dt > 0.0 and cfg.ki_speed > 0.0:
            # Conditional integration: do not wind up into a saturated actuator.
            if not (self._last_torque_saturation * error > 0.0):
                self._integral += error * dt
                bound = cfg.integral_limit / cfg.ki_speed
                self._integral = min(max(self._integral, -bound), bound)
        torque = (
            cfg.torque_feedforward_per_speed * v_target
            + cfg.kp_speed * error
            + cfg.ki_speed * self._integral
        )
        if torque >= cfg.torque_max:
            self._last_torque_saturation = 1
        elif torque <= cfg.torque_min:
            self._last_torque_saturation = -1
        else:
            self._last_torque_saturation = 0
        torque = min(max(torque, cfg.torque_min), cfg.torque_max)

        self.status = PathFollowerStatus(
            s=projection.s,
            lateral_error=projection.lateral_error,
            lookahead=lookahead,
            goal_x=goal_x,
            goal_y=goal_y,
            v_target=v_target,
        )
        return np.array([delta, torque], dtype=float)

    @staticmethod
    def _validate(t: float, x: ArrayLike) -> NDArray[np.float64]:
        try:
            t_value = float(t)
        except (TypeError, ValueError):
            raise FieldError("t", f"must be a number, got {t!r}") from None
        if not math.isfinite(t_value):
            raise FieldError("t", f"must be finite, got {t_value!r}")
        try:
            state = np.asarray(x, dtype=float)
        except (TypeError, ValueError):
            raise FieldError("x", "state must be a numeric vector of length 6") from None
        if state.shape != (_STATE_SIZE,):
            raise FieldError(
                "x",
                "state must have shape (6,) [x_p, y_p, psi, v_x, v_y, omega], "
                f"got shape {state.shape}",
            )
        if not np.all(np.isfinite(state)):
            names = ("x_p", "y_p", "psi", "v_x", "v_y", "omega")
            bad = [names[i] for i in np.flatnonzero(~np.isfinite(state))]
            raise FieldError("x", f"state has non-finite entries: {', '.join(bad)}")
        return state
