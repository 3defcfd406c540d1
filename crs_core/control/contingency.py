"""Commands safe to hold through a link outage: the MPCC's hold-safety filter.

A Chronos car holds its last reference until none has come for 200 ms (the firmware's
cut-off; ``hold_time`` allows for the command's way to the car), then cuts the motors and
coasts with the steering where it was; the host's next command acts only once the link is
back. Nothing the host sends meanwhile arrives, so
what a car does in an outage is decided by the command sent *before* it. Racing commands are
not safe to hold: 300 ms of full throttle towards a hairpin took a car 0.7 m further at
2.3 m/s, and it could not brake to the hairpin's speed within the track once the link was
back; 200 ms of the steering of a corner's exit, held with full throttle, turned another car
0.7 rad past the track's direction and off it.

:class:`HoldSafetyFilter` checks a command against that outage: it rolls the car's model out
from the current state under the command for ``hold_time`` s, then coasting (zero torque, the
same steering) for ``coast_time`` s, then driven back for ``recovery_time`` s as the host would
once the link is back (steering along the track by the Stanley law, full braking), and the
command is safe when

* the car's centre stays within ``bound`` of the centreline at every sample of that rollout,
  the recovery included (a car that comes back from an outage with its nose past the track's
  direction can be within the bound and still not turn in before the border);
* at the end of the coast the car is no faster than full braking allows for every corner ahead:
  the braking envelope ``B(s)``, the highest speed from which braking at ``braking`` m/s^2
  reaches each corner's speed ``sqrt(lateral / |kappa|)`` (``kappa`` the curvature of the
  track's minimum-curvature line, :func:`~crs_core.track.racing_line.minimum_curvature_line`;
  the centreline's hairpins and chicanes are far tighter than what a racing car drives).

The filter leaves a car slower than ``min_speed`` alone: braking is always safe to hold, so
filtered, a slow car at the edge braked to a stand facing out. An unsafe command is replaced
by the nearest safe one of a grid of steering angles and torques (rolled out together, in two
mapped CasADi calls); when none is safe it is kept. A safe command passes unchanged after one
rollout of its own, and the supervisor asks for the filter once the link has shown an outage
(or always: :class:`~crs_core.control.supervisor.Supervisor`).

Conventions: state ``[x_p, y_p, psi, v_x, v_y, omega]`` (m, rad, m/s, rad/s; world pose, body
velocities), command ``[delta, T]`` (rad, normalised torque), arc length along the centreline
(m), speeds m/s, accelerations m/s^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from crs_core.analysis.angles import wrap_angle
from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.parameters import ParameterSet
from crs_core.settings import Settings, non_negative, positive
from crs_core.track import Track, minimum_curvature_line

__all__ = ["ContingencySettings", "HoldSafetyFilter", "braking_envelope", "lag_decay"]

#: Arc-length step of the braking envelope and of the centreline lookup, m.
GRID_STEP = 0.01
#: Steering angles tried, as fractions of full lock (with the command's own).
STEER_FRACTIONS = np.linspace(-1.0, 1.0, 13)
#: RK4 substeps of a rollout sample.
SUBSTEPS = 2


@dataclass(frozen=True)
class ContingencySettings(Settings):
    """What an outage is assumed to do to a car, and what is safe after it.

    Attributes
    ----------
    hold_time : float
        How long the car holds a command before it cuts the motors, s: the firmware's
        ``CONFIG_DISCONNECT_THRESHOLD_MS`` (200 ms) counts from the car's last reading of a
        reference, which comes up to a command period (33 ms; the bridge repeats the last
        command meanwhile) and the link's jitter after the command acts (in the link
        benchmark's bad Wi-Fi a command was held 0.27 s).
    coast_time : float
        Coasting after the cut-off until the host's first command after the outage acts, s:
        the rest of a 300 ms outage and the way of a command to the car (about 50 ms).
    steering_time_constant : float
        The car's steering follows its reference as a first-order lag of this time constant,
        s (the Chronos steering loop: 90 % of a 0.3 rad step after 0.10 s); it starts from the
        angle the car steers at now. 0: the steering is where it is told at once.
    sample_time : float
        Step of the rollout, s: the track is checked at each.
    edge_clearance : float
        The car's centre stays this far inside the border, m (its half width and a margin;
        the MPCC's own bound is its ``track_margin``).
    recovery_time : float
        After the coast, the car is driven back towards the centreline this long (steering
        along the track, full braking) and must stay within the bound throughout, s (0: no
        recovery; then only the hold and the coast are checked).
    recovery_gain : float
        Cross-track gain of the recovery's steering, 1/s (the Stanley law's ``k``).
    min_speed : float
        Slower than this (m/s) the filter leaves the command as it is.
    lateral : float
        Lateral acceleration the car keeps through a corner, m/s^2 (the Chronos car's front
        tyres saturate at about 4.9 m/s^2).
    braking : float
        Deceleration of full braking, m/s^2 (the Chronos car's ``Cm1 / m`` is 4.0).
    """

    hold_time: float = non_negative(0.25)
    coast_time: float = non_negative(0.2)
    steering_time_constant: float = non_negative(0.04)
    sample_time: float = positive(0.025)
    edge_clearance: float = non_negative(0.06)
    recovery_time: float = non_negative(0.4)
    recovery_gain: float = positive(2.5)
    min_speed: float = non_negative(0.5)
    lateral: float = positive(4.0)
    braking: float = positive(4.0)


class HoldSafetyFilter:
    """Replaces a command that is not safe to hold through an outage (module docstring).

    Parameters
    ----------
    track : Track
        The track raced, in the direction of increasing arc length.
    model : CarModel
        The car's model (its rollout).
    parameters : ParameterSet
        Its parameter values.
    steer_max : float
        Full lock, rad.
    torque_limits : tuple of float
        ``(torque_min, torque_max)``, normalised.
    top_speed : float
        Highest speed the car is driven at, m/s (the envelope never exceeds it).
    settings : ContingencySettings, optional
    """

    def __init__(
        self,
        track: Track,
        model: CarModel,
        parameters: ParameterSet,
        steer_max: float,
        torque_limits: tuple[float, float],
        top_speed: float,
        settings: ContingencySettings | None = None,
    ) -> None:
        self.settings = s = settings or ContingencySettings()
        self.bound = track.width / 2 - s.edge_clearance
        if not self.bound > 0:
            raise FieldError(
                "edge_clearance", f"must be below half the track's width, got {s.edge_clearance!r}"
            )
        self.steer_max = float(steer_max)
        self.torque_limits = (float(torque_limits[0]), float(torque_limits[1]))
        self.length = float(track.length)
        # the centreline, densely: the nearest sample gives arc length and signed offset
        n = max(math.ceil(self.length / GRID_STEP), 4)
        self._s = np.arange(n) * (self.length / n)
        x, y, heading, _ = track.interpolate(self._s)
        self._centre = np.column_stack((x, y))
        self._heading = np.asarray(heading, dtype=float)
        self._curvature = _curvature(self._heading, self.length / n)
        self._tree = cKDTree(self._centre)
        self.envelope = braking_envelope(track, s.lateral, s.braking, top_speed, s.edge_clearance)
        self._nx = model.nx
        self._model = model
        self._p = parameters.vector()
        holds = max(round(s.hold_time / s.sample_time), 0)
        coasts = max(round(s.coast_time / s.sample_time), 1)
        self._candidates = len(STEER_FRACTIONS) * 5  # see _candidate_commands
        values = dict(zip(parameters.names, self._p, strict=True))
        step = _lagged_step(model, s.sample_time, s.steering_time_constant)
        rollout = _rollout_function(step, model.nx, holds, coasts)
        recovery = _recovery_function(
            step,
            model,
            max(round(s.recovery_time / s.sample_time), 0),
            _RecoveryLaw(
                values["lf"] + values["lr"],
                self.steer_max,
                self.torque_limits[0],
                s.recovery_gain,
                s.min_speed,
            ),
        )
        # one command alone (the common case: it is safe), or the whole grid at once
        self._functions = {
            1: (rollout, recovery),
            self._candidates: (rollout.map(self._candidates), recovery.map(self._candidates)),
        }
        #: commands replaced so far
        self.replaced = 0

    def __call__(self, x: ArrayLike, u: ArrayLike, steering: float | None = None) -> np.ndarray:
        """Command ``u`` (2,) if it is safe to hold from state ``x`` (6 or more) with the car
        steering at ``steering`` rad now (default: ``u``'s angle), else the nearest safe one
        (steering and torque each relative to their range); ``u`` itself when none is (a car
        at the edge already is the MPCC's to bring back)."""
        state = np.asarray(x, dtype=float).ravel()[: self._nx]
        command = np.asarray(u, dtype=float).ravel()[:2]
        if self._speeds(state[:, None], command[:1])[0] < self.settings.min_speed:
            return command.copy()  # braking is always safe: filtered, a slow car stood at the edge
        angle = command[0] if steering is None else float(steering)
        if self.excess(state, command[None, :], angle)[0] <= 0.0:
            return command.copy()
        candidates = self._candidate_commands(command)
        safe = np.flatnonzero(self.excess(state, candidates, angle) <= 0.0)
        if safe.size == 0:  # nothing is safe (the car is at the edge already): the MPCC knows
            return command.copy()
        self.replaced += 1
        low, high = self.torque_limits
        change = ((candidates[safe, 0] - command[0]) / (2 * self.steer_max)) ** 2 + (
            (candidates[safe, 1] - command[1]) / (high - low)
        ) ** 2
        return candidates[safe[int(np.argmin(change))]].copy()

    def excess(
        self,
        x: NDArray[np.float64],
        commands: NDArray[np.float64],
        steering: float | None = None,
    ) -> np.ndarray:
        """Per command (rows of ``commands``, at most the filter's candidate count): the worst
        of how far its rollout from state ``x`` with the car steering at ``steering`` rad
        (default: each command's angle; held, coasting, driven back) leaves the bound (m) and
        how much faster than the braking envelope it is at the end of the coast (m/s, scaled
        to m by the sample time); <= 0 is safe."""
        count = commands.shape[0]
        width = 1 if count == 1 else self._candidates
        rollout, recovery = self._functions[width]
        U = np.zeros((2, width))
        U[:, :count] = commands.T
        X0 = np.tile(np.append(x, 0.0)[:, None], (1, width))
        X0[-1] = U[0] if steering is None else steering
        samples = np.asarray(rollout(X0, U, self._p), dtype=float)
        steps = samples.shape[1] // width
        states = samples.reshape(self._nx + 1, width, steps)[:, :count, :]
        s, lateral = self._project(states[0], states[1])
        outside = np.max(np.abs(lateral), axis=1) - self.bound
        ends = samples[:, steps - 1 :: steps]
        outside = np.maximum(outside, self._recovery_excess(recovery, ends, count))
        too_fast = self._speeds(states[: self._nx, :, -1], states[self._nx, :, -1])
        too_fast = too_fast - self.envelope(s[:, -1])
        return np.maximum(outside, too_fast * self.settings.sample_time)

    def _speeds(self, states: NDArray[np.float64], steering: ArrayLike) -> np.ndarray:
        """The car's speed (m/s) of each column of model ``states`` (nx x K) steering at
        ``steering`` rad (K,)."""
        angles = np.broadcast_to(np.asarray(steering, dtype=float), (states.shape[1],))
        inputs = np.column_stack((angles, np.zeros_like(angles)))
        car = self._model.numeric.car_states(states.T, inputs, self._p)
        return np.hypot(car[:, 3], car[:, 4])

    def _recovery_excess(
        self, recovery: ca.Function, ends: NDArray[np.float64], count: int
    ) -> np.ndarray:
        """How far each of the first ``count`` rollouts, from its end state (columns of
        ``ends``), leaves the bound while ``recovery`` drives it back, m (``-inf`` without a
        recovery check)."""
        if recovery.numel_out(0) == 0:
            return np.full(count, -np.inf)
        _, index = self._tree.query(ends[:2].T)
        reference = np.vstack((self._centre[index].T, self._heading[index], self._curvature[index]))
        recovered = np.asarray(recovery(ends, reference, self._p), dtype=float)
        width = ends.shape[1]
        states = recovered.reshape(self._nx + 1, width, -1)[:, :count, :]
        _, lateral = self._project(states[0], states[1])
        return np.max(np.abs(lateral), axis=1) - self.bound

    def _candidate_commands(self, command: NDArray[np.float64]) -> np.ndarray:
        """Every steering fraction with five torques: the command's, half a unit less, no
        throttle, half and full braking (within the limits); the command itself, found unsafe
        before the grid is asked for, is not among them."""
        low, high = self.torque_limits
        torque = float(command[1])
        torques = np.clip([torque, torque - 0.5, min(torque, 0.0), -0.5, -1.0], low, high)
        steer = STEER_FRACTIONS * self.steer_max
        return np.array([[d, t] for t in torques for d in steer])

    def _project(
        self, px: NDArray[np.float64], py: NDArray[np.float64]
    ) -> tuple[np.ndarray, np.ndarray]:
        """Arc length and signed offset (left positive) of the nearest centreline sample, for
        points ``px``, ``py`` of any shape."""
        _, index = self._tree.query(np.column_stack((px.ravel(), py.ravel())))
        heading = self._heading[index]
        dx, dy = px.ravel() - self._centre[index, 0], py.ravel() - self._centre[index, 1]
        lateral = -np.sin(heading) * dx + np.cos(heading) * dy
        return self._s[index].reshape(px.shape), lateral.reshape(px.shape)


class BrakingEnvelope:
    """The highest speed at each arc length from which braking reaches every corner ahead
    slowly enough (see :func:`braking_envelope`); called with arc lengths (m, any lap)."""

    def __init__(self, speed: NDArray[np.float64], length: float) -> None:
        self.speed = speed
        self.length = length
        self._step = length / speed.size

    def __call__(self, s: ArrayLike) -> NDArray[np.float64]:
        index = np.floor(
            np.mod(np.atleast_1d(np.asarray(s, dtype=float)), self.length) / self._step
        )
        return self.speed[index.astype(int) % self.speed.size]


def braking_envelope(
    track: Track, lateral: float, braking: float, top_speed: float, edge_clearance: float
) -> BrakingEnvelope:
    """The braking envelope of ``track``: corner speeds ``sqrt(lateral / |kappa|)`` (m/s^2 over
    the minimum-curvature line's curvature within ``edge_clearance`` m of the border), at
    most ``top_speed`` m/s, and a backward pass at ``braking`` m/s^2 round the lap twice."""
    length = float(track.length)
    n = max(math.ceil(length / GRID_STEP), 4)
    step = length / n
    line = minimum_curvature_line(track, max(track.width / 2 - edge_clearance, 0.0))
    curvature = np.interp(np.arange(n) * step, line.s, np.abs(line.curvature), period=length)
    speed = np.minimum(np.sqrt(lateral / np.maximum(curvature, 1e-9)), top_speed)
    rise = 2.0 * braking * step
    for k in range(2 * n - 1, -1, -1):
        i, ahead = k % n, (k + 1) % n
        speed[i] = min(speed[i], math.sqrt(speed[ahead] ** 2 + rise))
    return BrakingEnvelope(speed, length)


def _curvature(heading: NDArray[np.float64], step: float) -> np.ndarray:
    """Signed curvature (1/m, left positive) of a closed line from its headings (rad) at
    samples ``step`` m apart, smoothed over three samples."""
    turn = wrap_angle(np.roll(heading, -1) - heading) / step
    central = 0.5 * (turn + np.roll(turn, 1))
    return (np.roll(central, 1) + central + np.roll(central, -1)) / 3.0


@dataclass(frozen=True)
class _RecoveryLaw:
    """How the recovery drives: wheelbase (m), full lock (rad), the braking torque
    (normalised), the Stanley cross-track gain (1/s) and the speed below which it coasts
    (m/s)."""

    wheelbase: float
    steer_max: float
    braking_torque: float
    gain: float
    min_speed: float


def lag_decay(elapsed: float, lag: float) -> float:
    """What is left after ``elapsed`` s (>= 0) of a first-order lag of time constant ``lag`` s
    of the gap between an angle and its target (``lag = 0``: nothing)."""
    return math.exp(-max(elapsed, 0.0) / lag) if lag > 0 else 0.0


def _lagged_step(model: CarModel, step: float, lag: float) -> ca.Function:
    """``F(xs, target, torque, p)``: ``step`` s of the car, ``xs = [x; delta]`` with its
    steering angle ``delta`` following ``target`` as a first-order lag of ``lag`` s (the
    model driven with the angle's mean over the step; ``lag = 0``: the angle is the target)."""
    advance = model.step_function(SUBSTEPS, "contingency_step")
    xs, target, torque = ca.SX.sym("xs", model.nx + 1), ca.SX.sym("target"), ca.SX.sym("torque")
    decay = lag_decay(step, lag)
    mean_share = lag / step * (1.0 - decay) if lag > 0 else 0.0
    angle = xs[model.nx]
    mean = target + (angle - target) * mean_share
    x = advance(xs[: model.nx], ca.vertcat(mean, torque), model.p_sym, step)
    return ca.Function(
        "contingency_lagged_step",
        [xs, target, torque, model.p_sym],
        [ca.vertcat(x, target + (angle - target) * decay)],
    )


def _recovery_function(
    step: ca.Function, model: CarModel, steps: int, law: _RecoveryLaw
) -> ca.Function:
    """``recover(xs0, reference, p)``: the states ``[x; delta]`` after each of ``steps`` of the
    lagged ``step`` driving back to the track, ``(nx + 1, steps)``.

    ``reference`` is ``[x, y, heading, curvature]`` of the centreline point nearest ``xs0``;
    the track is taken as the circle arc through it with that curvature (a straight line at
    zero), and the car steers by the Stanley law along it: curvature feed-forward, minus the
    heading error, minus ``atan(gain * lateral / v)``, with full braking down to
    ``min_speed``."""
    nx = model.nx
    xs0, p = ca.SX.sym("xs0", nx + 1), ca.SX.sym("p", step.numel_in(3))
    reference = ca.SX.sym("reference", 4)
    cx, cy, heading, curvature = (reference[i] for i in range(4))
    xs, samples = xs0, []
    for _ in range(steps):
        car = model.car_state_function(xs[:nx], ca.vertcat(xs[nx], 0.0), p)
        dx, dy = car[0] - cx, car[1] - cy
        along = ca.cos(heading) * dx + ca.sin(heading) * dy
        left = -ca.sin(heading) * dx + ca.cos(heading) * dy
        # signed distance to the arc and the arc's direction there (exact for a circle; well
        # defined at zero curvature)
        bend = 1.0 - curvature * left
        lateral = (2.0 * left - curvature * (along**2 + left**2)) / (
            1.0 + ca.sqrt((curvature * along) ** 2 + bend**2)
        )
        track_heading = heading + ca.atan2(curvature * along, bend)
        error = ca.atan2(ca.sin(car[2] - track_heading), ca.cos(car[2] - track_heading))
        speed = ca.fmax(ca.sqrt(car[3] ** 2 + car[4] ** 2), 0.3)
        steer = ca.atan(law.wheelbase * curvature) - error - ca.atan(law.gain * lateral / speed)
        steer = ca.fmin(ca.fmax(steer, -law.steer_max), law.steer_max)
        torque = ca.if_else(car[3] > law.min_speed, law.braking_torque, 0.0)
        xs = step(xs, steer, torque, p)
        samples.append(xs)
    out = ca.horzcat(*samples) if samples else ca.SX(nx + 1, 0)
    return ca.Function("contingency_recovery", [xs0, reference, p], [out])


def _rollout_function(step: ca.Function, nx: int, holds: int, coasts: int) -> ca.Function:
    """``rollout(xs0, u, p)``: the states ``[x; delta]`` after each of ``holds`` lagged steps
    under ``u`` and ``coasts`` more with the steering of ``u`` and zero torque,
    ``(nx + 1, holds + coasts)``."""
    xs0, u, p = ca.SX.sym("xs0", nx + 1), ca.SX.sym("u", 2), ca.SX.sym("p", step.numel_in(3))
    xs, samples = xs0, []
    for k in range(holds + coasts):
        xs = step(xs, u[0], u[1] if k < holds else 0.0, p)
        samples.append(xs)
    return ca.Function("contingency_rollout", [xs0, u, p], [ca.horzcat(*samples)])
