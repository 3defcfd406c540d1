"""What the visualizer shows, built from plain values (no ROS): the Foxglove scene, frames,
per-car status and the built-in page's JSON.

:class:`CarWatch` follows one car from its validated messages (estimate, truth, estimator
diagnostics, the controller's plan and solve time, the Lighthouse pose fixes, the online
parameters) and counts its laps
(:class:`~crs_core.analysis.laps.LapCounter` on the track's projection); :meth:`CarWatch.view`
is a :class:`CarView`, a snapshot the builders below turn into messages:
:func:`track_scene` / :func:`cars_scene` (``foxglove.SceneUpdate``), :func:`frame_transforms`
(``foxglove.FrameTransforms``), :func:`status_json` (``/viz/<car>/status``),
:func:`page_track_json` and :func:`page_cars_json` (the built-in page's contract,
``docs/live-view.md``). Every position is in the ``world`` frame, m; yaw in rad,
counter-clockwise from world x; stamps in s.

The car's footprint is the simulator's (:data:`sim.closed_loop.CAR_LENGTH` x
:data:`sim.closed_loop.CAR_WIDTH`), centred on the centre of mass.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from foxglove.messages import (
    Color,
    CubePrimitive,
    FrameTransform,
    FrameTransforms,
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
    Timestamp,
    Vector3,
)

from crs_core.analysis.laps import LapCounter
from crs_core.analysis.statistics import covariance_ellipse
from crs_core.errors import FieldError
from crs_core.estimation.base import OnlineValue
from crs_core.track import Track
from ros4crs.conversions import body_frame, stamp_ns
from sim.closed_loop import CAR_LENGTH, CAR_WIDTH

__all__ = [
    "CAR_SIZE",
    "PAGE_CARS_SCHEMA",
    "PAGE_TRACK_SCHEMA",
    "SCENE_CHANNEL",
    "STATUSES",
    "STATUS_SCHEMA",
    "CarView",
    "CarWatch",
    "car_status",
    "cars_scene",
    "frame_transforms",
    "page_cars_json",
    "page_track_json",
    "position_covariance",
    "status_channel",
    "status_json",
    "track_scene",
]

#: The channel of the scene (``foxglove.SceneUpdate``).
SCENE_CHANNEL = "/viz/scene"


def status_channel(car: str) -> str:
    """The JSON status channel of ``car`` (a namespace without the slash)."""
    return f"/viz/{car}/status"


#: A car's footprint ``[length, width]``, m.
CAR_SIZE = (CAR_LENGTH, CAR_WIDTH)
#: Height of the drawn footprint, m.
CAR_HEIGHT = 0.04
#: The statuses a car can have: ``none`` (no estimate yet), ``ok``, ``degraded``, ``lost``.
STATUSES = ("ok", "degraded", "lost", "none")
#: An estimate older than this (receive time, s) counts as lost: the estimator publishes
#: nothing while lost, and the controller stops the car after 0.2 s without one.
STALE_AFTER = 0.5
#: Standard deviations of the drawn position-covariance ellipse.
ELLIPSE_SIGMA = 2.0
#: Points of the drawn ellipse.
ELLIPSE_POINTS = 32
#: Lighthouse pose fixes stay drawn this long after they arrived, s.
FIX_MEMORY = 0.5
#: Diameter of a drawn fix and length of its heading tick, m.
FIX_SIZE = (0.02, 0.06)

_STATUS_COLOURS = {
    "ok": Color(r=0.1, g=0.7, b=0.2, a=0.9),
    "degraded": Color(r=0.95, g=0.6, b=0.05, a=0.9),
    "lost": Color(r=0.85, g=0.1, b=0.1, a=0.9),
    "none": Color(r=0.5, g=0.5, b=0.5, a=0.9),
}
_TRUTH_COLOUR = Color(r=0.3, g=0.3, b=0.9, a=0.3)
_BORDER_COLOUR = Color(r=0.2, g=0.2, b=0.2, a=1.0)
_CENTRE_COLOUR = Color(r=0.6, g=0.6, b=0.6, a=1.0)
_PLAN_COLOUR = Color(r=0.1, g=0.5, b=1.0, a=1.0)
_REFERENCE_COLOUR = Color(r=1.0, g=0.8, b=0.1, a=0.9)
_ELLIPSE_COLOUR = Color(r=0.9, g=0.1, b=0.6, a=1.0)
_FIX_COLOUR = Color(r=0.0, g=0.75, b=0.75, a=0.9)


@dataclass(frozen=True)
class CarView:
    """A snapshot of one car, as the viewers see it.

    Attributes
    ----------
    name : str
        The car's namespace without the slash (``car1``).
    status : str
        One of :data:`STATUSES`.
    reason : str
        Why the status is not ``ok`` (``""`` when it is).
    estimate : numpy.ndarray or None
        ``[x, y, yaw]`` of the newest estimate (m, m, rad; world), None when there is none or
        it is lost.
    covariance : numpy.ndarray or None
        The estimate's 2 x 2 position covariance, m^2 (None: unknown).
    truth : numpy.ndarray or None
        ``[x, y, yaw]`` of the simulator's ground truth (None: no simulator).
    plan : numpy.ndarray
        The controller's planned positions ``(n, 2)``, m (empty: no plan).
    reference : numpy.ndarray
        The centreline points at the plan's progress ``(n, 2)``, m (empty: none).
    fixes : numpy.ndarray
        The Lighthouse pose fixes of the last :data:`FIX_MEMORY` s, ``(n, 3)`` rows
        ``[x, y, yaw]`` (m, m, rad; empty: none).
    laps : int
        Laps completed (by the estimate).
    last_lap_s : float or None
        Duration of the last completed lap, s.
    solve_ms : float or None
        The controller's last call time, ms.
    deadline_misses : int
        The estimator's updates slower than their deadline, since it started.
    stamp : float or None
        Stamp of the newest estimate, s.
    parameters : dict of str to OnlineValue
        The estimator's online parameters by name (value and std in the parameter's unit,
        whether the data inform it; empty: none estimated).
    """

    name: str
    status: str = "none"
    reason: str = "no estimate yet"
    estimate: np.ndarray | None = None
    covariance: np.ndarray | None = None
    truth: np.ndarray | None = None
    plan: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    reference: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    fixes: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    laps: int = 0
    last_lap_s: float | None = None
    solve_ms: float | None = None
    deadline_misses: int = 0
    stamp: float | None = None
    parameters: Mapping[str, OnlineValue] = field(default_factory=dict)


def car_status(
    age: float | None, estimate_status: str | None, estimator_status: str | None
) -> tuple[str, str]:
    """A car's status and its reason.

    Parameters
    ----------
    age : float or None
        Time since the newest estimate arrived, s (None: none arrived yet).
    estimate_status : str or None
        That estimate's status (``ok`` / ``degraded``).
    estimator_status : str or None
        The estimator's last diagnostics status (``ok``, ``degraded: why``, ``lost: why``).

    Returns
    -------
    tuple of str
        One of :data:`STATUSES` and the reason (``""`` for ``ok``).
    """
    kind, _, why = (estimator_status or "").partition(":")
    why = why.strip()
    if age is None:
        return "none", why or "no estimate yet"
    if age > STALE_AFTER:
        return "lost", why if kind == "lost" and why else f"no estimate for {age:.1f} s"
    if estimate_status == "degraded":
        return "degraded", why if kind == "degraded" and why else "estimate degraded"
    return "ok", ""


class CarWatch:
    """One car's view, updated from its validated messages.

    Parameters
    ----------
    name : str
        The car's namespace without the slash (``car1``).
    track : Track
        The track its laps are counted on.
    """

    def __init__(self, name: str, track: Track) -> None:
        self.name, self.track = name, track
        self.laps = LapCounter(track.length)
        self._s_hint: float | None = None
        self._received: float | None = None
        self._stamp: float | None = None
        self._state: np.ndarray | None = None
        self._covariance: np.ndarray | None = None
        self._estimate_status: str | None = None
        self._estimator_status: str | None = None
        self._deadline_misses = 0
        self._truth: np.ndarray | None = None
        self._plan = np.zeros((0, 2))
        self._reference = np.zeros((0, 2))
        self._solve_ms: float | None = None
        self._fixes: deque[tuple[float, np.ndarray]] = deque()
        self._parameters: Mapping[str, OnlineValue] = {}

    def estimate(
        self,
        received: float,
        stamp: float,
        x: np.ndarray,
        status: str,
        covariance: np.ndarray | None,
    ) -> None:
        """A state estimate arrived at ``received`` (monotonic s): stamp (s), state (6,),
        status and position covariance (2 x 2, m^2; None: unknown), all checked. A stamp older
        than the last (a replayed bag that loops) starts the lap count over."""
        if self._stamp is not None and stamp < self._stamp:
            self.laps.reset()
            self._s_hint = None
        projection = self.track.project(x[0], x[1], self._s_hint)
        self._s_hint = projection.s
        self.laps.update(stamp, projection.s)
        self._received, self._stamp, self._state = received, stamp, np.asarray(x, dtype=float)
        self._estimate_status, self._covariance = status, covariance

    def truth(self, x: np.ndarray) -> None:
        """The simulator's ground truth, state (6,)."""
        self._truth = np.asarray(x[:3], dtype=float)

    def diagnostics(self, status: str, deadline_misses: int) -> None:
        """The estimator's diagnostics: status text and deadline misses since it started."""
        self._estimator_status, self._deadline_misses = status, int(deadline_misses)

    def plan(self, points: np.ndarray) -> None:
        """The controller's planned positions ``(n, 2)``, m."""
        self._plan = np.asarray(points, dtype=float).reshape(-1, 2)

    def reference(self, points: np.ndarray) -> None:
        """The centreline points at the plan's progress ``(n, 2)``, m."""
        self._reference = np.asarray(points, dtype=float).reshape(-1, 2)

    def solve_time(self, seconds: float) -> None:
        """The controller's last call time, s."""
        self._solve_ms = 1e3 * float(seconds)

    def lighthouse_fix(self, received: float, pose: np.ndarray) -> None:
        """A Lighthouse pose fix ``[x, y, yaw]`` (m, m, rad) arrived at ``received``
        (monotonic s)."""
        self._fixes.append((received, np.asarray(pose[:3], dtype=float)))

    def parameters(self, values: Mapping[str, OnlineValue]) -> None:
        """The estimator's online parameters by name (checked)."""
        self._parameters = dict(values)

    def view(self, now: float) -> CarView:
        """The snapshot at ``now`` (monotonic s, the clock of ``received``)."""
        age = None if self._received is None else now - self._received
        while self._fixes and self._fixes[0][0] < now - FIX_MEMORY:
            self._fixes.popleft()
        status, reason = car_status(age, self._estimate_status, self._estimator_status)
        shown = status in ("ok", "degraded") and self._state is not None
        times = self.laps.lap_times
        return CarView(
            name=self.name,
            status=status,
            reason=reason,
            estimate=self._state[:3].copy() if shown and self._state is not None else None,
            covariance=self._covariance if shown else None,
            truth=self._truth,
            plan=self._plan if shown else np.zeros((0, 2)),
            reference=self._reference if shown else np.zeros((0, 2)),
            fixes=np.array([pose for _, pose in self._fixes]).reshape(-1, 3),
            laps=self.laps.laps_completed,
            last_lap_s=times[-1] if times else None,
            solve_ms=self._solve_ms,
            deadline_misses=self._deadline_misses,
            stamp=self._stamp,
            parameters=self._parameters,
        )


# --- geometry --------------------------------------------------------------------------------
def position_covariance(covariance: Sequence[float]) -> np.ndarray | None:
    """The 2 x 2 position block (m^2) of a ``CarState.covariance`` (36 values, row-major 6 x 6),
    None when it is all zeros (unknown). ``FieldError`` naming ``covariance`` unless it is
    finite, symmetric and positive semi-definite (up to rounding)."""
    P = np.asarray(covariance, dtype=float)
    if P.size != 36 or not np.all(np.isfinite(P)):
        raise FieldError("covariance", f"expected 36 finite values, got {P.size}")
    block = P.reshape(6, 6)[:2, :2]
    if not np.any(block):
        return None
    scale = float(np.max(np.abs(block)))
    if abs(block[0, 1] - block[1, 0]) > 1e-9 * scale:
        raise FieldError("covariance", f"the position block is not symmetric: {block.tolist()}")
    if np.linalg.eigvalsh(block)[0] < -1e-9 * scale:
        raise FieldError("covariance", f"the position block is not positive: {block.tolist()}")
    return block


def _timestamp(seconds: float) -> Timestamp:
    return Timestamp(*divmod(stamp_ns(seconds), 1_000_000_000))


def _yaw_quaternion(yaw: float) -> Quaternion:
    return Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))


def _pose(x: float, y: float, yaw: float, z: float = 0.0) -> Pose:
    return Pose(position=Vector3(x=x, y=y, z=z), orientation=_yaw_quaternion(yaw))


def _line(points: np.ndarray, kind: Any, colour: Color, thickness: float, z: float) -> Any:
    return LinePrimitive(
        type=kind,
        pose=_pose(0.0, 0.0, 0.0),
        thickness=thickness,
        points=[Point3(x=float(px), y=float(py), z=z) for px, py in points],
        color=colour,
    )


# --- scene -----------------------------------------------------------------------------------
def track_scene(track: Track, stamp: float) -> SceneUpdate:
    """The entity ``track`` (frame ``world``): both borders and the centreline as line loops."""
    left, right = track.borders()
    centre = np.stack([track.x, track.y], axis=1)
    loop = LinePrimitiveLineType.LineLoop
    return SceneUpdate(
        entities=[
            SceneEntity(
                timestamp=_timestamp(stamp),
                frame_id="world",
                id="track",
                lines=[
                    _line(left, loop, _BORDER_COLOUR, 0.01, 0.0),
                    _line(right, loop, _BORDER_COLOUR, 0.01, 0.0),
                    _line(centre, loop, _CENTRE_COLOUR, 0.004, 0.0),
                ],
            )
        ]
    )


def _footprint(pose: np.ndarray, colour: Color) -> CubePrimitive:
    length, width = CAR_SIZE
    return CubePrimitive(
        pose=_pose(float(pose[0]), float(pose[1]), float(pose[2]), CAR_HEIGHT / 2),
        size=Vector3(x=length, y=width, z=CAR_HEIGHT),
        color=colour,
    )


def cars_scene(cars: list[CarView], stamp: float) -> SceneUpdate:
    """One entity per car (id its name, frame ``world``; each update replaces the last): the
    estimate's footprint coloured by status, the truth's fainter one, the 2-sigma position
    ellipse, the planned horizon and its progress reference on the centreline, the recent
    Lighthouse pose fixes (a dot with a heading tick each; whichever exist)."""
    entities = []
    for car in cars:
        cubes, lines, spheres = [], [], []
        if car.estimate is not None:
            cubes.append(_footprint(car.estimate, _STATUS_COLOURS[car.status]))
            if car.covariance is not None:
                ellipse = covariance_ellipse(
                    car.estimate, car.covariance, ELLIPSE_SIGMA, ELLIPSE_POINTS
                )
                lines.append(
                    _line(ellipse, LinePrimitiveLineType.LineLoop, _ELLIPSE_COLOUR, 0.004, 0.05)
                )
        if car.truth is not None:
            cubes.append(_footprint(car.truth, _TRUTH_COLOUR))
        if len(car.plan) >= 2:
            lines.append(
                _line(car.plan, LinePrimitiveLineType.LineStrip, _PLAN_COLOUR, 0.008, 0.01)
            )
        if len(car.reference) >= 2:
            lines.append(
                _line(
                    car.reference, LinePrimitiveLineType.LineStrip, _REFERENCE_COLOUR, 0.004, 0.01
                )
            )
        if len(car.fixes):
            spheres, ticks = _fix_marks(car.fixes)
            lines.append(ticks)
        entities.append(
            SceneEntity(
                timestamp=_timestamp(stamp),
                frame_id="world",
                id=car.name,
                cubes=cubes,
                lines=lines,
                spheres=spheres,
            )
        )
    return SceneUpdate(entities=entities)


def _fix_marks(fixes: np.ndarray) -> tuple[list[SpherePrimitive], LinePrimitive]:
    """A dot at each fix and a tick along its heading (one line list)."""
    diameter, tick = FIX_SIZE
    z = 0.06  # above the footprint: a fix under the car is still seen
    dots = [
        SpherePrimitive(
            pose=_pose(float(x), float(y), 0.0, z),
            size=Vector3(x=diameter, y=diameter, z=diameter),
            color=_FIX_COLOUR,
        )
        for x, y, _ in fixes
    ]
    ends = fixes[:, :2] + tick * np.column_stack([np.cos(fixes[:, 2]), np.sin(fixes[:, 2])])
    segments = np.stack([fixes[:, :2], ends], axis=1).reshape(-1, 2)
    return dots, _line(segments, LinePrimitiveLineType.LineList, _FIX_COLOUR, 0.004, z)


def frame_transforms(cars: list[CarView], stamp: float) -> FrameTransforms:
    """``world`` -> ``<car>/base_link`` of every car with an estimate (planar, z = 0)."""
    return FrameTransforms(
        transforms=[
            FrameTransform(
                timestamp=_timestamp(stamp),
                parent_frame_id="world",
                child_frame_id=body_frame(car.name),
                translation=Vector3(x=float(car.estimate[0]), y=float(car.estimate[1]), z=0.0),
                rotation=_yaw_quaternion(float(car.estimate[2])),
            )
            for car in cars
            if car.estimate is not None
        ]
    )


# --- JSON ------------------------------------------------------------------------------------
def _points(array: np.ndarray) -> list[list[float]]:
    return [[round(float(x), 4), round(float(y), 4)] for x, y in np.asarray(array).reshape(-1, 2)]


def _pose_list(pose: np.ndarray | None) -> list[float] | None:
    return None if pose is None else [round(float(v), 4) for v in pose[:3]]


def _maybe(value: float | None, digits: int) -> float | None:
    return None if value is None or not math.isfinite(value) else round(float(value), digits)


def _parameters_json(car: CarView) -> list[dict[str, Any]]:
    return [
        {
            "name": name,
            "value": _maybe(p.value, 6),
            "std": _maybe(p.std, 6),
            "informed": bool(p.informed),
        }
        for name, p in car.parameters.items()
    ]


def status_json(car: CarView) -> dict[str, Any]:
    """``/viz/<car>/status``: status, reason, laps, last lap (s), solve time (ms), the
    estimator's deadline misses and its online parameters (:data:`STATUS_SCHEMA`)."""
    return {
        "status": car.status,
        "reason": car.reason,
        "laps": car.laps,
        "last_lap_s": _maybe(car.last_lap_s, 3),
        "solve_ms": _maybe(car.solve_ms, 3),
        "deadline_misses": car.deadline_misses,
        "parameters": _parameters_json(car),
    }


def page_track_json(track: Track) -> dict[str, Any]:
    """``/viz/page/track``: the centreline and both borders, ``[[x, y], ...]`` m, world."""
    left, right = track.borders()
    return {
        "centre": _points(np.stack([track.x, track.y], axis=1)),
        "left": _points(left),
        "right": _points(right),
    }


def page_cars_json(cars: list[CarView], stamp: float) -> dict[str, Any]:
    """``/viz/page/cars``: every car's status, estimate and truth ``[x, y, yaw]`` (or null),
    plan, recent Lighthouse fixes ``[[x, y, yaw], ...]``, size ``[length, width]`` (m), laps,
    last lap (s) and online parameters (name, value, std, informed) at ``stamp`` (s)."""
    return {
        "stamp": round(stamp, 6),
        "cars": [
            {
                "name": car.name,
                "status": car.status,
                "reason": car.reason,
                "estimate": _pose_list(car.estimate),
                "truth": _pose_list(car.truth),
                "plan": _points(car.plan),
                "fixes": [_pose_list(fix) for fix in car.fixes],
                "size": list(CAR_SIZE),
                "laps": car.laps,
                "last_lap_s": _maybe(car.last_lap_s, 3),
                "parameters": _parameters_json(car),
            }
            for car in cars
        ],
    }


_POINTS = {"type": "array", "items": {"type": "array", "items": {"type": "number"}}}
_POSE = {"type": ["array", "null"], "items": {"type": "number"}, "minItems": 3, "maxItems": 3}
_STATUS = {"type": "string", "enum": list(STATUSES)}
_PARAMETERS = {
    "type": "array",
    "items": {
        "type": "object",
        "properties": {
            "name": {"type": "string"},
            "value": {"type": ["number", "null"]},
            "std": {"type": ["number", "null"]},
            "informed": {"type": "boolean"},
        },
        "required": ["name", "value", "std", "informed"],
    },
}
#: JSON schema of :func:`status_json`.
STATUS_SCHEMA: dict[str, Any] = {
    "title": "chronos.CarStatus",
    "type": "object",
    "properties": {
        "status": _STATUS,
        "reason": {"type": "string"},
        "laps": {"type": "integer"},
        "last_lap_s": {"type": ["number", "null"]},
        "solve_ms": {"type": ["number", "null"]},
        "deadline_misses": {"type": "integer"},
        "parameters": _PARAMETERS,
    },
    "required": [
        "status",
        "reason",
        "laps",
        "last_lap_s",
        "solve_ms",
        "deadline_misses",
        "parameters",
    ],
}
#: JSON schema of :func:`page_track_json`.
PAGE_TRACK_SCHEMA: dict[str, Any] = {
    "title": "chronos.PageTrack",
    "type": "object",
    "properties": {"centre": _POINTS, "left": _POINTS, "right": _POINTS},
    "required": ["centre", "left", "right"],
}
#: JSON schema of :func:`page_cars_json`.
PAGE_CARS_SCHEMA: dict[str, Any] = {
    "title": "chronos.PageCars",
    "type": "object",
    "properties": {
        "stamp": {"type": "number"},
        "cars": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "name": {"type": "string"},
                    "status": _STATUS,
                    "reason": {"type": "string"},
                    "estimate": _POSE,
                    "truth": _POSE,
                    "plan": _POINTS,
                    "fixes": _POINTS,
                    "size": {"type": "array", "items": {"type": "number"}},
                    "laps": {"type": "integer"},
                    "last_lap_s": {"type": ["number", "null"]},
                    "parameters": _PARAMETERS,
                },
                "required": [
                    "name",
                    "status",
                    "reason",
                    "estimate",
                    "truth",
                    "plan",
                    "fixes",
                    "size",
                    "laps",
                    "last_lap_s",
                    "parameters",
                ],
            },
        },
    },
    "required": ["stamp", "cars"],
}
