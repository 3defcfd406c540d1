"""A bag as a dataset: one car's recording in the layout every offline tool reads.

A bag recorded by ``crs launch sim|car`` (or any bag with this suite's topics: through the bridge
from a real car as well) becomes a :class:`~crs_core.dataset.Dataset`, read with rosbags (no
ROS needed; a bag folder or one ``.mcap`` file; a cut-off bag is read up to its last complete
message, with a warning):

* the full-rate stream: every sensor reading of the car (``sensors/batch`` or the per-reading
  topics), an exact duplicate (same sensor and stamp) kept once;
* the 13-channel samples at the Lighthouse sweeps (:func:`crs_core.stream_samples.sample_stream`);
* the inputs ``[steer, torque]``: by default the inputs the car reported applying
  (``input/applied``, published by the bridge and the simulator) where the bag has them, else the
  torque-mode commands sent (``input``; velocity-mode commands carry no torque and are left
  out);
* the reference states ``x``: by default the simulation truth (``ground_truth``) where the bag
  has it, else the car's on-line estimates (``estimate/state``: not ground truth), or none.
  Yaw is unwrapped; states are interpolated linearly to the samples.

The samples are kept from the first input on (before it, no input was in force) and, with a
reference, within the reference's time span; ``meta`` says what was read from where and what
was left out.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader

from crs_core.analysis.metrics import interpolate_states
from crs_core.dataset import Dataset, Geometry
from crs_core.errors import FieldError
from crs_core.measurements import InputSample, Measurement
from crs_core.stream_samples import held_at, sample_stream
from ros4crs import conversions
from ros4crs.bag_repair import open_bag
from ros4crs.bag_replay import BagContents, read_car_from

__all__ = [
    "INPUT_CHOICES",
    "REFERENCE_CHOICES",
    "BagDatasetWarning",
    "cars_in",
    "dataset_from_bag",
    "is_bag",
    "load_recording",
]

#: Where the inputs are read from: ``auto`` (applied where the bag has them, else commands).
INPUT_CHOICES = ("auto", "applied", "commands")
#: Where the reference states come from: ``auto`` (truth, else estimates), or none.
REFERENCE_CHOICES = ("auto", "truth", "estimates", "none")

_SENSOR_TOPICS = tuple(
    conversions.TOPICS[family] for family in (*conversions.SENSOR_PARSERS, "batch")
)


class BagDatasetWarning(UserWarning):
    """Something of the bag was left out or missing (no inputs, no reference, samples cut)."""


@dataclass(frozen=True)
class _Span:
    """The part of the samples kept, and why."""

    start: float
    end: float
    reasons: tuple[str, ...]


def cars_in(reader: Reader) -> list[str]:
    """The namespaces (``car1``, ...) of the cars whose sensor readings the bag holds, sorted;
    ``""`` for a car recorded without a namespace."""
    cars = set()
    for connection in reader.connections:
        for topic in _SENSOR_TOPICS:
            if connection.topic.endswith("/" + topic) and connection.msgcount:
                cars.add(connection.topic[: -len(topic) - 1].strip("/"))
    return sorted(cars)


def _chosen_car(cars: list[str], car: str | None) -> str:
    if car is not None:
        name = car.strip("/")
        if name not in cars:
            held = ", ".join(c or "(no namespace)" for c in cars) or "none"
            raise FieldError("car", f"no sensor readings of {name!r} in the bag (cars: {held})")
        return name
    if not cars:
        raise FieldError("bag", "holds no sensor readings (no sensors/* topic of any car)")
    if len(cars) > 1:
        raise FieldError("car", f"the bag holds several cars ({', '.join(cars)}): name one")
    return cars[0]


def _input_topic(reader: Reader, prefix: str, inputs: str) -> str:
    """``input/applied`` or ``input``, as ``inputs`` asks and the bag has."""
    if inputs not in INPUT_CHOICES:
        raise FieldError("inputs", f"must be one of {', '.join(INPUT_CHOICES)}, got {inputs!r}")
    counts = {c.topic[len(prefix) :]: c.msgcount for c in reader.connections}
    applied = conversions.TOPICS["applied_input"]
    if inputs == "applied" or (inputs == "auto" and counts.get(applied, 0) > 0):
        return applied
    return conversions.TOPICS["input"]


def _distinct(measurements: list[Measurement]) -> list[Measurement]:
    """``measurements`` (stamp order) with exact repeats of a sensor's stamp left out."""
    seen: set[tuple[str, float]] = set()
    out = []
    for m in measurements:
        if (m.sensor, m.stamp) not in seen:
            seen.add((m.sensor, m.stamp))
            out.append(m)
    return out


def _reference(contents: BagContents, reference: str) -> tuple[str, list[tuple[float, np.ndarray]]]:
    """The reference states chosen: (label, [(stamp, x)]) (label ``""``: none)."""
    if reference not in REFERENCE_CHOICES:
        raise FieldError(
            "reference", f"must be one of {', '.join(REFERENCE_CHOICES)}, got {reference!r}"
        )
    if reference in ("auto", "truth") and contents.truth:
        return "truth", contents.truth
    if reference in ("auto", "estimates") and contents.estimates:
        return "estimates", contents.estimates
    if reference in ("truth", "estimates"):
        topic = conversions.TOPICS["ground_truth" if reference == "truth" else "state"]
        raise FieldError("reference", f"{reference}: the bag has no {topic} of this car")
    return "", []


def _states(series: list[tuple[float, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (distinct, increasing) and states ``(n, 6)`` with the yaw unwrapped."""
    stamps = np.array([t for t, _ in series])
    states = np.stack([x for _, x in series])
    order = np.argsort(stamps, kind="stable")
    stamps, states = stamps[order], states[order]
    keep = np.concatenate([[True], np.diff(stamps) > 0])
    stamps, states = stamps[keep], states[keep].copy()
    states[:, 2] = np.unwrap(states[:, 2])
    return stamps, states


def dataset_from_bag(
    bag: str | Path,
    car: str | None = None,
    *,
    inputs: str = "auto",
    reference: str = "auto",
    geometry: Geometry | None = None,
) -> Dataset:
    """The dataset of one car's recording in ``bag``.

    Parameters
    ----------
    bag : str or Path
        A bag folder or ``.mcap`` file.
    car : str, optional
        The car's namespace (``car1``); needed only when the bag holds several cars.
    inputs : {"auto", "applied", "commands"}
        Inputs from ``input/applied`` or ``input`` (``auto``: applied where the bag has them).
    reference : {"auto", "truth", "estimates", "none"}
        Reference states from ``ground_truth`` or ``estimate/state`` (``auto``: the truth, else
        the estimates, else none).
    geometry : Geometry, optional
        The Lighthouse geometry of the recording (default: the real recordings', which is also
        the simulator's default car).

    Raises
    ------
    FieldError
        ``car`` missing (several cars) or unknown; ``bag`` without sensor readings or without
        a Lighthouse sweep pair of station 0 (the samples' stamps); a bad choice.
    """
    with open_bag(bag) as reader:
        name = _chosen_car(cars_in(reader), car)
        prefix = f"/{name}/" if name else "/"
        input_topic = _input_topic(reader, prefix, inputs)
        contents = read_car_from(reader, prefix, input_topic)
    label, series = _reference(contents, reference)
    measurements = _distinct(contents.measurements)
    samples = sample_stream(measurements)
    if samples.t.size == 0:
        raise FieldError(
            "bag",
            f"no Lighthouse sweep pair of station 0 from {name or 'the car'} (the samples of a "
            "dataset are stamped at them)",
        )
    span = _span(samples.t, contents.inputs, series)
    keep = (samples.t >= span.start) & (samples.t <= span.end)
    t, y = samples.t[keep], samples.y[keep]
    if t.size < 2:
        raise FieldError(
            "bag", f"fewer than 2 samples within {', '.join(span.reasons) or 'the recording'}"
        )
    if span.reasons:
        warnings.warn(
            f"kept {t.size} of {samples.t.size} samples ({t[-1] - t[0]:.1f} s): "
            + ", ".join(span.reasons),
            BagDatasetWarning,
            stacklevel=2,
        )
    u = held_at(contents.inputs, t) if contents.inputs else None
    if u is None:
        warnings.warn(
            f"no torque-mode inputs on {prefix}{input_topic}: the dataset has none "
            "(estimators then estimate them)",
            BagDatasetWarning,
            stacklevel=2,
        )
    x = None
    truth_t = truth_x = None
    if series:
        stamps, states = _states(series)
        x = interpolate_states(t, stamps, states)
        if label == "truth":
            truth_t, truth_x = stamps, states
    stream = [m for m in measurements if t[0] <= m.stamp <= t[-1]]
    held: list[InputSample] = []
    if contents.inputs:
        before = [s for s in contents.inputs if s.stamp <= t[0]]
        held = before[-1:] + [s for s in contents.inputs if t[0] < s.stamp <= t[-1]]
    meta = {
        "source": "simulated" if label == "truth" else "bag",
        "bag": str(Path(bag).resolve()),
        "car": name,
        "inputs": f"{prefix}{input_topic}" if held else None,
        "reference": _reference_text(label, prefix),
        "malformed_messages": contents.malformed,
    }
    return Dataset(
        t=t,
        u=u,
        y=y,
        x=x,
        geometry=geometry or Geometry(),
        meta=meta,
        measurements=stream,
        inputs=held or None,
        truth_t=truth_t,
        truth_x=truth_x,
    )


def _reference_text(label: str, prefix: str) -> str | None:
    if label == "truth":
        return f"simulation truth ({prefix}{conversions.TOPICS['ground_truth']})"
    if label == "estimates":
        return f"the car's on-line estimates ({prefix}{conversions.TOPICS['state']}), not truth"
    return None


def _span(
    t: np.ndarray, inputs: list[InputSample], series: list[tuple[float, np.ndarray]]
) -> _Span:
    """The samples to keep: from the first input on, within the reference's span."""
    start, end, reasons = float(t[0]), float(t[-1]), []
    if inputs and inputs[0].stamp > start:
        start = inputs[0].stamp
        reasons.append("from the first input on")
    if series:
        first, last = min(s for s, _ in series), max(s for s, _ in series)
        if first > start or last < end:
            reasons.append("within the reference states' span")
        start, end = max(start, first), min(end, last)
    return _Span(start, end, tuple(reasons))


def is_bag(path: str | Path) -> bool:
    """Whether ``path`` is a bag: an ``.mcap`` file, or a folder with ``metadata.yaml`` or
    storage files (``*.mcap``, ``*.db3``) and no dataset (``t.npy``)."""
    path = Path(path)
    if path.is_file():
        return path.suffix == ".mcap"
    if not path.is_dir() or (path / "t.npy").exists():
        return False
    return (path / "metadata.yaml").exists() or any(
        next(path.glob(pattern), None) is not None for pattern in ("*.mcap", "*.db3")
    )


def load_recording(
    path: str | Path,
    car: str | None = None,
    geometry: Geometry | None = None,
    inputs: str = "auto",
    reference: str = "auto",
) -> Dataset:
    """A recording as a dataset: a dataset folder (:meth:`~crs_core.dataset.Dataset.load`), or a
    bag (:func:`dataset_from_bag`, with ``car``, ``geometry``, ``inputs`` and ``reference``).

    Raises
    ------
    FileNotFoundError
        ``path`` is neither.
    FieldError
        ``car`` or ``geometry`` given for a dataset folder (it has its own), and as
        :meth:`~crs_core.dataset.Dataset.load` and :func:`dataset_from_bag`.
    """
    if is_bag(path):
        return dataset_from_bag(path, car, inputs=inputs, reference=reference, geometry=geometry)
    if car is not None:
        raise FieldError("car", f"{path} is a dataset folder (one car), not a bag")
    if geometry is not None:
        raise FieldError("geometry", f"{path} is a dataset folder: its geometry is its own")
    return Dataset.load(path)
