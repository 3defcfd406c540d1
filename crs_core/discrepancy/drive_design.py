r"""The design of drives that decide between parameters the data leave open (issue 40).

Racing data fix each axle's cornering stiffness :math:`D C B` but leave the tyre's peak
:math:`D` and shape :math:`B` on a ridge; a motor lag hides in smooth throttle. A drive that
decides loads the tyres past the linear range (yaw transients) and steps the torque, while it
stays on the track and where the Lighthouse sees the car.

The drive (:mod:`crs_core.discrepancy.drive_file`) is the path follower plus command offsets
held over equal segments. :func:`design_drive` chooses the offsets: each candidate is driven
with the model (closed loop, the model's compiled RK4 step, :func:`rollout`), sampled like a
recording, and its information is the FIE's, predicted
(:mod:`crs_core.discrepancy.drive_information`): from the prior covariance of the fitted
parameters (the model's prior, or the covariance a race's identification reported) to the
covariance after the drive. The criterion is D-optimal over the open parameters: the
``log det`` of their marginal covariance after the drive (the other fitted parameters
refitted: the open block of the full covariance, the inverse of the information's Schur
complement), in units of their prior sigmas, plus penalties for leaving the track (the
centreline's distance beyond ``width / 2 - track_margin``), the Lighthouse's view and a speed
floor. L-BFGS-B with finite differences minimises it from a fast square wave of steering and
torque (:func:`square_waves`), within a budget of simulated drives.

What it is not: the design is local (at the model's values; a truth far from them would be
excited differently) and the prediction is the Laplace covariance (the curvature of the FIE's
cost), not the spread of the estimates.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.optimize import minimize

from crs_core.discrepancy.drive_file import Drive, DriveController, DriveLimits
from crs_core.discrepancy.drive_information import (
    LIGHTHOUSE_VIEW_LIMIT,
    DriveInformation,
    DriveSamples,
    log_det,
    marginal_covariance,
)
from crs_core.discrepancy.hypotheses import extended_model
from crs_core.errors import FieldError
from crs_core.estimation.noise import EstimatorNoise
from crs_core.identification.data import Y_LAYOUT
from crs_core.identification.problem import check_fit, default_fit, prior_std
from crs_core.model import CarModel
from crs_core.model.effects import EFFECTS, effect_of_parameter
from crs_core.track import Track

#: The searches of :func:`design_drive`.
SEARCHES = ("lbfgsb", "spsa")
#: Weight of each penalty, in units of the criterion (log det of prior sigmas).
PENALTY_WEIGHT = 20.0
#: Track excess (m) that costs one penalty weight when held over the whole drive.
TRACK_SCALE = 0.01
#: Speed shortfall (m/s) below the floor that costs one penalty weight over the whole drive.
SPEED_SCALE = 0.1


@dataclass(frozen=True)
class DesignSettings:
    """What :func:`design_drive` designs and how hard it searches.

    Attributes
    ----------
    duration_s : float
        The drive's length, s.
    segment_s : float
        Each offset held this long, s.
    v_ref : float
        The follower's speed reference, m/s.
    a_lat_max : float
        The follower's lateral-acceleration limit, m/s^2.
    steer_offset_max, torque_offset_max : float
        Bounds of the offsets (rad, normalised torque).
    limits : DriveLimits
        Command limits.
    track_margin : float
        The car's centre stays this far inside each track edge, m (0.07: the half diagonal of
        a Chronos's 0.12 x 0.07 m footprint, so no corner leaves the track whatever the yaw;
        0.05 let the emulated car's footprint out by 9 mm).
    min_speed : float
        Speed floor, m/s (slip angles are defined at speed).
    sample_period : float
        Interval of the recording's samples (the Lighthouse's), s.
    process_scale : float
        The FIE's process-noise scale (1 on real data, 0.1 on simulated).
    view_limit : float
        Sweep angles beyond this are out of the base station's view, rad.
    starts : int
        Searches, one after the other within the budget: from the fastest square wave of
        :func:`square_waves` (a quarter of the bounds, torque in phase), then from the
        best-scoring of the other square waves and seeded random offsets.
    search : {"lbfgsb", "spsa"}
        The search from each start: L-BFGS-B with finite differences (one drive per offset
        and step; the better one on the bench's race: criterion -2.1 against -1.5 at 400
        drives) or simultaneous-perturbation gradient steps (two drives a step whatever the
        number of offsets).
    evaluations : int
        Budget of simulated drives over all starts (each about 0.2 s on one core).
    seed : int
    start : (x, y, yaw, vx), optional
        Where the drive begins (m, m, rad, m/s; world pose, forward speed); default the track's
        start pose at ``v_ref``.
    """

    duration_s: float = 8.0
    segment_s: float = 0.25
    v_ref: float = 1.2
    a_lat_max: float = 4.0
    steer_offset_max: float = 0.34
    torque_offset_max: float = 0.6
    limits: DriveLimits = field(default_factory=DriveLimits)
    track_margin: float = 0.07
    min_speed: float = 0.3
    sample_period: float = 1.0 / 45.0
    process_scale: float = 1.0
    view_limit: float = LIGHTHOUSE_VIEW_LIMIT
    starts: int = 1
    search: str = "lbfgsb"
    evaluations: int = 400
    seed: int = 0
    start: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if self.search not in SEARCHES:
            raise FieldError("search", f"one of {', '.join(SEARCHES)}, got {self.search!r}")
        if self.starts < 1 or self.evaluations < 1:
            raise FieldError("starts", "starts and evaluations must be >= 1")


@dataclass
class DriveDesign:
    """A drive and what it is predicted to tell.

    Attributes
    ----------
    drive : Drive
    samples : DriveSamples, the drive driven with the model
    lateral_error : (N,) distance from the centreline, m (left positive)
    fit, open : the fitted and the open parameters' names
    covariance_before, covariance_after : (n, n) of ``fit``, the parameters' units
    criterion : log det of the open parameters' marginal covariance after the drive, in
        their prior sigmas (lower is better)
    penalty : the track, view and speed penalties of the criterion
    evaluations : drives simulated by the design
    """

    drive: Drive
    samples: DriveSamples
    lateral_error: np.ndarray
    fit: tuple[str, ...]
    open: tuple[str, ...]
    covariance_before: np.ndarray
    covariance_after: np.ndarray
    criterion: float
    penalty: float
    evaluations: int = 1

    def sigma(self, after: bool = True) -> dict[str, float]:
        """The open parameters' sigma before or after the drive, the parameters' units."""
        cov = self.covariance_after if after else self.covariance_before
        block = marginal_covariance(cov, self.fit, self.open)
        return {n: float(math.sqrt(max(block[i, i], 0.0))) for i, n in enumerate(self.open)}


def with_open_effects(model: CarModel, names: Sequence[str]) -> CarModel:
    """``model`` with the registry effects owning those of ``names`` it lacks switched on at
    their prior (default) values; :class:`FieldError` (field ``open``) for a name that is no
    model parameter and no effect's."""
    added: list[str] = []
    for name in names:
        if name in model.parameters.names:
            continue
        owner = effect_of_parameter(name)
        if owner is None:
            raise FieldError(
                "open",
                f"unknown parameter {name!r} (not a model parameter nor an effect's; "
                f"effects: {', '.join(EFFECTS)})",
            )
        if owner not in added:
            added.append(owner)
    if not added:
        return model
    defaults = {p.name: p.value for e in added for p in EFFECTS[e].parameters}
    return extended_model(model, added, defaults)


def planned_fit(model: CarModel, open_names: Sequence[str] = ()) -> tuple[str, ...]:
    """``crs sysid``'s default fit (:func:`~crs_core.identification.problem.default_fit`)
    plus any open name it lacks."""
    names = default_fit(model)
    return names + tuple(n for n in open_names if n not in names)


def prior_covariance(model: CarModel, fit: Sequence[str]) -> np.ndarray:
    """The FIE's prior covariance of ``fit``: diagonal, each ``prior_std`` squared."""
    return np.diag([prior_std(model, n) ** 2 for n in fit])


def prior_from(
    model: CarModel,
    fit: Sequence[str],
    names: Sequence[str],
    std: Sequence[float],
    correlation: np.ndarray | None = None,
) -> np.ndarray:
    """A prior covariance of ``fit`` from an identification's ``names``, their ``std`` (the
    parameters' units) and ``correlation`` (default none): the entries of ``fit`` the
    identification lacks (an open effect added since) keep the model's prior, uncorrelated."""
    cov = prior_covariance(model, fit)
    names = list(names)
    sigma = np.asarray(std, dtype=float)
    rho = np.eye(len(names)) if correlation is None else np.asarray(correlation, dtype=float)
    if rho.shape != (len(names), len(names)):
        raise FieldError("correlation", f"must be {len(names)} x {len(names)}, got {rho.shape}")
    if not (np.all(np.isfinite(sigma)) and np.all(sigma > 0)):
        raise FieldError("std", "must be positive finite numbers")
    both = [n for n in fit if n in names]
    i = [list(fit).index(n) for n in both]
    j = [names.index(n) for n in both]
    cov[np.ix_(i, i)] = rho[np.ix_(j, j)] * np.outer(sigma[j], sigma[j])
    scale = np.sqrt(np.diag(cov))
    unit = cov / np.outer(scale, scale)
    lowest = float(np.linalg.eigvalsh(unit).min())
    if lowest < 1e-9:  # correlations rounded (result.json's 4 digits): lift to definite
        unit += (1e-9 - lowest) * np.eye(len(fit))
    return unit * np.outer(scale, scale)


def rollout(
    model: CarModel, drive: Drive, track: Track, sample_period: float, view_limit: float
) -> tuple[DriveSamples, np.ndarray]:
    """Drive ``drive`` with ``model`` (closed loop, noise-free) from its start; samples every
    ``sample_period`` s and the distance from the centreline (m) at each."""
    p = model.parameters.vector()
    wheelbase = model.parameters.value("lf") + model.parameters.value("lr")
    controller = DriveController(drive, track, wheelbase)
    sx, sy, syaw, svx = drive.start
    n = round(drive.duration_s / sample_period)
    x = model.initial_state([sx, sy, syaw, svx, 0.0, 0.0])
    numeric = model.numeric
    xs, us, lateral = np.zeros((n, model.nx)), np.zeros((n, 2)), np.zeros(n)
    for k in range(n):
        u = controller(k * sample_period, x)
        xs[k], us[k], lateral[k] = x, u, controller.lateral_error
        x = np.asarray(numeric.step(x, u, p, sample_period)).ravel()
        if not np.all(np.isfinite(x)):
            x = xs[k]
    t = np.arange(n) * sample_period
    angles = []
    for sensor, _ in Y_LAYOUT[:2]:
        out = model.output_function(sensor).map(n)(xs.T, us.T, np.repeat(p[:, None], n, 1))
        angles.append(np.asarray(out))
    sweeps = np.vstack(angles)
    in_view = np.all(np.isfinite(sweeps) & (np.abs(sweeps) <= view_limit), axis=0)
    measured = np.ones((n, 13), dtype=bool)
    measured[:, :8] = in_view[:, None]
    return DriveSamples(t, xs, us, measured, in_view), lateral


def penalty(
    samples: DriveSamples, lateral: np.ndarray, track: Track, settings: DesignSettings
) -> float:
    """Track, view and speed penalties of a driven drive (criterion units)."""
    half = float(np.min(track.width)) / 2 - settings.track_margin
    excess = np.clip(np.abs(lateral) - half, 0.0, None) / TRACK_SCALE
    slow = np.clip(settings.min_speed - samples.x[:, 3], 0.0, None) / SPEED_SCALE
    out = 1.0 - samples.in_view.astype(float)
    return PENALTY_WEIGHT * float(np.mean(excess**2) + np.mean(out) + np.mean(slow**2))


def evaluate_drive(
    model: CarModel,
    drive: Drive,
    fit: Sequence[str],
    open_names: Sequence[str],
    prior: np.ndarray,
    track: Track,
    settings: DesignSettings,
    information: DriveInformation | None = None,
) -> DriveDesign:
    """Drive ``drive`` with ``model`` and predict the covariance after it from ``prior``."""
    fit, open_names = tuple(fit), tuple(open_names)
    information = information or DriveInformation(
        model, fit, settings.sample_period, EstimatorNoise(), settings.process_scale
    )
    samples, lateral = rollout(model, drive, track, settings.sample_period, settings.view_limit)
    after = information.posterior_covariance(samples, prior)
    scale = np.sqrt(np.diag(marginal_covariance(prior, fit, open_names)))
    block = marginal_covariance(after, fit, open_names) / np.outer(scale, scale)
    cost = penalty(samples, lateral, track, settings)
    return DriveDesign(drive, samples, lateral, fit, open_names, prior, after, log_det(block), cost)


def base_drive(settings: DesignSettings, open_names: Sequence[str], track: Track) -> Drive:
    """A drive of the settings' length with zero offsets from the settings' start (default
    the track's start pose at the speed reference)."""
    n = max(1, round(settings.duration_s / settings.segment_s))
    start = settings.start or track.start_state(settings.v_ref)
    return Drive(
        duration_s=settings.duration_s,
        segment_s=settings.segment_s,
        v_ref=settings.v_ref,
        a_lat_max=settings.a_lat_max,
        steer_offset=(0.0,) * n,
        torque_offset=(0.0,) * n,
        open=tuple(open_names),
        limits=settings.limits,
        start=(float(start[0]), float(start[1]), float(start[2]), float(start[3])),
    )


def slalom_drive(
    settings: DesignSettings,
    open_names: Sequence[str],
    track: Track,
    amplitude: float,
    frequency_hz: float = 1.0,
) -> Drive:
    """A slalom of the settings' length: the follower plus ``amplitude`` (rad) of steering
    sine at ``frequency_hz``, sampled every 0.05 s, no torque offset."""
    step = 0.05
    n = max(1, round(settings.duration_s / step))
    times = (np.arange(n) + 0.5) * step
    steer = amplitude * np.sin(2 * np.pi * frequency_hz * times)
    plain = base_drive(replace(settings, segment_s=step), open_names, track)
    return replace(plain, kind="slalom", steer_offset=tuple(steer), torque_offset=(0.0,) * n)


def _spsa(
    objective: Callable[[np.ndarray], float],
    v0: np.ndarray,
    iterations: int,
    rng: np.random.Generator,
    step: float = 0.05,
    probe: float = 0.05,
) -> np.ndarray:
    """Simultaneous-perturbation gradient descent in the box ``[-1, 1]``: each iteration two
    drives (``v ± probe * delta``, ``delta`` random signs) estimate the gradient, whose first
    and second moments (Adam's) scale a step of about ``step``. The best drive is kept by the
    objective's caller; returns the last iterate."""
    v = np.asarray(v0, dtype=float).copy()
    first, second = np.zeros_like(v), np.zeros_like(v)
    for k in range(1, iterations + 1):
        delta = rng.choice([-1.0, 1.0], size=v.size)
        up = objective(np.clip(v + probe * delta, -1.0, 1.0))
        down = objective(np.clip(v - probe * delta, -1.0, 1.0))
        gradient = (up - down) / (2.0 * probe) * delta
        first = 0.9 * first + 0.1 * gradient
        second = 0.999 * second + 0.001 * gradient**2
        unbiased = first / (1 - 0.9**k), second / (1 - 0.999**k)
        v = np.clip(v - step * unbiased[0] / (np.sqrt(unbiased[1]) + 1e-12), -1.0, 1.0)
    return v


def square_waves(segments: int) -> list[np.ndarray]:
    """Candidate starts of the search (offsets in units of their bounds): steering square
    waves of half periods 1, 2 and 4 segments at a quarter and a half of the bound, the torque
    offset none, in phase or against it at the same share (the second: half period 1, a
    quarter, torque in phase)."""
    out = []
    for half in (1, 2, 4):
        wave = (-1.0) ** (np.arange(segments) // half)
        for amplitude in (0.25, 0.5):
            for torque in (0.0, 1.0, -1.0):
                out.append(amplitude * np.concatenate([wave, torque * wave]))
    return out


def design_drive(
    model: CarModel,
    fit: Sequence[str],
    open_names: Sequence[str],
    prior: np.ndarray,
    track: Track,
    settings: DesignSettings | None = None,
    progress: Callable[[int, float], None] | None = None,
) -> DriveDesign:
    """The drive of :class:`DesignSettings`' length whose offsets minimise the D-optimal
    criterion plus penalties (module docstring), from ``prior`` (``(n, n)`` of ``fit``): the
    best drive the search found without a penalty (on the track, in view, at speed), else the
    best with one.

    ``model`` must have every open parameter (:func:`with_open_effects`); ``progress`` is
    called with the evaluation count and the best objective so far."""
    settings = settings or DesignSettings()
    fit, open_names = tuple(fit), tuple(open_names)
    missing = [n for n in (*fit, *open_names) if n not in model.parameters.names]
    if missing:
        raise FieldError("open", f"the model lacks {', '.join(missing)}")
    if not set(open_names) <= set(fit):
        raise FieldError("open", "every open parameter must be fitted")
    check_fit(model, fit)  # what the FIE cannot fit, no drive decides
    information = DriveInformation(
        model, fit, settings.sample_period, EstimatorNoise(), settings.process_scale
    )
    plain = base_drive(settings, open_names, track)
    n = plain.segments
    bounds = np.array([settings.steer_offset_max] * n + [settings.torque_offset_max] * n)
    best: list[Any] = [np.inf, None]
    feasible: list[Any] = [np.inf, None]  # the best drive without a penalty
    count = [0]

    class _BudgetSpentError(Exception):
        pass

    def drive_of(v: np.ndarray) -> Drive:
        offsets = np.clip(v, -1.0, 1.0) * bounds
        return plain.with_offsets(offsets[:n], offsets[n:])

    def objective(v: np.ndarray) -> float:
        result = evaluate_drive(
            model, drive_of(v), fit, open_names, prior, track, settings, information
        )
        value = result.criterion + result.penalty
        count[0] += 1
        if count[0] > settings.evaluations:
            raise _BudgetSpentError
        if value < best[0]:
            best[0], best[1] = value, result
        if result.penalty == 0.0 and value < feasible[0]:
            feasible[0], feasible[1] = value, result
        if progress is not None:
            progress(count[0], best[0])
        return value

    # the first start: the fastest square wave the segments allow, a quarter of the bounds,
    # torque in phase (steps of steering and torque excite the yaw transients and the motor);
    # further starts: the best-scoring of the other square waves and seeded random offsets
    waves = square_waves(n)
    starts = [waves[1]]
    if settings.starts > 1:
        rng = np.random.default_rng(settings.seed)
        others = waves[:1] + waves[2:] + [rng.uniform(-0.4, 0.4, 2 * n) for _ in range(4)]
        try:
            scores = [objective(v) for v in others]
        except _BudgetSpentError:
            scores = []
        starts += [others[i] for i in np.argsort(scores)[: settings.starts - 1]]
    rng = np.random.default_rng(settings.seed)
    for v0 in starts:
        left = settings.evaluations - count[0]
        if left <= 0:
            break
        try:
            if settings.search == "spsa":
                _spsa(objective, v0, left // 2, rng)
            else:
                minimize(
                    objective,
                    v0,
                    method="L-BFGS-B",
                    bounds=[(-1.0, 1.0)] * (2 * n),
                    options={"maxfun": left, "eps": 0.03},
                )
        except _BudgetSpentError:
            break
    design: DriveDesign = feasible[1] if feasible[1] is not None else best[1]
    design.evaluations = min(count[0], settings.evaluations)
    return design
