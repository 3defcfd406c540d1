"""Short human-readable report of a simulation run: numbers (text + JSON) and PNG plots.

Figures (``write_report``):

* ``path.png``: the true path on the track, coloured by the forward speed over the range
  actually driven.
* ``sensors.png``: every simulated sensor signal over time (all photodiodes of every base
  station, wheel speeds, IMU, yaw rate, steering and torque commands).
* ``estimation.png``: an offline estimator run over the simulated data, its x, y and yaw error
  against the simulator's truth over time with the estimator's own ±2σ band.

The error numbers come from :mod:`crs_core.analysis.metrics`, the error-band drawing from
:mod:`crs_core.analysis.figures` (shared with the figures of ``crs estimate`` and
``crs launch sim``).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from crs_core.analysis.figures import (
    ERROR_COMPONENTS,
    draw_error_panel,
    error_legend_handles,
    label_band_panel,
)
from crs_core.analysis.metrics import (
    band_statistics,
    interpolate_pose,
    lap_statistics,
    pose_error_bands,
)
from crs_core.estimation.offline import OfflineEstimates, estimate_dataset
from crs_core.measurements import lighthouse_sensor
from crs_core.model.sensors import N_PHOTODIODES
from crs_core.track import Track
from sim.simulator import SimulationResult

#: Sensor groups in words, for titles.
SENSOR_WORDS = {
    "lh": "Lighthouse",
    "imu": "IMU",
    "gyro": "gyro",
    "we": "wheel encoders",
    "pose": "motion capture",
}
#: A sample counts as moving (for the speed colour scale) above this fraction of the median
#: forward speed of the run.
MOVING_FRACTION = 0.5
#: Percentiles of the moving forward speed that bound the colour scale of ``path.png``.
SPEED_PERCENTILES = (2.0, 98.0)


def sensor_statistics(result: SimulationResult) -> dict[str, Any]:
    """Samples and effective rate per sensor."""
    out = {}
    for name in sorted({m.sensor for m in result.measurements}):
        stamps, _ = result.measurements_of(name)
        out[name] = {
            "samples": int(stamps.size),
            "rate_hz": round(stamps.size / result.duration, 2),
        }
    return out


def sensor_words(groups: str) -> str:
    """``"lh+imu+we"`` -> ``"Lighthouse + IMU + wheel encoders"``."""
    return " + ".join(SENSOR_WORDS.get(g, g) for g in groups.split("+"))


def speed_colour_limits(vx: np.ndarray) -> tuple[float, float]:
    """Colour-scale limits of the forward speed: the :data:`SPEED_PERCENTILES` of the samples
    where the car moves (above :data:`MOVING_FRACTION` of the median positive speed), so that the
    colours span the speeds actually driven rather than 0..max. At least 0.05 m/s wide."""
    vx = np.asarray(vx, dtype=float)
    positive = vx[vx > 0.05]
    moving = positive[positive >= MOVING_FRACTION * np.median(positive)] if positive.size else vx
    low, high = (float(v) for v in np.percentile(moving, SPEED_PERCENTILES))
    if high - low < 0.05:
        centre = 0.5 * (high + low)
        low, high = centre - 0.025, centre + 0.025
    return low, high


def estimation_errors(result: SimulationResult, kind: str = "mhe") -> dict[str, Any]:
    """Run the ``kind`` estimator offline over the simulated data (blind start, the nominal
    Chronos model, every sensor, the commanded inputs) and compare it with the truth.

    Returns the estimates (``"estimates"``), the error ``x, y, yaw`` (n, 3; NaN where the
    estimate is lost), the standard deviations (n, 3) and JSON-ready ``"summary"`` numbers
    (RMSE and fraction inside ±2σ per component, in mm / mrad). Raises ``ValueError`` when the
    run has nothing to estimate from (e.g. no Lighthouse sample).
    """
    started = time.perf_counter()
    estimates = estimate_dataset(result.to_dataset(), kind)
    wall = time.perf_counter() - started
    found = estimates.status != "lost"
    truth = interpolate_pose(estimates.t, result.truth_t, result.truth_x)
    errors, sigmas = pose_error_bands(
        estimates.x[:3].T, estimates.covariance_diag[:3].T, truth, found
    )
    d = estimates.diagnostics
    summary: dict[str, Any] = {
        "estimator": kind,
        "sensors": d["sensors"],
        "start": d["start"],
        "samples": int(estimates.t.size),
        "samples_not_lost": int(found.sum()),
        "time_to_first_fix_s": d["time_to_first_fix_s"],
        "wall_time_s": round(d["wall_time_s"], 2),
        "total_time_s": round(wall, 2),
    }
    for k, (name, unit, factor) in enumerate(ERROR_COMPONENTS):
        stats = band_statistics(errors[:, k] * factor, sigmas[:, k] * factor)
        summary[name] = {
            f"rmse_{unit}": None if stats["rmse"] is None else round(stats["rmse"], 3),
            "inside_2sigma": None
            if stats["inside_2sigma"] is None
            else round(stats["inside_2sigma"], 3),
        }
    return {"estimates": estimates, "errors": errors, "sigmas": sigmas, "summary": summary}


def write_report(
    result: SimulationResult,
    track: Track,
    folder: str | Path,
    extra: dict[str, Any] | None = None,
    estimator: str | None = "mhe",
) -> Path:
    """Write ``summary.txt``, ``summary.json``, ``path.png``, ``sensors.png`` and (unless
    ``estimator`` is None) ``estimation.png`` into ``folder``.

    ``estimator`` (``"mhe"``, the suite's main estimator, or ``"ekf"``) runs over the
    simulated data offline for the estimation error figure and the ``estimation`` numbers; None
    skips it. Its cost: the MHE about 3.5 s for a 40 s run (the EKF about 1.7 s), plus a
    one-off 15–20 s on a machine where its compiled code is not cached yet (EKF about 5 s).
    When the run has nothing to estimate from (no Lighthouse data), ``estimation`` says why
    and there is no ``estimation.png``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    speed = result.truth_x[:, 3]
    summary = {
        "duration_s": result.duration,
        "seed": result.seed,
        "effects": {
            e.name: {p.name: result.model.parameters.value(p.name) for p in e.parameters}
            for e in result.model.effects
        },
        "mean_speed_mps": round(float(speed.mean()), 3),
        "max_speed_mps": round(float(speed.max()), 3),
        **lap_statistics(result.truth_t, result.truth_x, track),
        "sensors": sensor_statistics(result),
    }
    estimation = None
    if estimator is not None:
        try:
            estimation = estimation_errors(result, estimator)
            summary["estimation"] = estimation["summary"]
        except ValueError as error:
            summary["estimation"] = {"estimator": estimator, "skipped": str(error)}
    summary.update(extra or {})
    (folder / "summary.json").write_text(json.dumps(summary, indent=2))
    (folder / "summary.txt").write_text(_summary_text(result, summary))
    _save(path_figure(result, track), folder / "path.png", dpi=120)
    _save(sensors_figure(result), folder / "sensors.png", dpi=100)
    if estimation is not None:
        _save(estimation_figure(estimation), folder / "estimation.png", dpi=100)
    return folder


def _save(fig, path: Path, dpi: int) -> None:
    fig.savefig(path, dpi=dpi)


def _summary_text(result: SimulationResult, summary: dict[str, Any]) -> str:
    lines = [f"Chronos simulation: {result.duration:.1f} s, seed {result.seed}"]
    for key, value in summary.items():
        if key == "sensors":
            lines.append("sensors:")
            lines += [f"  {n}: {v['samples']} samples, {v['rate_hz']} Hz" for n, v in value.items()]
        elif key == "estimation" and "skipped" in value:
            lines.append(f"estimation: {value['estimator']} skipped ({value['skipped']})")
        elif key == "estimation":
            lines.append(
                f"estimation: {value['estimator'].upper()} on {value['sensors']} (offline, "
                f"{value['start']} start), {value['samples_not_lost']} of {value['samples']} "
                f"samples not lost, {value['total_time_s']} s"
            )
            for name, unit, _ in ERROR_COMPONENTS:
                v = value[name]
                if v[f"rmse_{unit}"] is not None:
                    inside = v["inside_2sigma"]
                    lines.append(
                        f"  {name} error: RMSE {v[f'rmse_{unit}']:.2f} {unit}, "
                        + (
                            "no covariance"
                            if inside is None
                            else f"{100 * inside:.1f} % inside ±2σ"
                        )
                    )
        else:
            lines.append(f"{key}: {value}")
    return "\n".join(lines) + "\n"


def path_figure(result: SimulationResult, track: Track):
    """``path.png``: track borders, centreline, the true path coloured by forward speed (scale
    from :func:`speed_colour_limits`), start marker and colour bar."""
    fig = Figure(figsize=(8, 6))
    ax = fig.subplots()
    for edge, label in zip(track.borders(), ("track borders", None), strict=True):
        ax.plot(edge[:, 0], edge[:, 1], color="0.3", lw=1, label=label)
    ax.plot(track.x, track.y, "--", color="0.6", lw=0.8, label="centerline")
    low, high = speed_colour_limits(result.truth_x[:, 3])
    points = ax.scatter(
        result.truth_x[::2, 0],
        result.truth_x[::2, 1],
        c=result.truth_x[::2, 3],
        s=3,
        cmap="viridis",
        vmin=low,
        vmax=high,
        label="driven path (true)",
    )
    ax.plot(*result.truth_x[0, :2], "r^", ms=8, label="start")
    fig.colorbar(points, ax=ax, extend="both", shrink=0.8, label="forward speed v_x [m/s]")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (world)")
    ax.set_ylabel("y [m] (world)")
    ax.grid(alpha=0.3)
    low_p, high_p = SPEED_PERCENTILES
    ax.set_title(
        f"Simulated Chronos run, {result.duration:g} s: true path coloured by forward speed\n"
        f"colour scale {low:.2f}–{high:.2f} m/s: percentiles {low_p:g}–{high_p:g} of v_x while "
        "moving (arrows: beyond)",
        fontsize=9,
    )
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.11), ncol=4, fontsize=8)
    fig.tight_layout()
    return fig


def _lighthouse_stations(result: SimulationResult) -> list[int]:
    stations = set()
    for m in result.measurements:
        if m.sensor.startswith("lighthouse/"):
            stations.add(int(m.sensor.split("/")[1]))
    return sorted(stations)


def sensors_figure(result: SimulationResult):
    """``sensors.png``: per Lighthouse base station the sweep angle of each plane and every
    photodiode's offset, then wheel speeds, IMU, yaw rate, steering and torque commands."""
    stations = _lighthouse_stations(result)
    heights = [1.0, 0.9, 0.9] * len(stations) + [0.9, 0.9, 0.9, 0.7, 0.7]
    fig = Figure(figsize=(11, 1.9 * sum(heights) + 0.6), layout="constrained")
    axes = fig.subplots(len(heights), 1, sharex=True, gridspec_kw={"height_ratios": heights})
    for k, station in enumerate(stations):
        _plot_lighthouse(result, station, axes[3 * k : 3 * k + 3])
    axes = axes[3 * len(stations) :]
    t, v = result.measurements_of("wheel_encoders")
    if t.size:
        for i, name in enumerate(("front left", "front right", "rear left", "rear right")):
            axes[0].plot(t, v[:, i], lw=0.5, alpha=0.8, label=name)
        _legend_right(axes[0], title="front ≈ rear\non each side", title_fontsize=7)
    axes[0].set_ylabel("wheel speed\n[rad/s]")
    t, v = result.measurements_of("imu")
    if t.size:
        axes[1].plot(t, v[:, 0], lw=0.5, label="a_x (forward)")
        axes[1].plot(t, v[:, 1], lw=0.5, label="a_y (left)")
        axes[2].plot(t, v[:, 2], lw=0.5, label="IMU gyro")
    axes[1].set_ylabel("IMU specific\nforce [m/s²]")
    axes[2].plot(result.truth_t, result.truth_x[:, 5], "k", lw=0.8, label="true ω")
    axes[2].set_ylabel("yaw rate\n[rad/s]")
    stamps = np.array([s.stamp for s in result.inputs])
    inputs = np.stack([s.u for s in result.inputs])
    axes[3].step(stamps, inputs[:, 0], where="post", color="tab:purple")
    axes[3].set_ylabel("steering\ncommand [rad]")
    axes[4].step(stamps, inputs[:, 1], where="post", color="tab:brown")
    axes[4].set_ylabel("torque command\n[–] (normalised)")
    axes[4].set_xlabel("t [s] (simulation time)")
    for ax in fig.axes:
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0] and ax.get_legend() is None:
            _legend_right(ax)
    fig.align_ylabels(fig.axes)
    fig.suptitle(f"Simulated sensor signals and commands (with noise), seed {result.seed}")
    return fig


def _legend_right(ax, **kwargs) -> None:
    ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=7, frameon=False, **kwargs)


def _plot_lighthouse(result: SimulationResult, station: int, axes) -> None:
    """One base station: the sweep angle of each plane (mean of the photodiodes, which lie
    within a few mrad of each other at this scale), then per plane every photodiode's offset
    from that mean, which tells the diodes apart."""
    plane_colours = {1: "black", 2: "tab:gray"}
    for plane in (1, 2):
        t, v = result.measurements_of(lighthouse_sensor(station, plane))
        ax = axes[plane]
        if t.size:
            mean = np.nanmean(v, axis=1)
            axes[0].plot(t, mean, ".", color=plane_colours[plane], ms=1.5, label=f"plane {plane}")
            offset = 1e3 * (v - mean[:, None])
            for diode in range(v.shape[1]):
                ax.plot(t, offset[:, diode], ".", color=f"C{diode}", ms=1.2, label=f"diode {diode}")
        ax.set_ylabel(f"LH{station} plane {plane}:\ndiode − mean\n[mrad]")
        if ax.get_legend_handles_labels()[0]:
            _legend_right(ax, markerscale=5)
    axes[0].set_ylabel(f"Lighthouse {station}\nsweep angle\n[rad]")
    if axes[0].get_legend_handles_labels()[0]:
        _legend_right(
            axes[0], markerscale=5, title=f"mean of {N_PHOTODIODES} diodes", title_fontsize=7
        )


def estimation_figure(estimation: dict[str, Any]):
    """``estimation.png``: x, y and yaw error against the truth inside the ±2σ band, from
    :func:`estimation_errors`."""
    estimates: OfflineEstimates = estimation["estimates"]
    summary = estimation["summary"]
    t = estimates.t
    lost = estimates.status == "lost"
    fig = Figure(figsize=(11, 7.5), layout="constrained")
    axes = fig.subplots(3, 1, sharex=True)
    for k, (ax, (name, unit, factor)) in enumerate(zip(axes, ERROR_COMPONENTS, strict=True)):
        error = estimation["errors"][:, k] * factor
        sigma = np.where(lost, np.nan, estimation["sigmas"][:, k] * factor)
        off_scale = draw_error_panel(ax, t, error, sigma, estimates.status, unit)
        label_band_panel(ax, name, unit, [("", band_statistics(error, sigma))], off_scale)
    handles = error_legend_handles("simulation truth", status_prefix="status ")
    fig.legend(handles=handles, loc="outside lower center", ncol=4, fontsize=8)
    axes[-1].set_xlabel("t [s] (simulation time)")
    fig.suptitle(
        f"Estimation error over time: offline {summary['estimator'].upper()} on "
        f"{sensor_words(summary['sensors'])} ({summary['start']} start) vs the simulator's truth",
        fontsize=11,
    )
    return fig
