"""Closed loop without middleware: simulator, estimator and controller in one process.

:func:`run_closed_loop` drives the simulated car around a track: at every controller tick the
simulator is advanced, its new measurements go to the estimator (unless a Lighthouse blackout
is on), the controller acts on the estimate (or on the true state), and the command goes to
the car and, as the commanded input, to the estimator. Used by tests, ``crs bench control`` and
quick studies; the ROS 2 stack runs the same core objects as nodes.

The Lighthouse blackout of the benchmark starts each lap when the car passes a fixed arc length
and drops every Lighthouse sample for its duration (the paper's closed-loop test: 1.127 s).
A *boundary violation* is an episode in which a corner of the car's footprint
(:data:`CAR_LENGTH` x :data:`CAR_WIDTH`, centred on the centre of mass) is outside the track.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from tqdm import tqdm

from crs_core.analysis.laps import LapCounter
from crs_core.analysis.metrics import state_rmse
from crs_core.errors import FieldError
from crs_core.estimation.base import Estimator
from crs_core.measurements import InputSample
from crs_core.track import Track
from sim.simulator import Simulator

__all__ = ["CAR_LENGTH", "CAR_WIDTH", "ClosedLoopResult", "footprint_outside", "run_closed_loop"]

#: Footprint of a Chronos car (1:28 scale) for the boundary check, m.
CAR_LENGTH = 0.12
CAR_WIDTH = 0.07

#: ``controller(t, x) -> u``: the command for state ``x`` (6 base states) at time ``t``.
Controller = Callable[[float, np.ndarray], np.ndarray]
#: ``stop(x) -> u``: the safe command when there is no usable estimate.
StopPolicy = Callable[[np.ndarray | None], np.ndarray]


def footprint_outside(track: Track, x: float, y: float, yaw: float, s_hint: float | None) -> float:
    """How far the footprint's worst corner is outside the track, m (<= 0: inside)."""
    half = track.width / 2
    worst = -math.inf
    c, s = math.cos(yaw), math.sin(yaw)
    for dx, dy in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
        cx = x + c * dx * CAR_LENGTH / 2 - s * dy * CAR_WIDTH / 2
        cy = y + s * dx * CAR_LENGTH / 2 + c * dy * CAR_WIDTH / 2
        worst = max(worst, abs(track.project(cx, cy, s_hint).lateral_error) - half)
    return worst


@dataclass
class ClosedLoopResult:
    """A closed-loop run at the controller's ticks.

    Attributes
    ----------
    t : numpy.ndarray
        (n,) tick times, s.
    truth : numpy.ndarray
        (n, 6) true base state at the ticks.
    estimate : numpy.ndarray
        (n, 6) the state the controller acted on (the truth when run on it; NaN while lost).
    status : list of str
        Estimate status per tick (``ok``, ``degraded``, ``lost``; ``true`` on the truth).
    u : numpy.ndarray
        (n, 2) commands.
    solve_time_s : numpy.ndarray
        (n,) wall time of each controller call, s.
    controller_mode : list of str
        The controller's mode per tick when it reports one (MPCC: solved, fallback, stop).
    lateral_error : numpy.ndarray
        (n,) signed distance of the true centre of mass from the centreline, m (left +).
    outside : numpy.ndarray
        (n,) how far the footprint's worst corner is outside the track, m (<= 0 inside).
    lap_times_s : list of float
        Completed laps' times, s.
    blackouts : list of tuple
        ``(start, end)`` of each Lighthouse blackout, s.
    """

    t: np.ndarray
    truth: np.ndarray
    estimate: np.ndarray
    status: list[str]
    u: np.ndarray
    solve_time_s: np.ndarray
    controller_mode: list[str]
    lateral_error: np.ndarray
    outside: np.ndarray
    lap_times_s: list[float]
    blackouts: list[tuple[float, float]] = field(default_factory=list)

    @property
    def boundary_violations(self) -> int:
        """Episodes with a footprint corner outside the track."""
        out = self.outside > 0
        return int(np.count_nonzero(out[1:] & ~out[:-1]) + (1 if out.size and out[0] else 0))

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures of the run."""
        modes = {m: self.controller_mode.count(m) for m in sorted(set(self.controller_mode))}
        laps = self.lap_times_s
        summary = {
            "laps": len(laps),
            "lap_times_s": [round(v, 3) for v in laps],
            "mean_lap_s": round(float(np.mean(laps)), 3) if laps else None,
            "boundary_violations": self.boundary_violations,
            "max_outside_m": round(float(np.max(self.outside)), 4),
            "max_contouring_error_m": round(float(np.max(np.abs(self.lateral_error))), 4),
            "max_speed_mps": round(float(np.max(self.truth[:, 3])), 3),
            "mean_speed_mps": round(float(np.mean(self.truth[:, 3])), 3),
            "controller_modes": modes,
            "lost_ticks": self.status.count("lost"),
            "blackouts": len(self.blackouts),
        }
        usable = np.all(np.isfinite(self.estimate), axis=1)
        if "true" not in self.status and np.any(usable):
            rmse = state_rmse(self.estimate[usable], self.truth[usable])
            summary["estimation_rmse"] = {k: round(v, 5) for k, v in rmse.items()}
        return summary


def off_track(t: np.ndarray, x: np.ndarray, track: Track) -> dict[str, float | int]:
    """Time with the car's footprint (:data:`~sim.closed_loop.CAR_LENGTH` x
    :data:`~sim.closed_loop.CAR_WIDTH`) partly outside the track, from a true trajectory.

    Parameters
    ----------
    t : numpy.ndarray
        (n,) increasing stamps, s.
    x : numpy.ndarray
        (n, >= 3) true states ``[x, y, yaw, ...]``, m and rad.
    track : Track
        The track (its borders: half its width on each side of the centreline).

    Returns
    -------
    dict
        ``seconds``: total time with any corner outside (each sample holds until the next; the
        last one for the median sample period), s; ``max_outside_m``: the largest distance of a
        corner outside the border, m (0 when always inside); ``episodes``: separate spells
        outside.
    """
    t, x = np.asarray(t, dtype=float), np.asarray(x, dtype=float)
    if t.size == 0:
        return {"seconds": 0.0, "max_outside_m": 0.0, "episodes": 0}
    # a corner is at most this far from the centre of mass, so a footprint whose centre is
    # further than this inside the border is inside (the distance to the centreline is
    # 1-Lipschitz): only those samples need the four corners projected
    reach = math.hypot(CAR_LENGTH / 2, CAR_WIDTH / 2)
    outside = np.zeros(t.size)
    s_hint = None
    for k in range(t.size):
        projection = track.project(x[k, 0], x[k, 1], s_hint)
        s_hint = projection.s
        if abs(projection.lateral_error) + reach > track.width / 2:
            outside[k] = footprint_outside(track, x[k, 0], x[k, 1], x[k, 2], s_hint)
        else:
            outside[k] = -1.0
    dt = np.diff(t)
    hold = np.append(dt, np.median(dt) if dt.size else 0.0)
    out = outside > 0
    starts = np.flatnonzero(out & ~np.concatenate(([False], out[:-1])))
    return {
        "seconds": round(float(np.sum(hold[out])), 3),
        "max_outside_m": round(float(max(outside.max(), 0.0)), 4),
        "episodes": int(starts.size),
    }


def run_closed_loop(
    simulator: Simulator,
    track: Track,
    controller: Controller,
    stop: StopPolicy,
    rate_hz: float,
    *,
    laps: int = 5,
    max_duration: float = 60.0,
    estimator: Estimator | None = None,
    blackout_s: float = 0.0,
    blackout_at: float = 0.5,
    progress: bool = False,
    status_of: Callable[[], str] | None = None,
    command_mode: str = "torque",
) -> ClosedLoopResult:
    """Race ``laps`` laps (or ``max_duration`` s) from the track's start line at rest.

    Parameters
    ----------
    simulator : Simulator
        The simulated car (truth model and sensors).
    track : Track
        The track; laps are counted at its start line.
    controller, stop : callable
        ``controller(t, x) -> u`` and the safe ``stop(x) -> u`` used while the estimate is lost.
    rate_hz : float
        Controller rate, Hz.
    laps : int
        Laps to complete before stopping.
    max_duration : float
        Longest run, s.
    estimator : Estimator, optional
        Acts on the estimate of this estimator (started at the true initial pose); on the true
        state when None.
    blackout_s : float
        Lighthouse blackout per lap, s (0: none); it starts when the car passes
        ``blackout_at * track.length`` of arc length.
    progress : bool
        Show a progress bar.
    status_of : callable, optional
        Returns the controller's mode after a call (e.g. ``lambda: mpcc.status.mode``).
    command_mode : {"torque", "velocity"}
        ``velocity``: the commands are ``[delta, v_x]`` references for the car's onboard loop
        (the simulator needs ``onboard`` settings; the estimator, if any, then runs without
        commands, as it cannot know the torque the loop applies).
    """
    for name, value in (("rate_hz", rate_hz), ("max_duration", max_duration)):
        if not value > 0:
            raise FieldError(name, f"must be positive, got {value!r}")
    if laps < 1:
        raise FieldError("laps", f"must be at least 1, got {laps!r}")
    x0 = track.start_state()
    session = simulator.session(x0, keep_history=False)
    if estimator is not None:
        estimator.reset(0.0, x0)
    counter = LapCounter(track.length)
    dt = 1.0 / rate_hz
    records: dict[str, list] = {
        key: []
        for key in ("t", "truth", "estimate", "status", "u", "time", "mode", "lat", "outside")
    }
    blackouts: list[tuple[float, float]] = []
    blackout_until = -math.inf
    s_hint: float | None = None
    next_blackout_lap = 0
    with tqdm(total=laps, unit="lap", disable=not progress, leave=False) as bar:
        for k in range(int(max_duration * rate_hz) + 1):
            t = k * dt
            for measurement in session.advance(t):
                if estimator is None:
                    continue
                if (
                    measurement.sensor.startswith("lighthouse")
                    and measurement.stamp < blackout_until
                ):
                    continue
                estimator.add_measurement(measurement)
            truth = session.base_state
            projection = track.project(truth[0], truth[1], s_hint)
            s_hint = projection.s
            counter.update(t, projection.s)
            if (
                blackout_s > 0
                and counter.laps_completed >= next_blackout_lap
                and counter.progress - next_blackout_lap * track.length
                >= blackout_at * track.length
            ):
                blackout_until = t + blackout_s
                blackouts.append((t, blackout_until))
                next_blackout_lap += 1
            if estimator is None:
                state, status = truth, "true"
            else:
                estimate = estimator.estimate(t)
                status = estimate.status
                state = estimate.x if status != "lost" else None
            started = time.perf_counter()
            u = controller(t, state) if state is not None else stop(None)
            elapsed = time.perf_counter() - started
            session.command(u, mode=command_mode)
            if estimator is not None and command_mode == "torque":
                estimator.add_input(InputSample(t, np.asarray(u, dtype=float)))
            records["t"].append(t)
            records["truth"].append(truth)
            records["estimate"].append(state if state is not None else np.full(6, np.nan))
            records["status"].append(status)
            records["u"].append(np.asarray(u, dtype=float))
            records["time"].append(elapsed)
            records["mode"].append(status_of() if status_of else "")
            records["lat"].append(projection.lateral_error)
            records["outside"].append(footprint_outside(track, *truth[:3], s_hint))
            bar.n = counter.laps_completed
            bar.refresh()
            if counter.laps_completed >= laps:
                break
    return ClosedLoopResult(
        t=np.array(records["t"]),
        truth=np.array(records["truth"]),
        estimate=np.array(records["estimate"]),
        status=records["status"],
        u=np.array(records["u"]),
        solve_time_s=np.array(records["time"]),
        controller_mode=records["mode"],
        lateral_error=np.array(records["lat"]),
        outside=np.array(records["outside"]),
        lap_times_s=list(counter.lap_times),
        blackouts=blackouts,
    )
