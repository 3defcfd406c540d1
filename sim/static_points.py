"""Simulated static Lighthouse calibration points, written as a ``POINTS_FILE``.

The car stands at ``n`` known poses; at each, every base station's two light planes are swept
``sweeps`` times. Angles come from the model's Lighthouse outputs (``CarModel.numeric``, the
compiled ``output_function`` of every sensor) plus the white noise (and any bias) of the
simulator's Lighthouse sensor (:class:`sim.sensors.SensorSuite`, 1 mrad by default: the level
of the real recordings, see :mod:`sim.sensors`). Sweeps outside a station's view
(:data:`sim.simulator.LIGHTHOUSE_VIEW_LIMIT`) are not recorded. The known positions written to
the file can carry a reference error (``position_std``, e.g. 2 mm for motion capture).
The format is :mod:`crs_core.calibration.points`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from crs_core.calibration.points import CalibrationPoint, CalibrationPoints
from crs_core.errors import FieldError
from crs_core.model import CarModel
from crs_core.model.lighthouse import RECORDED_PHOTODIODES, BaseStation
from crs_core.model.sensors import N_PHOTODIODES
from crs_core.parameters import ParameterSet
from sim.sensors import SensorSuite
from sim.simulator import LIGHTHOUSE_VIEW_LIMIT

#: The area of the demo track (x from, x to, y from, y to), m: where the points are laid out.
TRACK_AREA = (-1.5, 1.5, -1.05, 1.05)


def grid_layout(
    n: int, area: tuple[float, float, float, float] = TRACK_AREA, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` positions (n, 2) filling ``area`` and random yaws (n,), rad.

    Points lie on the smallest grid with the area's aspect ratio holding ``n`` cells (cell
    centres, extra cells dropped evenly), so they are well spread for every ``n``.
    """
    if n < 1:
        raise FieldError("n", f"needs at least one point, got {n}")
    x0, x1, y0, y1 = area
    aspect = (x1 - x0) / (y1 - y0)
    columns = max(1, round(math.sqrt(n * aspect)))
    rows = math.ceil(n / columns)
    xs = x0 + (np.arange(columns) + 0.5) * (x1 - x0) / columns
    ys = y0 + (np.arange(rows) + 0.5) * (y1 - y0) / rows
    cells = np.array([(x, y) for y in ys for x in xs])
    keep = np.round(np.linspace(0, len(cells) - 1, n)).astype(int)
    rng = np.random.default_rng(seed)
    return cells[keep], rng.uniform(-math.pi, math.pi, n)


def simulate_static_points(
    stations: Sequence[BaseStation],
    positions: np.ndarray,
    yaws: np.ndarray,
    photodiodes: Sequence[tuple[float, float]] = RECORDED_PHOTODIODES,
    sensors: SensorSuite | None = None,
    sweeps: int = 20,
    seed: int = 0,
    yaw_known: bool = True,
    position_std: float = 0.0,
    write_tilts: bool = True,
) -> CalibrationPoints:
    """Sweeps of every station at every pose (module docstring).

    Parameters
    ----------
    stations : the true base stations.
    positions : (n, 2) true body-origin positions, m.
    yaws : (n,) true headings, rad.
    photodiodes : true photodiode positions (body frame), m; also written to the file.
    sensors : the noise of ``sensors.lighthouse`` is used (default: ``SensorSuite()``).
    sweeps : sweeps per plane recorded at each point.
    seed : seed of the noise.
    yaw_known : write the yaws (else they are left for the fit).
    position_std : std of the error of the written positions, m.
    write_tilts : write the stations' dt1, dt2 (as a station's data stream provides them).
    """
    sensors = sensors or SensorSuite()
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    yaws = np.asarray(yaws, dtype=float).reshape(-1)
    if yaws.size != positions.shape[0]:
        raise FieldError("yaws", "needs one yaw per position")
    if sweeps < 1:
        raise FieldError("sweeps", f"needs at least 1 sweep per point, got {sweeps}")
    model = CarModel(base_stations=list(stations))
    diode_values = {
        f"lh_d{k}_{axis}": float(photodiodes[k][a])
        for k in range(N_PHOTODIODES)
        for a, axis in enumerate("xy")
    }
    parameters: ParameterSet = model.parameters.updated(diode_values)
    p = parameters.vector()
    numeric = model.numeric
    spec = sensors.lighthouse
    noise = np.array(spec.noise_std, dtype=float)
    bias = np.array(spec.bias, dtype=float) if spec.bias else np.zeros(N_PHOTODIODES)
    rng = np.random.default_rng(seed)
    points = []
    for (x, y), yaw in zip(positions, yaws, strict=True):
        state = np.array([x, y, yaw, 0.0, 0.0, 0.0])
        outputs = numeric.outputs(state, np.zeros(2), p)
        recorded: dict[tuple[int, int], np.ndarray] = {}
        for s in range(len(stations)):
            for plane in (1, 2):
                clean = outputs[f"lighthouse/{s}/{plane}"]
                rows = clean + bias + noise * rng.standard_normal((sweeps, N_PHOTODIODES))
                visible = np.all(np.isfinite(rows), axis=1) & np.all(
                    np.abs(rows) <= LIGHTHOUSE_VIEW_LIMIT, axis=1
                )
                if visible.any():
                    recorded[(s, plane)] = rows[visible]
        written = np.array([x, y]) + position_std * rng.standard_normal(2)
        points.append(
            CalibrationPoint(
                (float(written[0]), float(written[1])),
                float(yaw) if yaw_known else None,
                recorded,
            )
        )
    tilts = tuple((s.dt1, s.dt2) if write_tilts else (None, None) for s in stations)
    return CalibrationPoints(tuple(points), tilts, tuple(map(tuple, photodiodes)))
