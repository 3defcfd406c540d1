"""Output of ``crs estimate``: the summary text and the figure ``estimate.png`` (no algorithm).

The estimates and metrics come from :mod:`crs_core.estimation.offline`; this module only
presents them. ``estimate.png``: the x-y path, the six states over time, and the x, y and yaw
error against the dataset's reference over time with the estimator's ±2σ band.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.gridspec import GridSpec
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from crs_core.analysis.figures import (
    ERROR_COMPONENTS,
    STATUS_COLOURS,
    draw_error_panel,
    error_legend_handles,
    label_band_panel,
    shade_status_strip,
)
from crs_core.analysis.metrics import band_statistics, pose_error_bands
from crs_core.dataset import Dataset
from crs_core.estimation.base import sensor_group
from crs_core.estimation.offline import (
    OfflineEstimates,
    dataset_stream,
    reference_label,
    reference_states_at,
)
from crs_core.track import Track, load_demo_track

#: Label and unit of each state in the time plots.
STATE_AXES = (
    ("x", "m"),
    ("y", "m"),
    ("yaw", "rad"),
    ("v_x", "m/s"),
    ("v_y", "m/s"),
    ("ω", "rad/s"),
)


def format_summary(
    name: str, diagnostics: dict[str, Any], comparison: dict[str, Any] | None, duration_s: float
) -> str:
    """A few lines for the terminal: samples, status, rejections, RMSE against the reference."""
    d = diagnostics
    start = "blind start" if d["start"] == "blind" else f"x0 = {d['start']}"
    rate = f" at {d['rate_hz']:g} Hz" if d["rate_hz"] else ""
    counts = d["status_counts"]
    fix = d["time_to_first_fix_s"]
    lines = [
        f"{name}: {d['estimator']}{rate} on {d['sensors']}, inputs {d['inputs']} "
        f"(ran {d['input_mode']}), {start}; {d['samples']} samples over {duration_s:.1f} s "
        f"({d['data']})",
        f"status: ok {counts['ok']}, degraded {counts['degraded']}, lost {counts['lost']}; first "
        + (f"fix after {fix:.3f} s" if fix is not None else "fix: never")
        + f"; re-initialisations {d['reinitializations']}, solver fallbacks {d['fallbacks']}, "
        f"late {d['late']}",
        "processed: " + _counts(d["processed"]),
        "rejected:  " + _counts(d["rejected"]) + "   ignored: " + _counts(d["ignored"]),
    ]
    if d["groups_without_data"]:
        lines.append(f"note: no data for sensor group(s) {', '.join(d['groups_without_data'])}")
    if comparison is None:
        lines.append("reference: none (the dataset has no x.npy)")
    elif comparison["rmse"] is None:
        lines.append(f"reference: {comparison['reference']}; no estimate that is not lost")
    else:
        lines.append(
            f"RMSE vs {comparison['reference']}, {comparison['samples']} samples not lost: "
            + _rmse(comparison["rmse"])
        )
        if comparison["rmse_settled"] is not None:
            lines.append(
                f"  from {comparison['settling_s']:g} s after the first fix on: "
                + _rmse(comparison["rmse_settled"])
            )
    wall = d["wall_time_s"]
    lines.append(
        f"wall time {wall:.2f} s ({duration_s / wall:.0f}x real time); per sample median "
        f"{d['time_per_sample_ms']['median']:.2f} ms, max {d['time_per_sample_ms']['max']:.1f} ms"
    )
    return "\n".join(lines)


def _counts(counter: dict[str, int]) -> str:
    return ", ".join(f"{k} {v}" for k, v in counter.items()) or "none"


def _rmse(rmse: dict[str, float]) -> str:
    return (
        f"position {rmse['position'] * 1e3:.1f} mm (x {rmse['x'] * 1e3:.1f}, y "
        f"{rmse['y'] * 1e3:.1f}), yaw {rmse['yaw'] * 1e3:.1f} mrad, vx {rmse['vx'] * 1e3:.0f} "
        f"mm/s, vy {rmse['vy'] * 1e3:.0f} mm/s, ω {rmse['omega'] * 1e3:.0f} mrad/s"
    )


def error_bands(result: OfflineEstimates, dataset: Dataset) -> dict[str, Any] | None:
    """Error of ``x, y, yaw`` against the dataset's reference and the estimator's σ over time.

    Returns None without a reference (no ``x.npy``), else ``errors`` and ``sigmas`` (N, 3) in
    mm, mm, mrad (the yaw error wrapped; NaN where the estimate is lost or the reference is
    missing) and ``stats``: per component the
    :func:`~crs_core.analysis.metrics.band_statistics` (RMSE and the fraction inside ±2σ) over
    the samples that are not lost.
    """
    reference = reference_states_at(dataset, result.t)
    if reference is None:
        return None
    factors = np.array([factor for _, _, factor in ERROR_COMPONENTS])
    found = (result.status != "lost") & np.isfinite(reference[:, 0])
    errors, sigmas = pose_error_bands(
        result.x[:3].T, result.covariance_diag[:3].T, reference, found
    )
    errors, sigmas = errors * factors, sigmas * factors
    stats = {
        name: band_statistics(errors[:, k], sigmas[:, k])
        for k, (name, _, _) in enumerate(ERROR_COMPONENTS)
    }
    return {"errors": errors, "sigmas": sigmas, "stats": stats}


def write_figure(result: OfflineEstimates, dataset: Dataset, path: Path, title: str) -> Path:
    """``estimate.png``: the x-y path (with DEMO_TRACK and the reference), the six states, and
    the x, y, yaw error against the reference with the estimator's ±2σ band over time."""
    fig = Figure(figsize=(22, 9.5))
    grid = GridSpec(
        1, 3, figure=fig, width_ratios=(1.0, 1.15, 1.15), wspace=0.2, left=0.04, right=0.985
    )
    grid.update(top=0.9, bottom=0.07)
    _plot_path(fig.add_subplot(grid[0, 0]), result, dataset)
    states = grid[0, 1].subgridspec(6, 1, hspace=0.15)
    axes = [fig.add_subplot(states[0])]
    axes += [fig.add_subplot(states[i], sharex=axes[0]) for i in range(1, 6)]
    _plot_states(axes, result, dataset)
    errors = grid[0, 2].subgridspec(3, 1, hspace=0.3)
    error_axes = [fig.add_subplot(errors[i], sharex=axes[0]) for i in range(3)]
    _plot_errors(error_axes, result, dataset)
    fig.suptitle(title)
    fig.savefig(path, dpi=100)
    return path


def _plot_errors(axes, result: OfflineEstimates, dataset: Dataset) -> None:
    """x, y and yaw error against the reference (if any) inside the ±2σ band, over time."""
    t = result.t - result.t[0]
    bands = error_bands(result, dataset)
    factors = np.array([factor for _, _, factor in ERROR_COMPONENTS])
    sigmas = np.sqrt(np.clip(result.covariance_diag[:3].T, 0.0, None)) * factors
    sigmas[result.status == "lost"] = np.nan
    for k, (ax, (name, unit, _)) in enumerate(zip(axes, ERROR_COMPONENTS, strict=True)):
        sigma = sigmas[:, k]
        error = np.full(t.shape, np.nan) if bands is None else bands["errors"][:, k]
        off_scale = draw_error_panel(ax, t, error, sigma, result.status, unit)
        if bands is None:
            ax.set_ylabel(f"{name} ±2σ [{unit}]")
            ax.set_title(f"no reference: band only   {off_scale}", loc="left", fontsize=8)
        else:
            label_band_panel(ax, name, unit, [("", bands["stats"][name])], off_scale)
        if k < 2:
            ax.tick_params(labelbottom=False)
    handles = error_legend_handles(None if bands is None else _reference(dataset))
    axes[0].legend(
        handles=handles, loc="lower left", bbox_to_anchor=(0.0, 1.12), fontsize=8, ncol=2
    )
    start = f" (t₀ = {result.t[0]:.3f} s)" if abs(result.t[0]) > 1e-9 else ""
    axes[-1].set_xlabel(f"t − t₀ [s]{start}")


def _plot_path(ax, result: OfflineEstimates, dataset: Dataset) -> None:
    found = result.status != "lost"
    track = _track_near(result.x[:2, found])
    if track is not None:
        for edge, label in zip(track.borders(), ("DEMO_TRACK borders", None), strict=True):
            ax.plot(edge[:, 0], edge[:, 1], color="0.75", lw=1, label=label)
    if dataset.x is not None:
        ax.plot(dataset.x[:, 0], dataset.x[:, 1], color="0.45", lw=1.2, label=_reference(dataset))
    x, y = (np.where(found, v, np.nan) for v in result.x[:2])
    ax.plot(x, y, color="tab:blue", lw=0.9, label="estimate (not lost)")
    degraded = result.status == "degraded"
    if degraded.any():
        ax.plot(*result.x[:2, degraded], ".", color="tab:orange", ms=2.5, label="degraded")
    if found.any():
        first = np.flatnonzero(found)[0]
        ax.plot(*result.x[:2, first], "g^", ms=8, label="first fix")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m] (world)")
    ax.set_ylabel("y [m] (world)")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=8)


def _plot_states(axes, result: OfflineEstimates, dataset: Dataset) -> None:
    t = result.t - result.t[0]
    found = result.status != "lost"
    estimate = result.x.copy()
    states = reference_states_at(dataset, result.t)
    reference = None if states is None else states[:, :6].T.copy()
    if found.any():  # yaw unwrapped for reading, the reference moved by whole turns to match
        estimate[2, found] = np.unwrap(estimate[2, found])
        if reference is not None:
            reference[2] = np.unwrap(reference[2])
            first = np.flatnonzero(found)[0]
            turns = np.round((estimate[2, first] - reference[2, first]) / (2 * np.pi))
            reference[2] += 2 * np.pi * turns
    for i, (ax, (name, unit)) in enumerate(zip(axes, STATE_AXES, strict=True)):
        if reference is not None:
            ax.plot(t, reference[i], color="0.45", lw=1.0)
        ax.plot(t, np.where(found, estimate[i], np.nan), color="tab:blue", lw=0.8)
        shade_status_strip(ax, t, result.status, height=1.0, alpha=0.25)
        ax.set_ylabel(f"{name} [{unit}]")
        ax.grid(alpha=0.3)
        if i < 5:
            ax.tick_params(labelbottom=False)
    handles = [Line2D([], [], color="tab:blue", lw=0.8, label="estimate")]
    if reference is not None:
        handles.append(Line2D([], [], color="0.45", lw=1.0, label=_reference(dataset)))
    handles += [Patch(color=c, alpha=0.25, label=s) for s, c in STATUS_COLOURS.items()]
    axes[0].legend(
        handles=handles, loc="lower right", bbox_to_anchor=(1.0, 1.0), fontsize=8, ncol=4
    )
    start = f" (t₀ = {result.t[0]:.3f} s)" if abs(result.t[0]) > 1e-9 else ""
    axes[-1].set_xlabel(f"t − t₀ [s]{start}")


def _reference(dataset: Dataset) -> str:
    """The reference in words. A recording's ``x.npy`` is the car's own on-line estimate:
    Lighthouse-based when the recording has Lighthouse data and no motion capture (as the
    Chronos recordings in ``shared/data/chronos_real``)."""
    label = reference_label(dataset)
    if label == "simulation truth" or dataset.meta.get("reference"):
        return label  # as the simulator or a bag's conversion named it
    measurements, _, _ = dataset_stream(dataset)
    groups = {sensor_group(m.sensor) for m in measurements}
    if "lh" in groups and "pose" not in groups:
        return "recorded on-line estimate (Lighthouse-based, not ground truth)"
    return "recorded on-line estimate (not ground truth)"


def _track_near(points: np.ndarray) -> Track | None:
    """DEMO_TRACK, if most of the estimated path lies within half a metre of its extent."""
    if points.shape[1] == 0:
        return None
    track = load_demo_track()
    margin = 0.5
    inside = (
        (points[0] > track.x.min() - margin)
        & (points[0] < track.x.max() + margin)
        & (points[1] > track.y.min() - margin)
        & (points[1] < track.y.max() + margin)
    )
    return track if inside.mean() > 0.8 else None


def write_online_figure(result: OfflineEstimates, path: Path, title: str) -> Path:
    """One panel per online parameter: its estimate with the ±2σ band over the run, the prior
    dashed; the stretches where the data informed it drawn solid, the others faint."""
    online = result.online
    t = result.t - result.t[0]
    figure = Figure(figsize=(9.0, 2.2 * len(online.names) + 0.6), layout="constrained")
    axes = figure.subplots(len(online.names), 1, sharex=True, squeeze=False)[:, 0]
    priors = result.estimator.model.online.priors
    for ax, name, value, std, informed in zip(
        axes, online.names, online.value, online.std, online.informed, strict=True
    ):
        ax.fill_between(t, value - 2 * std, value + 2 * std, color="C0", alpha=0.2, lw=0)
        ax.plot(t, np.where(informed, value, np.nan), color="C0", lw=1.2, label="informed")
        ax.plot(
            t,
            np.where(informed, np.nan, value),
            color="C0",
            lw=1.0,
            alpha=0.4,
            label="not informed",
        )
        ax.axhline(priors[name][0], color="0.4", ls="--", lw=0.8, label="prior")
        ax.set_ylabel(name)
    axes[0].legend(loc="upper right", fontsize="small", ncol=3)
    axes[-1].set_xlabel("time since the first stamp [s]")
    figure.suptitle(f"{title}: online parameters (±2σ)", fontsize="medium")
    figure.savefig(path, dpi=110)
    return path
