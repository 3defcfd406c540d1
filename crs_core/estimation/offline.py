"""Offline estimation: run an EKF or MHE over a recorded dataset (``crs estimate``, notebooks).

:func:`estimate_dataset` replays a :class:`~crs_core.dataset.Dataset` through an estimator as
it would have arrived live, and queries the estimate at every sample stamp ``dataset.t[k]``
after delivering every measurement and input stamped up to it (in stamp order, inputs first at
equal stamps). The result is on the dataset's own time base, so it lines up sample by sample
with ``y``, ``u`` and the reference ``x`` of the dataset; or at any stamps asked for within the
data (``at``: a motion-capture clock, or a fixed rate from :func:`rate_stamps`).

Data used: the full-rate stream (``stream.npz``) when the dataset has one, else the 13-channel
samples of ``y.npy`` (:meth:`~crs_core.dataset.Dataset.sample_stream`; the yaw rate is then the
``gyro`` sensor). Commanded inputs: those of the stream, else ``u.npy``; none with
``inputs="estimated"`` or when the recording has none (the input-free model then estimates the
applied steering and torque).

Start: blind by default (``x0=None``; the estimate is ``lost`` until the Lighthouse gives a
fix), from a pose ``(x, y, yaw)`` at rest with the loose standard deviations
:data:`POSE_X0_STD`, or from a full state. The start time is the first stamp of the data.

Units and frames everywhere: SI, rad; world pose ``x, y, yaw`` (REP 103, yaw counter-clockwise
from the world x axis), body velocities ``vx`` (forward), ``vy`` (left), yaw rate ``omega``.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from crs_core.analysis.metrics import STATE_NAMES, interpolate_states, state_rmse
from crs_core.analysis.statistics import summary
from crs_core.dataset import Dataset
from crs_core.errors import FieldError
from crs_core.estimation.base import (
    SENSOR_GROUPS,
    Estimator,
    EstimatorSettings,
    parse_sensor_set,
    sensor_group,
)
from crs_core.estimation.factory import KINDS, make_estimator
from crs_core.estimation.mhe import MheSettings
from crs_core.estimation.online_track import OnlineTrack
from crs_core.measurements import InputSample, Measurement, in_stamp_order
from crs_core.model import CarModel
from crs_core.model.car_model import effects_in_file
from crs_core.model.plant import Plant
from crs_core.model.plants import load_plant, resolve_model
from crs_core.model.terms import Term, terms_in_file

#: Integer codes of the status words in ``estimates.npz``.
STATUS_CODES = {"ok": 0, "degraded": 1, "lost": 2}
#: Initial standard deviation of ``[x, y, yaw, vx, vy, omega]`` (m, m, rad, m/s, m/s, rad/s)
#: when the start is a pose only: the pose roughly known, the car assumed at rest but possibly
#: moving at up to ~2 m/s.
POSE_X0_STD = (0.1, 0.1, 0.2, 2.0, 0.5, 3.0)
#: Sensor groups ``sensors="auto"`` may pick (motion-capture ``pose`` only when asked for: it is
#: usually the reference, not a sensor).
AUTO_SENSOR_GROUPS = ("lh", "imu", "gyro", "we")
#: Reference comparisons also report the RMSE from this long after the first fix on, s.
SETTLING_S = 2.0


def dataset_model(
    dataset: Dataset,
    parameters_yaml: str | Path | None = None,
    effects: Mapping[str, Any] = MappingProxyType({}),
    values: Mapping[str, float] = MappingProxyType({}),
    model: str | Plant | None = None,
) -> CarModel:
    """The model ``model`` (:func:`~crs_core.model.plants.load_plant`; by default the one
    ``parameters_yaml`` names, else the dynamic bicycle) with the dataset's Lighthouse geometry
    (stations, photodiodes).

    ``effects`` (the ``CarModel`` effects mapping) are switched on, and those whose parameters
    ``parameters_yaml`` names (:func:`~crs_core.model.car_model.effects_in_file`), with the
    terms it lists (:func:`~crs_core.model.terms.terms_in_file`); ``values``
    (parameter values by name) and then ``parameters_yaml`` (a parameter file,
    :meth:`~crs_core.parameters.ParameterSet.updated_from_yaml`) are applied last, so they may
    also override the geometry. A geometry without base stations (the deck layout alone) is
    refused with a :class:`~crs_core.errors.FieldError` naming ``geometry.base_stations``.
    """
    terms: tuple[Term, ...] = ()
    plant = load_plant(resolve_model(model, parameters_yaml), "model")
    if parameters_yaml is not None:
        effects = {**dict.fromkeys(effects_in_file(parameters_yaml)), **effects}
        terms = terms_in_file(parameters_yaml)
    n = len(dataset.geometry.known_stations())
    geometry = {name: p.value for name, p in dataset.geometry.parameters().items()}
    skeleton = CarModel(effects, n_base_stations=n, terms=terms, model=plant)
    parameters = skeleton.parameters.updated(geometry).updated(dict(values))
    if parameters_yaml is not None:
        parameters = parameters.updated_from_yaml(parameters_yaml)
    return CarModel(effects, n_base_stations=n, parameters=parameters, terms=terms, model=plant)


def dataset_stream(dataset: Dataset) -> tuple[list[Measurement], list[InputSample], str]:
    """Measurements and commanded inputs of a dataset, and where they came from (a phrase)."""
    if dataset.measurements:
        measurements, source = dataset.measurements, "stream.npz"
    else:
        measurements, source = dataset.sample_stream(), "y.npy samples"
    if dataset.inputs:
        inputs, source = list(dataset.inputs), source + ", inputs from stream.npz"
    elif dataset.u is not None:
        inputs = [InputSample(float(t), u) for t, u in zip(dataset.t, dataset.u, strict=True)]
        source += ", inputs from u.npy"
    else:
        inputs, source = [], source + ", no inputs recorded"
    return measurements, inputs, source


def available_sensors(dataset: Dataset, model: CarModel | None = None) -> str:
    """The groups of :data:`AUTO_SENSOR_GROUPS` the dataset has data for, e.g.
    ``"lh+we+gyro"``, and that ``model``'s plant explains
    (:attr:`~crs_core.model.plant.Plant.explains`; every group without a model)."""
    measurements, _, _ = dataset_stream(dataset)
    present = {sensor_group(m.sensor) for m in measurements}
    explained = model.plant.explains if model is not None else AUTO_SENSOR_GROUPS
    groups = [g for g in AUTO_SENSOR_GROUPS if g in present and g in explained]
    if not groups:
        raise FieldError(
            "sensors",
            "the dataset has no Lighthouse, IMU, gyro or wheel data"
            + ("" if model is None else f" that model {model.plant.name} explains"),
        )
    return "+".join(groups)


def initial_state(x0: Any) -> tuple[np.ndarray, np.ndarray | None]:
    """``x0`` (3 or 6 finite values) as a base state and covariance (None: the default)."""
    values = np.asarray(x0, dtype=float).ravel()
    if values.size not in (3, 6) or not np.all(np.isfinite(values)):
        raise FieldError(
            "x0",
            "needs 3 (x, y, yaw) or 6 (x, y, yaw, vx, vy, omega) finite values, got "
            f"{values.size}" + ("" if np.all(np.isfinite(values)) else " with NaN or inf"),
        )
    if values.size == 6:
        return values, None
    return np.concatenate([values, np.zeros(3)]), np.diag(np.square(POSE_X0_STD))


@dataclass
class OfflineEstimates:
    """Estimates at the stamps of a dataset.

    Attributes
    ----------
    t : np.ndarray
        (N,) the stamps estimated at: the dataset's own ``dataset.t``, or those asked for, s.
    x : np.ndarray
        (6, N) estimates ``[x, y, yaw, vx, vy, omega]`` (m, m, rad, m/s, m/s, rad/s; world pose,
        body velocities). Where the status is ``lost`` this is the estimator's held guess (zeros
        before the first fix): mask it with ``status``.
    covariance_diag : np.ndarray
        (6, N) variances of ``x`` (SI units squared).
    status : np.ndarray
        (N,) ``"ok"``, ``"degraded"`` or ``"lost"``.
    reasons : np.ndarray
        (N,) why, when the status is not ``ok`` (else ``""``).
    diagnostics : dict
        JSON-ready summary: settings, the estimator's counters (``processed``, ``rejected``,
        ``ignored`` per sensor, ``late``, ``fallbacks``, ``reinitializations``, ``skipped_s``),
        ``status_counts``, ``time_to_first_fix_s`` (from the first data stamp to the first
        estimate that is not lost; None if never), ``reasons`` (the 20 most frequent, with their
        sample counts) and timing.
    estimator : Estimator
        The estimator after the run (on the dataset's clock).
    online : OnlineTrack
        The online parameters at the same stamps (none without them).
    """

    t: np.ndarray
    x: np.ndarray
    covariance_diag: np.ndarray
    status: np.ndarray
    reasons: np.ndarray
    diagnostics: dict[str, Any]
    estimator: Estimator = field(repr=False)
    online: OnlineTrack = field(default_factory=lambda: OnlineTrack.empty(0))

    @property
    def status_codes(self) -> np.ndarray:
        """(N,) int8: 0 ok, 1 degraded, 2 lost (:data:`STATUS_CODES`)."""
        return np.array([STATUS_CODES[s] for s in self.status], dtype=np.int8)

    def save_npz(self, path: str | Path) -> Path:
        """Write ``t``, ``x``, ``status`` (codes), ``covariance_diag`` and ``state_names``, and
        with online parameters ``online_names``, ``online_value``, ``online_std`` and
        ``online_informed`` (each (P, N))."""
        path = Path(path)
        arrays: dict[str, Any] = {
            "t": self.t,
            "x": self.x,
            "status": self.status_codes,
            "covariance_diag": self.covariance_diag,
            "state_names": np.array(STATE_NAMES),
        }
        if self.online.names:
            arrays["online_names"] = np.array(self.online.names)
            arrays["online_value"] = self.online.value
            arrays["online_std"] = self.online.std
            arrays["online_informed"] = self.online.informed
        np.savez_compressed(path, **arrays)
        return path


def estimate_dataset(
    dataset: Dataset,
    kind: str,
    sensors: str = "auto",
    *,
    model: CarModel | None = None,
    settings: EstimatorSettings | None = None,
    inputs: str = "auto",
    x0: Any = None,
    rate_hz: float | None = None,
    progress: Callable[[float], None] | None = None,
    at: Any = None,
) -> OfflineEstimates:
    """Run an estimator over ``dataset`` and return its estimates at every ``dataset.t[k]``
    (or at the stamps ``at``).

    Parameters
    ----------
    dataset : Dataset
        The recording (:mod:`crs_core.dataset`); its stream if it has one, else its samples.
    kind : {"ekf", "mhe"}
    sensors : str
        Sensor groups joined by ``+`` (``"lh+imu+we"``), or ``"auto"``: every group among
        :data:`AUTO_SENSOR_GROUPS` the dataset has data for.
    model : CarModel, optional
        The estimation model (commanded form); default :func:`dataset_model` (the Chronos
        parameters with the dataset's Lighthouse geometry).
    settings : EkfSettings or MheSettings, optional
        Estimator settings; default ``EkfSettings()`` / ``MheSettings(rate_hz=rate_hz)``.
    inputs : {"auto", "commanded", "estimated"}
        See :func:`~crs_core.estimation.factory.make_estimator`. ``estimated`` withholds the
        recorded inputs; ``auto`` on a recording without inputs stays input-free; ``commanded``
        needs recorded inputs.
    x0 : array-like, optional
        None: blind start from the Lighthouse. 3 values ``x, y, yaw`` (m, m, rad): that pose at
        rest, standard deviations :data:`POSE_X0_STD`. 6 values: the full state, standard
        deviations ``settings.initial_std``. It is the state at the first stamp of the data.
    rate_hz : float, optional
        MHE grid rate, Hz (default 60, or ``settings.rate_hz``); the EKF has no grid and ignores
        it.
    progress : callable, optional
        Called with the fraction done (0..1) now and then.
    at : array-like, optional
        Stamps to estimate at instead (s, the dataset's clock): strictly increasing, within the
        data (from the first measurement or sample to the last); e.g. a motion-capture clock,
        or a fixed rate (:func:`rate_stamps`).

    Returns
    -------
    OfflineEstimates

    Raises
    ------
    ValueError
        For an empty dataset and invalid ``kind``, ``sensors``, ``inputs``, ``x0``,
        ``rate_hz`` or ``at``, with a one-line message naming it.
    """
    if kind not in KINDS:
        raise FieldError("estimator", f"must be 'ekf' or 'mhe', got {kind!r}")
    if not len(dataset.t):
        raise FieldError("dataset", "has no samples (t.npy is empty)")
    if rate_hz is not None and not (math.isfinite(rate_hz) and rate_hz > 0):
        raise FieldError("rate_hz", f"must be finite and > 0, got {rate_hz}")
    sensor_text = available_sensors(dataset, model) if sensors == "auto" else sensors
    groups = parse_sensor_set(sensor_text)
    start_x, start_cov = (None, None) if x0 is None else initial_state(x0)
    measurements, recorded_inputs, source = dataset_stream(dataset)
    present = {sensor_group(m.sensor) for m in measurements}
    if not groups & present:
        have = "+".join(g for g in SENSOR_GROUPS if g in present) or "no measurements"
        raise FieldError("sensors", f"the dataset has no data for {sensor_text} (it has {have})")
    if inputs == "commanded" and not recorded_inputs:
        raise FieldError(
            "inputs",
            "'commanded' needs recorded inputs (u.npy or inputs in stream.npz) and this "
            "dataset has none; use 'auto' or 'estimated'",
        )
    delivered_inputs = [] if inputs == "estimated" else recorded_inputs
    if recorded_inputs and not delivered_inputs:
        source += " withheld"
    if kind == "mhe" and settings is None:
        settings = MheSettings(rate_hz=rate_hz or MheSettings().rate_hz)
    elif kind == "mhe" and rate_hz is not None and isinstance(settings, MheSettings):
        if rate_hz != settings.rate_hz:
            raise FieldError(
                "rate_hz", f"{rate_hz} contradicts settings.rate_hz {settings.rate_hz}"
            )
    estimator = make_estimator(
        kind, groups, model or dataset_model(dataset), settings, inputs=inputs
    )

    events = in_stamp_order(measurements, delivered_inputs)
    t_start, t_end = _span(dataset, events)
    stamps = np.array(dataset.t, dtype=float) if at is None else query_stamps(at, t_start, t_end)
    estimator.reset(t_start, start_x, start_cov)
    n = len(stamps)
    x, variances, times = np.zeros((6, n)), np.zeros((6, n)), np.zeros(n)
    online = OnlineTrack.empty(n, estimator.model.online.names)
    status, reasons = np.empty(n, dtype=object), np.empty(n, dtype=object)
    k_event, report_every = 0, max(1, n // 200)
    wall = time.perf_counter()
    for k, stamp in enumerate(stamps):
        started = time.perf_counter()
        while k_event < len(events) and events[k_event].stamp <= stamp:
            estimator.add(events[k_event])
            k_event += 1
        estimate = estimator.estimate(float(stamp))
        times[k] = time.perf_counter() - started
        x[:, k], variances[:, k] = estimate.x, np.diag(estimate.covariance)
        status[k], reasons[k] = estimate.status, estimate.reason
        online.set(k, estimate.parameters)
        if progress is not None and (k % report_every == 0 or k == n - 1):
            progress((k + 1) / n)
    wall = time.perf_counter() - wall

    status, reasons = status.astype(str), reasons.astype(str)
    found = np.flatnonzero(status != "lost")
    d = estimator.diagnostics
    diagnostics: dict[str, Any] = {
        "estimator": kind,
        "sensors": "+".join(g for g in SENSOR_GROUPS if g in groups),
        "inputs": inputs,
        "input_mode": getattr(estimator, "mode", inputs),
        "rate_hz": settings.rate_hz if isinstance(settings, MheSettings) else None,
        "process_std": list(estimator.settings.noise.process_std),
        "start": "blind" if x0 is None else [float(v) for v in np.ravel(x0)],
        "data": source,
        "samples": n,
        "t_start": t_start,
        "measurements_delivered": sum(isinstance(e, Measurement) for e in events[:k_event]),
        "inputs_delivered": sum(isinstance(e, InputSample) for e in events[:k_event]),
        "events_after_last_sample": len(events) - k_event,
        "groups_without_data": sorted(groups - present),
        "status_counts": {s: int(np.sum(status == s)) for s in STATUS_CODES},
        "time_to_first_fix_s": float(stamps[found[0]] - t_start) if found.size else None,
        "processed": dict(sorted(d.processed.items())),
        "rejected": dict(sorted(d.rejected.items())),
        "ignored": dict(sorted(d.ignored.items())),
        "late": d.late,
        "fallbacks": d.fallbacks,
        "reinitializations": d.reinitializations,
        "skipped_s": d.skipped_s,
        "final_status": d.status,
        "final_reason": d.reason,
        "reasons": dict(Counter(str(r) for r in reasons if r).most_common(20)),
        "wall_time_s": wall,
        "time_per_sample_ms": summary(times * 1e3),
    }
    if online.names:
        diagnostics["online_parameters"] = online.final_summary()
    return OfflineEstimates(stamps, x, variances, status, reasons, diagnostics, estimator, online)


def data_span(dataset: Dataset, with_inputs: bool = True) -> tuple[float, float]:
    """The first and the last stamp of a dataset's data (its samples, its stream and, unless
    they are withheld, its inputs), s: where an offline run starts and may be asked."""
    measurements, inputs, _ = dataset_stream(dataset)
    return _span(dataset, [*measurements, *(inputs if with_inputs else [])])


def _span(dataset: Dataset, items: Sequence[Measurement | InputSample]) -> tuple[float, float]:
    """The first and last stamp of the dataset's samples and of ``items``, s."""
    stamps = [float(dataset.t[0]), float(dataset.t[-1]), *(i.stamp for i in items)]
    return min(stamps), max(stamps)


def query_stamps(at: Any, start: float, end: float) -> np.ndarray:
    """``at`` as the stamps of an offline run over data from ``start`` to ``end`` (s):
    :class:`~crs_core.errors.FieldError` (field ``at``) unless a non-empty 1-D array of finite,
    strictly increasing stamps within that span."""
    try:
        stamps = np.asarray(at, dtype=float)
    except (TypeError, ValueError):
        raise FieldError("at", "must be an array of stamps (s)") from None
    if stamps.ndim != 1 or stamps.size == 0:
        raise FieldError("at", f"must be a non-empty 1-D array of stamps, got shape {stamps.shape}")
    if not np.all(np.isfinite(stamps)):
        raise FieldError("at", "holds a stamp that is not a finite number")
    if stamps.size > 1 and np.any(np.diff(stamps) <= 0):
        raise FieldError("at", "stamps must be strictly increasing")
    if stamps[0] < start or stamps[-1] > end:
        raise FieldError(
            "at",
            f"{stamps[0]:.3f} .. {stamps[-1]:.3f} s reaches outside the data "
            f"({start:.3f} .. {end:.3f} s)",
        )
    return stamps


def stamps_within(at: Any, start: float, end: float) -> tuple[np.ndarray, int]:
    """The stamps of ``at`` (checked as :func:`query_stamps` checks them) within the data from
    ``start`` to ``end`` (s), and how many lay outside; :class:`~crs_core.errors.FieldError`
    (field ``at``) when none is inside."""
    stamps = query_stamps(at, -math.inf, math.inf)
    inside = stamps[(stamps >= start) & (stamps <= end)]
    if not inside.size:
        raise FieldError(
            "at",
            f"{stamps[0]:.3f} .. {stamps[-1]:.3f} s: no stamp lies inside the data "
            f"({start:.3f} .. {end:.3f} s)",
        )
    return inside, int(stamps.size - inside.size)


def rate_stamps(dataset: Dataset, rate_hz: float) -> np.ndarray:
    """Stamps every ``1 / rate_hz`` s over the dataset's samples (from its first to its last)."""
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise FieldError("output_rate", f"must be finite and > 0 Hz, got {rate_hz}")
    if not len(dataset.t):
        raise FieldError("dataset", "has no samples (t.npy is empty)")
    count = math.floor((dataset.t[-1] - dataset.t[0]) * rate_hz + 1e-9) + 1
    return dataset.t[0] + np.arange(count) / rate_hz


def reference_label(dataset: Dataset) -> str:
    """What the dataset's ``x`` is: what its metadata say (a bag's dataset names the topic),
    else simulation truth or a recording's own on-line estimate."""
    described = dataset.meta.get("reference")
    if isinstance(described, str) and described:
        return described
    if dataset.meta.get("source") == "simulated":
        return "simulation truth"
    return "the recording's own on-line estimate x.npy (Lighthouse-derived, not ground truth)"


def reference_comparison(result: OfflineEstimates, dataset: Dataset) -> dict[str, Any] | None:
    """RMSE of the estimates against the dataset's reference ``x`` (None without one).

    ``rmse`` counts every sample that is not ``lost``; ``rmse_settled`` only those at least
    :data:`SETTLING_S` after the first fix. SI units, yaw error wrapped; ``position`` is
    ``sqrt(rmse_x² + rmse_y²)``.
    """
    reference = reference_states_at(dataset, result.t)
    if reference is None:
        return None
    found = (result.status != "lost") & np.isfinite(reference[:, 0])
    first = result.t[found][0] if found.any() else math.inf
    settled = found & (result.t >= first + SETTLING_S)
    return {
        "reference": reference_label(dataset),
        "rmse": state_rmse(result.x.T, reference, found),
        "rmse_settled": state_rmse(result.x.T, reference, settled),
        "settling_s": SETTLING_S,
        "samples": int(found.sum()),
        "samples_settled": int(settled.sum()),
    }


def reference_states_at(dataset: Dataset, t: np.ndarray) -> np.ndarray | None:
    """The dataset's reference states at stamps ``t``, ``(N, 6)`` (None without ``x``): its own
    rows at its own stamps, else linearly interpolated (yaw unwrapped), NaN outside them."""
    if dataset.x is None:
        return None
    if np.array_equal(t, dataset.t):
        return dataset.x
    states = interpolate_states(t, dataset.t, dataset.x)
    states[(t < dataset.t[0]) | (t > dataset.t[-1])] = np.nan
    return states
