"""A drive that decides: its file (``drive.yaml``) and the controller that drives it.

A drive is the track's path follower (pure pursuit and PI speed,
:class:`~crs_core.control.path_following.PathFollower`) at a speed reference, plus command
offsets held over equal segments: ``u = clip(follower(x) + [steer_offset[j], torque_offset[j]])``
in segment ``j``. The follower keeps the car on the track between the kicks that excite the
tyres and the motor; the offsets are what :mod:`crs_core.discrepancy.drive_design` chooses (or a
slalom's sine, sampled). After ``duration_s`` the drive is over (:meth:`DriveController.done`).

``drive.yaml`` (format ``crs-drive/1``)::

    format: crs-drive/1
    kind: designed            # designed | slalom (what made it)
    open: [Dr, Br, tau_motor] # the parameters it was designed to decide
    duration_s: 8.0           # s
    segment_s: 0.5            # s, each offset held this long (duration_s / segment_s of each)
    v_ref: 1.2                # m/s, the follower's speed reference
    a_lat_max: 4.0            # m/s^2, the follower's lateral-acceleration limit
    steer_offset: [...]       # rad, added to the follower's steering, one per segment
    torque_offset: [...]      # normalised torque (-), added to the follower's torque
    limits: {steer_max: 0.34, torque_min: -0.5, torque_max: 1.0}   # rad, -, -
    start: {x: 0.15, y: -1.05, yaw: 0.0, vx: 1.0}                  # m, m, rad, m/s (world)

``start`` is where the design assumed the drive begins (the track's start pose by default); the
car may begin it elsewhere on the track, the follower takes it from there.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from crs_core.control.path_following import PathFollower, PathFollowerSettings
from crs_core.errors import FieldError, finite_number
from crs_core.track import Track
from crs_core.yaml_io import load_yaml

#: ``format`` of a drive file.
DRIVE_FORMAT = "crs-drive/1"
#: A car within this distance of a drive's start position is at its start, m.
START_RADIUS = 0.15
#: ... when at least this share of the start's speed.
START_SPEED_SHARE = 0.8
#: What made a drive.
DRIVE_KINDS = ("designed", "slalom")


@dataclass(frozen=True)
class DriveLimits:
    """Command limits of a drive: steering ``±steer_max`` (rad), torque within
    ``[torque_min, torque_max]`` (normalised, -); inside the supervisor's defaults."""

    steer_max: float = 0.34
    torque_min: float = -0.5
    torque_max: float = 1.0


@dataclass(frozen=True)
class Drive:
    """A drive (the fields of ``drive.yaml``, module docstring)."""

    duration_s: float
    segment_s: float
    v_ref: float
    steer_offset: tuple[float, ...]
    torque_offset: tuple[float, ...]
    open: tuple[str, ...] = ()
    kind: str = "designed"
    a_lat_max: float = 4.0
    limits: DriveLimits = field(default_factory=DriveLimits)
    start: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("duration_s", "segment_s", "v_ref", "a_lat_max"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise FieldError(name, f"must be a positive number, got {value!r}")
        segments = self.segments
        for name in ("steer_offset", "torque_offset"):
            values = getattr(self, name)
            if len(values) != segments:
                raise FieldError(
                    name,
                    f"has {len(values)} values; duration_s / segment_s needs {segments}",
                )
            if not all(math.isfinite(v) for v in values):
                raise FieldError(name, "must be finite numbers")
        if self.kind not in DRIVE_KINDS:
            raise FieldError("kind", f"one of {', '.join(DRIVE_KINDS)}, got {self.kind!r}")
        lim = self.limits
        if not (0 < lim.steer_max < 0.5 * math.pi):
            raise FieldError("limits.steer_max", f"must be in (0, pi/2) rad, got {lim.steer_max}")
        if not lim.torque_min <= 0.0 < lim.torque_max:
            raise FieldError(
                "limits.torque_max", "needs torque_min <= 0 < torque_max (normalised torque)"
            )
        if len(self.start) != 4 or not all(math.isfinite(v) for v in self.start):
            raise FieldError("start", "needs finite x, y, yaw, vx")

    @property
    def segments(self) -> int:
        """Number of offset segments (``duration_s / segment_s``, rounded)."""
        return max(1, round(self.duration_s / self.segment_s))

    def offsets(self, t: float) -> tuple[float, float]:
        """The ``(steer, torque)`` offsets at ``t`` s into the drive (0 after it)."""
        if not 0.0 <= t < self.duration_s:
            return 0.0, 0.0
        j = min(int(t / self.segment_s), self.segments - 1)
        return self.steer_offset[j], self.torque_offset[j]

    def follower_settings(self) -> PathFollowerSettings:
        """The path follower's settings of this drive (its speed, bends and command limits)."""
        return PathFollowerSettings(
            v_ref=self.v_ref,
            a_lat_max=self.a_lat_max,
            steer_max=self.limits.steer_max,
            torque_min=self.limits.torque_min,
            torque_max=self.limits.torque_max,
        )

    def with_offsets(self, steer: Sequence[float], torque: Sequence[float]) -> Drive:
        """This drive with other offsets."""
        data = asdict(self) | {
            "steer_offset": tuple(float(v) for v in steer),
            "torque_offset": tuple(float(v) for v in torque),
            "limits": self.limits,
        }
        return Drive(**data)

    def to_dict(self) -> dict[str, Any]:
        """The ``drive.yaml`` document."""
        x, y, yaw, vx = self.start
        return {
            "format": DRIVE_FORMAT,
            "kind": self.kind,
            "open": list(self.open),
            "duration_s": float(self.duration_s),
            "segment_s": float(self.segment_s),
            "v_ref": float(self.v_ref),
            "a_lat_max": float(self.a_lat_max),
            "steer_offset": [round(float(v), 6) for v in self.steer_offset],
            "torque_offset": [round(float(v), 6) for v in self.torque_offset],
            "limits": {k: float(v) for k, v in asdict(self.limits).items()},
            "start": {"x": float(x), "y": float(y), "yaw": float(yaw), "vx": float(vx)},
        }

    def save(self, path: str | Path) -> Path:
        """Write ``drive.yaml`` to ``path``."""
        path = Path(path)
        path.write_text(yaml.safe_dump(self.to_dict(), sort_keys=False))
        return path


def _number(document: Mapping[str, Any], key: str, where: str, default: Any = None) -> float:
    value = document.get(key, default)
    if value is None:
        raise FieldError(f"{where}{key}", "required key missing")
    return finite_number(f"{where}{key}", value)


def _numbers(document: Mapping[str, Any], key: str) -> tuple[float, ...]:
    value = document.get(key)
    if not isinstance(value, list) or not value:
        raise FieldError(key, "must be a non-empty list of numbers")
    return tuple(finite_number(f"{key}[{i}]", v) for i, v in enumerate(value))


def drive_from_dict(document: Any) -> Drive:
    """A :class:`Drive` from a ``drive.yaml`` document; :class:`FieldError` naming the field."""
    if not isinstance(document, dict):
        raise FieldError("drive", "expected a mapping (a drive.yaml)")
    if document.get("format") != DRIVE_FORMAT:
        raise FieldError("format", f"must be {DRIVE_FORMAT!r}, got {document.get('format')!r}")
    duration, segment, v_ref = (
        _number(document, k, "") for k in ("duration_s", "segment_s", "v_ref")
    )
    steer, torque = (_numbers(document, k) for k in ("steer_offset", "torque_offset"))
    limits = document.get("limits", {})
    start = document.get("start")
    if not isinstance(limits, dict):
        raise FieldError("limits", "must be a mapping")
    if not isinstance(start, dict):
        raise FieldError("start", "must be a mapping with x, y, yaw, vx")
    unknown = set(limits) - {"steer_max", "torque_min", "torque_max"}
    if unknown:
        raise FieldError(f"limits.{sorted(unknown)[0]}", "unknown key")
    names = document.get("open", [])
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise FieldError("open", "must be a list of parameter names")
    defaults = DriveLimits()
    return Drive(
        duration_s=duration,
        segment_s=segment,
        v_ref=v_ref,
        steer_offset=steer,
        torque_offset=torque,
        a_lat_max=_number(document, "a_lat_max", "", 4.0),
        open=tuple(names),
        kind=document.get("kind", "designed"),
        limits=DriveLimits(
            **{k: _number(limits, k, "limits.", getattr(defaults, k)) for k in asdict(defaults)}
        ),
        start=tuple(_number(start, k, "start.") for k in ("x", "y", "yaw", "vx")),  # type: ignore[arg-type]
    )


def load_drive(path: str | Path) -> Drive:
    """Read and validate a ``drive.yaml``; :class:`FieldError` naming the file and the field."""
    path = Path(path)
    try:
        document = load_yaml(path.read_text())
    except yaml.YAMLError as error:
        raise FieldError(str(path), f"not valid YAML ({str(error).splitlines()[0]})") from None
    except OSError as error:
        raise FieldError(str(path), f"cannot read it ({error.strerror or error})") from None
    try:
        return drive_from_dict(document)
    except FieldError as error:
        raise error.renamed(f"{path}: {error.field}") from None


class DriveController:
    """``(t, x[, speed_limit]) -> u`` of a drive: the follower plus the drive's offsets, clipped.

    The drive begins at ``t_start``, or (``None``) at the first call, ``lead_in_s`` or more
    after the first, at which the car is where the design begins it (within
    :data:`START_RADIUS` of ``drive.start``'s position, heading within 45 degrees of its yaw) at
    :data:`START_SPEED_SHARE` of its speed or more: the offsets were chosen for that place on
    the track. A car that starts from rest first gets up to speed behind the follower (and
    laps until it passes the start at speed), and a lead-in is a race before the drive in the
    same recording. Before the drive
    and after its ``duration_s`` the follower alone drives. A car whose centre leaves the track
    (beyond half its width from the centreline) is stopped for good: zero torque, straight
    wheels.

    Parameters
    ----------
    drive : Drive
    track : Track
    wheelbase : float
        ``lf + lr``, m.
    t_start : float, optional
        The controller's time at which the drive begins, s.
    lead_in_s : float
        With ``t_start`` None: the follower alone drives at least this long first, s.
    """

    def __init__(
        self,
        drive: Drive,
        track: Track,
        wheelbase: float,
        t_start: float | None = 0.0,
        lead_in_s: float = 0.0,
    ) -> None:
        if not (math.isfinite(lead_in_s) and lead_in_s >= 0):
            raise FieldError("lead_in_s", f"must be >= 0 s, got {lead_in_s!r}")
        self.drive, self.lead_in_s = drive, float(lead_in_s)
        self.t_start = None if t_start is None else float(t_start)
        self._t_first: float | None = None
        self.follower = PathFollower(track, wheelbase, drive.follower_settings())
        self.edge = float(np.min(track.width)) / 2
        #: the car left the track: stopped for good
        self.stopped = False

    def done(self, t: float) -> bool:
        """The drive is over at controller time ``t`` s."""
        return self.t_start is not None and t - self.t_start >= self.drive.duration_s

    def reset(self) -> None:
        """Start the follower over (after a stop of the supervisor); the drive's clock runs on."""
        self.follower.reset()

    def __call__(self, t: float, x: np.ndarray, speed_limit: float | None = None) -> np.ndarray:
        state = np.asarray(x, dtype=float)[:6]
        if self._t_first is None:
            self._t_first = float(t)
        steer, torque = self.follower(t, state, speed_limit)
        if self.stopped or abs(self.lateral_error) > self.edge:
            self.stopped = True
            return np.zeros(2)
        if self.t_start is None and t - self._t_first >= self.lead_in_s and self.at_start(state):
            self.t_start = float(t)
        d_steer, d_torque = (
            (0.0, 0.0) if self.t_start is None else self.drive.offsets(t - self.t_start)
        )
        lim = self.drive.limits
        return np.array(
            [
                np.clip(steer + d_steer, -lim.steer_max, lim.steer_max),
                np.clip(torque + d_torque, lim.torque_min, lim.torque_max),
            ]
        )

    def at_start(self, state: np.ndarray) -> bool:
        """The car (base state) is where and as fast as the drive begins."""
        x, y, yaw, vx = self.drive.start
        near = math.hypot(state[0] - x, state[1] - y) <= START_RADIUS
        heading = math.cos(state[2] - yaw) >= math.cos(math.pi / 4)
        return near and heading and state[3] >= START_SPEED_SHARE * vx

    @property
    def lateral_error(self) -> float:
        """The follower's last distance from the centreline, m (left positive)."""
        status = self.follower.status
        return 0.0 if status is None else status.lateral_error
