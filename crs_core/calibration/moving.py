r"""Moving calibration: base stations (and clock offset, photodiodes) from a driven recording.

Input: a dataset (:mod:`crs_core.dataset`) with Lighthouse sweeps and a pose reference, the
motion-capture ``pose`` sensor of ``stream.npz``. Sweeps come from ``stream.npz``
(``lighthouse/<s>/<l>``, each plane at its own stamp) or, without them, from ``y.npy`` (station
0, both planes at the sample stamp). Inputs, IMU and encoders are not used and may be absent.

No prior station geometry is needed: the stations are those the sweeps name, and the
dataset's geometry need only give the photodiodes (``geometry: {photodiodes: ...}``,
:class:`~crs_core.dataset.Geometry` with ``base_stations`` None). Where it does give stations,
their factory tilt offsets are used (and nothing else of them).

Model: the sweep stamped :math:`t` (car clock) was taken at the reference pose stamped
:math:`t + \tau` (motion-capture clock), :math:`\tau` = ``offset`` (s); the reference pose is
a cubic smoothing spline through the motion-capture samples (yaw unwrapped;
:class:`ReferenceTrajectory`), so :math:`\partial q / \partial \tau` is the spline's
derivative. Unknowns: every station's pose
(:mod:`crs_core.calibration.solver`), optionally :math:`\tau` and the photodiode positions,
and the tilt offsets ``dt1, dt2`` of every station the geometry gives none for (of every
station with ``fit_tilt``); residuals: every photodiode angle of every sweep, ``soft_l1`` loss
(scale 5 mrad: quadratic for 1 mrad noise, linear for stray sweeps).

Tilt offsets are not optional: held at 0 instead of the recorded station's -0.051/+0.046 rad
they move its fitted position by 0.2 m (the residuals grow from 1 to 22 mrad), and fitted from
0 they come back within 0.1 mrad (one-sigma 0.05 mrad) with the station as accurate as with the
true values (simulated 12 s recordings). They are weakest (one-sigma a few mrad, the position's
a few mm) for a station whose spin axis is near the floor normal, a station standing upright
low beside the track: there the symmetric tilt trades off against the distance, as a camera's
focal length does for a target seen face on. The reported one-sigma says so.

Start: per station a closed-form pose from up to 400 plane pairs
(:func:`~crs_core.calibration.sweep_model.start_station`: planar DLT, unknown tilts started
from its homography). With ``fit_offset``, a coarse scan of :math:`\tau` over
``[-max_offset, max_offset]`` in 10 ms steps, each offset with closed-form stations of its own,
picks the basin (no station prior is needed for it; a start at offset 0 when the true one is
0.1-0.15 s puts the pose 10-15 cm and the station 0.25-0.5 m off, which the fit may not recover
from);
else the given offset is used. Then a station-only fit there (unknown tilts free), a fine scan
of :math:`\tau` in 2 ms steps with those stations, and the joint fit. A fit that ends with
sweeps its stations cannot produce (a photodiode outside a light plane) has not converged and
is refused (``lighthouse``). Sweeps whose :math:`t \pm` ``max_offset`` leaves the reference,
or that fall in a reference gap longer than 50 ms, are dropped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_smoothing_spline

from crs_core.calibration.solver import FitResult, LighthouseFit, Observations
from crs_core.calibration.sweep_model import SweepModel, start_station
from crs_core.dataset import Dataset
from crs_core.errors import FieldError
from crs_core.measurements import parse_lighthouse
from crs_core.model.lighthouse import BaseStation

#: Largest gap in the pose reference a sweep may fall in, s.
MAX_REFERENCE_GAP = 0.05
#: Plane pairs used for the closed-form start.
START_PAIRS = 400
#: Step of the clock-offset scan with the start fit's stations, s.
OFFSET_STEP = 0.002
#: Step of the coarse clock-offset scan with closed-form stations per offset, s.
COARSE_OFFSET_STEP = 0.01
#: Scale of the robust loss, rad.
LOSS_SCALE = 5e-3


@dataclass(frozen=True)
class Recording:
    """What moving calibration reads from a dataset.

    Attributes
    ----------
    stamps : (K,) sweep stamps, s (car clock).
    observations : the sweeps (station, plane, 4 angles).
    pose_t : (M,) reference stamps, s (motion-capture clock).
    pose : (M, 3) reference poses x, y (m), yaw (rad, unwrapped).
    n_stations : stations named by the sweeps (1 + the largest index).
    """

    stamps: np.ndarray
    observations: Observations
    pose_t: np.ndarray
    pose: np.ndarray
    n_stations: int


def read_recording(dataset: Dataset) -> Recording:
    """Sweeps and pose reference of ``dataset``; ``ValueError`` naming what is missing."""
    measurements = dataset.measurements or []
    parsed = [(m, parse_lighthouse(m.sensor)) for m in measurements]
    sweeps = [(m, key) for m, key in parsed if key is not None]
    if sweeps:
        stamps = np.array([m.stamp for m, _ in sweeps])
        station = np.array([key[0] for _, key in sweeps])
        plane = np.array([key[1] for _, key in sweeps])
        angles = np.stack([m.values for m, _ in sweeps])
    else:
        rows = np.all(np.isfinite(dataset.y[:, :8]), axis=1)
        if not rows.any():
            raise FieldError(
                "lighthouse",
                "the dataset has no Lighthouse sweeps (stream.npz "
                "meas:lighthouse__<s>__<l> or finite y.npy rows 0-7)",
            )
        t = dataset.t[rows]
        stamps = np.concatenate([t, t])
        station = np.zeros(2 * t.size, dtype=int)
        plane = np.repeat([1, 2], t.size)
        angles = np.vstack([dataset.y[rows, 0:4], dataset.y[rows, 4:8]])
    reference = sorted((m for m in measurements if m.sensor == "pose"), key=lambda m: m.stamp)
    if len(reference) < 10:
        raise FieldError(
            "pose",
            "the dataset has no motion-capture pose reference (stream.npz meas:pose:t and "
            f"meas:pose:v with at least 10 samples; found {len(reference)})",
        )
    pose_t = np.array([m.stamp for m in reference])
    keep = np.concatenate([[True], np.diff(pose_t) > 0])
    pose_t = pose_t[keep]
    pose = np.stack([m.values for m in reference])[keep]
    pose[:, 2] = np.unwrap(pose[:, 2])
    order = np.argsort(stamps, kind="stable")
    return Recording(
        stamps[order],
        Observations(station[order].astype(int), plane[order].astype(int), angles[order]),
        pose_t,
        pose,
        int(station.max()) + 1,
    )


@dataclass(frozen=True)
class MovingCalibration:
    """Result of :func:`calibrate_moving`.

    Attributes
    ----------
    fit : the least-squares result (stations, photodiodes, residuals, std).
    offset : clock offset (motion capture minus car), s.
    offset_std : its one-sigma, s (0 when not fitted).
    recording : the sweeps used (after dropping those outside the reference).
    start : closed-form start stations.
    scan : (offsets, cost) of the offset scan (empty when not fitted).
    reference : the smoothed pose reference (motion-capture clock).
    """

    fit: FitResult
    offset: float
    offset_std: float
    recording: Recording
    start: tuple[BaseStation, ...]
    scan: tuple[np.ndarray, np.ndarray]
    reference: ReferenceTrajectory

    @property
    def stations(self) -> tuple[BaseStation, ...]:
        return self.fit.stations

    def reference_pose(self, stamps: np.ndarray) -> np.ndarray:
        """Reference pose (N, 3) at car-clock ``stamps`` with the fitted offset."""
        return self.reference(np.asarray(stamps, dtype=float) + self.offset)


def calibrate_moving(
    dataset: Dataset,
    fit_offset: bool = True,
    fit_photodiodes: bool = False,
    fit_tilt: bool = False,
    max_offset: float = 0.25,
    offset: float = 0.0,
    sweep_model: SweepModel | None = None,
) -> MovingCalibration:
    """Fit the stations of a recording with a pose reference (module docstring).

    Parameters
    ----------
    dataset : sweeps and the motion-capture ``pose`` sensor; its geometry gives the
        photodiodes (body frame, m) and, optionally, stations whose tilt offsets are used.
    fit_offset : fit the clock offset (motion capture minus car).
    fit_photodiodes : fit the photodiode positions too.
    fit_tilt : fit every station's tilt offsets, also those the geometry gives (those it does
        not give are always fitted).
    max_offset : search range of the clock offset, +-s.
    offset : the start (or, without ``fit_offset``, the fixed) clock offset, s.
    sweep_model : the compiled sweep model (built when not given).

    Raises
    ------
    ValueError
        A :class:`~crs_core.errors.FieldError` naming what is missing or bad: ``lighthouse`` (no
        sweeps, a station without plane pairs, or a fit that did not converge), ``pose`` (no
        reference, or no overlap), ``offset``, ``max_offset``.
    """
    if not (math.isfinite(max_offset) and max_offset >= 0):
        raise FieldError("max_offset", f"must be finite and >= 0, got {max_offset!r}")
    if not (math.isfinite(offset) and abs(offset) <= max_offset):
        raise FieldError("offset", f"must lie within +-max_offset ({max_offset} s), got {offset!r}")
    data = read_recording(dataset)
    spline = ReferenceTrajectory(data.pose_t, data.pose)
    velocity = spline.velocity
    margin = max_offset if fit_offset else abs(offset)
    inside = (data.stamps - margin >= data.pose_t[0]) & (data.stamps + margin <= data.pose_t[-1])
    after = np.clip(np.searchsorted(data.pose_t, data.stamps + offset), 1, data.pose_t.size - 1)
    gap = data.pose_t[after] - data.pose_t[after - 1]
    keep = inside & (gap <= MAX_REFERENCE_GAP)
    if keep.sum() < 20:
        raise FieldError(
            "pose",
            f"only {int(keep.sum())} sweeps fall inside the motion-capture reference "
            f"(+-{margin} s); the recordings' time ranges barely overlap",
        )
    obs = Observations(
        data.observations.station[keep],
        data.observations.plane[keep],
        data.observations.angles[keep],
    )
    stamps = data.stamps[keep]
    data = Recording(stamps, obs, data.pose_t, data.pose, data.n_stations)
    n = data.n_stations
    prior = dataset.geometry
    known = prior.base_stations or ()
    tilts = [(known[s].dt1, known[s].dt2) if s < len(known) else None for s in range(n)]
    free = [fit_tilt or pair is None for pair in tilts]
    model = sweep_model or SweepModel()
    start_at = offset
    if fit_offset:
        start_at = _coarse_offset(data, spline, tilts, prior.photodiodes, max_offset, model)
    start = _start_stations(data, spline, start_at, tilts, np.asarray(prior.photodiodes))

    def poses_at(value: float):
        return spline(stamps + value), velocity(stamps + value)[:, :, None]

    fixed = LighthouseFit(
        obs,
        start,
        prior.photodiodes,
        _poses_fixed_at(spline, stamps, start_at),
        0,
        fit_tilt=free,
        sweep_model=model,
    )
    first = fixed.solve(np.zeros(0), loss="soft_l1", f_scale=LOSS_SCALE)
    scan = (np.zeros(0), np.zeros(0))
    start_offset = offset
    if fit_offset:
        offsets = np.arange(-max_offset, max_offset + 0.5 * OFFSET_STEP, OFFSET_STEP)
        at_first = LighthouseFit(
            obs,
            first.stations,
            prior.photodiodes,
            lambda e: poses_at(float(e[0])),
            1,
            sweep_model=model,
        )
        z = at_first.start_vector(np.zeros(1))
        costs = []
        for value in offsets:
            z[-1] = value
            costs.append(_scan_cost(at_first.evaluate(z, jacobian=False)))
        scan = (offsets, np.array(costs))
        start_offset = float(offsets[int(np.argmin(costs))])
    fixed_at_offset = _poses_fixed_at(spline, stamps, offset)
    problem = LighthouseFit(
        obs,
        first.stations,
        prior.photodiodes,
        (lambda e: poses_at(float(e[0]))) if fit_offset else fixed_at_offset,
        1 if fit_offset else 0,
        fit_tilt=free,
        fit_photodiodes=fit_photodiodes,
        sweep_model=model,
    )
    bounds = (np.array([-max_offset]), np.array([max_offset])) if fit_offset else None
    fit = problem.solve(
        np.array([start_offset]) if fit_offset else np.zeros(0),
        loss="soft_l1",
        f_scale=LOSS_SCALE,
        bounds=bounds,
    )
    fit.require_converged(
        "lighthouse",
        "sweeps",
        "check that the pose reference is the car's body origin in the world frame, and the "
        "clock offset range",
    )
    value = float(fit.extra[0]) if fit_offset else float(offset)
    spread = float(fit.extra_std[0]) if fit_offset else 0.0
    return MovingCalibration(fit, value, spread, data, tuple(start), scan, spline)


class ReferenceTrajectory:
    r"""The motion-capture pose as a smooth function of time: per channel a cubic smoothing
    spline (``scipy.interpolate.make_smoothing_spline``) with
    :math:`\lambda = 1 / (h\,(2\pi f_c)^4)`, :math:`h` the median sample spacing, which halves
    the amplitude at :math:`f_c` = ``cutoff_hz`` (default 10 Hz: 0.2 % loss at 2 Hz, the car's
    manoeuvres; 6 % of the amplitude left at 20 Hz).

    Interpolating the raw samples instead would make the reference noise depend on where a sweep
    falls between two samples (largest on a sample), which pulls the clock offset towards the
    middle between samples when the photodiodes are fitted too (4 ms in simulation); smoothing
    removes that.
    """

    def __init__(self, stamps: np.ndarray, poses: np.ndarray, cutoff_hz: float = 10.0) -> None:
        spacing = float(np.median(np.diff(stamps)))
        lam = 1.0 / (spacing * (2.0 * math.pi * cutoff_hz) ** 4)
        self._splines = [make_smoothing_spline(stamps, poses[:, i], lam=lam) for i in range(3)]
        self._derivatives = [s.derivative() for s in self._splines]

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Poses (N, 3) at reference-clock times ``t``."""
        return np.column_stack([s(t) for s in self._splines])

    def velocity(self, t: np.ndarray) -> np.ndarray:
        """Time derivative of the pose (N, 3) at ``t``."""
        return np.column_stack([s(t) for s in self._derivatives])


def _soft_l1(z: np.ndarray) -> np.ndarray:
    return 2.0 * (np.sqrt(1.0 + z * z) - 1.0)


def _scan_cost(residual: np.ndarray) -> float:
    """The robust cost of the residuals (rad) of a scan; an angle the model cannot produce
    counts as a quarter turn off."""
    residual = np.where(np.isfinite(residual), residual, 0.5 * math.pi)
    return float(np.sum(_soft_l1(residual / LOSS_SCALE)))


def _poses_fixed_at(spline: ReferenceTrajectory, stamps: np.ndarray, offset: float):
    """The pose function of a fit at a fixed clock ``offset`` (s): no extra unknowns."""
    poses, none = spline(stamps + offset), np.zeros((len(stamps), 3, 0))
    return lambda _: (poses, none)


def _coarse_offset(
    data: Recording,
    spline: ReferenceTrajectory,
    tilts: list[tuple[float, float] | None],
    photodiodes: tuple[tuple[float, float], ...],
    max_offset: float,
    model: SweepModel,
) -> float:
    """The clock offset (s) on a :data:`COARSE_OFFSET_STEP` grid over ``+-max_offset`` whose
    closed-form stations (its own at each offset) explain the sweeps best."""
    best, lowest = 0.0, math.inf
    diodes = np.asarray(photodiodes)
    step = COARSE_OFFSET_STEP
    for value in np.arange(-max_offset, max_offset + 0.5 * step, step):
        stations = _start_stations(data, spline, float(value), tilts, diodes)
        fit = LighthouseFit(
            data.observations,
            stations,
            photodiodes,
            _poses_fixed_at(spline, data.stamps, float(value)),
            0,
            sweep_model=model,
        )
        cost = _scan_cost(fit.evaluate(fit.start_vector(np.zeros(0)), jacobian=False))
        if cost < lowest:
            best, lowest = float(value), cost
    return best


def _start_stations(
    data: Recording,
    spline: ReferenceTrajectory,
    offset: float,
    tilts: list[tuple[float, float] | None],
    diodes: np.ndarray,
) -> list[BaseStation]:
    """Closed-form stations from plane pairs (a plane 2 sweep and the plane 1 before it, at
    most 30 ms apart); ``tilts`` per station, None when unknown."""
    stations = []
    obs = data.observations
    for s in range(data.n_stations):
        first = np.flatnonzero((obs.station == s) & (obs.plane == 1))
        second = np.flatnonzero((obs.station == s) & (obs.plane == 2))
        if first.size == 0 or second.size == 0:
            raise FieldError("lighthouse", f"station {s} has no sweeps of both light planes")
        before = np.searchsorted(data.stamps[first], data.stamps[second], side="right") - 1
        ok = before >= 0
        pairs_2, pairs_1 = second[ok], first[before[ok]]
        close = data.stamps[pairs_2] - data.stamps[pairs_1] <= 0.03
        pairs_1, pairs_2 = pairs_1[close], pairs_2[close]
        if pairs_1.size < 4:
            raise FieldError("lighthouse", f"station {s} has fewer than 4 pairs of light planes")
        pick = np.unique(
            np.linspace(0, pairs_1.size - 1, min(START_PAIRS, pairs_1.size)).astype(int)
        )
        pairs_1, pairs_2 = pairs_1[pick], pairs_2[pick]
        q = spline(0.5 * (data.stamps[pairs_1] + data.stamps[pairs_2]) + offset)
        c, si = np.cos(q[:, 2]), np.sin(q[:, 2])
        world = np.stack(
            [
                q[:, 0:1] + c[:, None] * diodes[:, 0] - si[:, None] * diodes[:, 1],
                q[:, 1:2] + si[:, None] * diodes[:, 0] + c[:, None] * diodes[:, 1],
            ],
            axis=-1,
        ).reshape(-1, 2)
        alpha1 = obs.angles[pairs_1].reshape(-1)
        alpha2 = obs.angles[pairs_2].reshape(-1)
        stations.append(start_station(world, alpha1, alpha2, tilts[s]))
    return stations
