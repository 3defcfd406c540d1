"""The MPCC racing through link outages, without middleware: what a held command does.

:func:`run_outage_loop` races the simulated car (:class:`~sim.simulator.Simulator` with its
onboard loop: the steering follows its reference through the steering PID and motor) around a
track with the MPCC at its control rate, and takes the link down for the given windows. While
the link is up the controller sees the true state and the car gets each command at once; while
it is down nothing gets through: the car holds the last command it got and, once none has come
for ``cut_off`` s, cuts its drive motor and coasts with the steering reference where it was
(the Chronos firmware); the host dead-reckons its state with its own commands and keeps
computing. The estimator, the transport and the sensors
are left out on purpose: this isolates what the command held through an outage does, which
no host-side measure can change once the link is down.

Used by ``crs bench contingency`` and the tests of the hold-safety filter
(:mod:`crs_core.control.contingency`).

Conventions: state ``[x_p, y_p, psi, v_x, v_y, omega]`` (m, rad, m/s, rad/s), command
``[delta, T]`` (rad, normalised torque), times in s from the start at rest on the start line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from crs_core.analysis.laps import LapCounter
from crs_core.control.mpcc import Mpcc
from crs_core.errors import FieldError
from sim.closed_loop import footprint_outside
from sim.onboard import OnboardSettings
from sim.sensors import SensorSuite
from sim.simulator import Simulator

__all__ = ["OutageRun", "random_outages", "run_outage_loop"]


@dataclass(frozen=True)
class OutageRun:
    """What an outage loop did.

    Attributes
    ----------
    off_track_s : float
        Time with a corner of the car's footprint outside the track, s (at the control ticks).
    episodes : int
        Separate spells off the track.
    lap_times : list of float
        Completed laps' durations, s (the first from rest).
    replaced : int
        Commands the hold-safety filter replaced (0 without it).
    """

    off_track_s: float
    episodes: int
    lap_times: list[float]
    replaced: int


def random_outages(
    duration: float, length: float, rng: np.random.Generator, first: float = 3.0
) -> np.ndarray:
    """Outage windows ``(k, 2)`` ``[start, end)`` of ``length`` s within ``duration`` s: the
    first after ``first`` s plus a uniform 3.5-6.5 s gap, then gaps of 3.5-6.5 s (a mean of
    5 s, the outages preset's period, at phases that move along the lap)."""
    starts = first + np.cumsum(rng.uniform(3.5, 6.5, size=max(int(duration / 3.5), 1)))
    starts = starts[starts < duration]
    return np.column_stack((starts, starts + length))


def run_outage_loop(
    mpcc: Mpcc,
    duration: float,
    outages: ArrayLike,
    hold_safe: bool,
    cut_off: float = 0.2,
) -> OutageRun:
    """Race ``duration`` s from rest on the start line through the link ``outages`` (windows
    ``[start, end)``, s) with ``mpcc`` (reset first), its commands hold-safe or not."""
    if not (math.isfinite(duration) and duration > 0):
        raise FieldError("duration", f"must be a finite number > 0 s, got {duration!r}")
    windows = np.asarray(outages, dtype=float).reshape(-1, 2)
    track = mpcc.path.track
    dt = mpcc.settings.dt
    mpcc.reset()
    x0, y0, heading, _ = (float(v) for v in track.interpolate(0.0))
    car = Simulator(mpcc.model, SensorSuite().ideal(), onboard=OnboardSettings()).session(
        np.array([x0, y0, heading, 0.0, 0.0, 0.0]), keep_history=False
    )
    host, held, last_received = car.base_state, np.zeros(2), 0.0
    model = mpcc.model
    reckoned = None  # the host's dead-reckoned model state through an outage (None: link up)
    laps = LapCounter(track.length)
    laps.update(0.0, track.project(x0, y0).s)  # on the line: the lap from rest starts
    replaced_before = mpcc.hold_safe_replaced
    t, off, episodes, was_off, s_hint = 0.0, 0.0, 0, False, None
    while t < duration:
        link_up = not np.any((t >= windows[:, 0]) & (t < windows[:, 1]))
        # the host sees the car while the link is up, else dead-reckons with its own commands
        if link_up:
            host, reckoned = car.base_state, None
        else:  # in the model's own state (not the car state for every model), from the last seen
            u = mpcc.last_command
            if reckoned is None:
                reckoned = model.initial_state(host, u)
            reckoned = model.numeric.step(reckoned, u, mpcc.p, dt)
            host = model.numeric.car_state(reckoned, u, mpcc.p)
        command = mpcc(host, None, dt, hold_safe)
        cut = last_received + cut_off  # the firmware's cut-off, if no command comes first
        if link_up:
            held, last_received = command.copy(), t
            car.command(held)
        elif t <= cut < t + dt:
            car.advance(cut)
            car.command(np.array([held[0], 0.0]))  # the drive motor off, the steering kept
        t += dt
        car.advance(t)
        state = car.base_state
        projection = track.project(state[0], state[1], s_hint)
        s_hint = projection.s
        laps.update(t, projection.s)
        outside = footprint_outside(track, state[0], state[1], state[2], s_hint) > 0
        off += dt if outside else 0.0
        episodes += int(outside and not was_off)
        was_off = outside
    return OutageRun(
        round(off, 3), episodes, list(laps.lap_times), mpcc.hold_safe_replaced - replaced_before
    )
