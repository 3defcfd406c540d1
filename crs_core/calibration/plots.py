"""Figures of a calibration (matplotlib, object-oriented API; imported only when drawing).

Static: ``angle_residuals.png`` (per point, station, plane and photodiode),
``position_residuals.png`` (floor map with the reprojection errors drawn 30x enlarged, and
the error per point) and
``residual_vs_n.png`` (mean/max position error vs number of points). Moving:
``moving_residuals.png`` (angle residuals and pose-fix errors over time) and
``offset_scan.png`` (cost vs clock offset).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

#: Arrows in the floor map are the position errors times this factor (as in the paper).
ARROW_SCALE = 30.0
_PLANE_MARKERS = {1: "o", 2: "s"}
_DIODE_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red")


def static_figures(out: Path, summary: dict[str, Any], fixes: list | None = None) -> list[Path]:
    """Draw the three static figures into ``out``; ``fixes``: per point the all-station fix
    ``(x, y, yaw)`` or None (the arrows). Returns the paths."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator

    points = summary["per_point"]
    paths = []
    # --- angle residuals per point ---------------------------------------------------------
    keys = sorted({k for p in points for k in p["angle_residuals_rad"]})
    fig = Figure(figsize=(10, 2.2 + 1.6 * len(keys)))
    axes = fig.subplots(len(keys), 1, sharex=True, squeeze=False)
    for ax, key in zip(axes[:, 0], keys, strict=True):
        for k in range(4):
            xs = [p["index"] + (k - 1.5) * 0.12 for p in points if key in p["angle_residuals_rad"]]
            ys = [
                1e3 * p["angle_residuals_rad"][key][k]
                for p in points
                if key in p["angle_residuals_rad"]
            ]
            ax.plot(
                xs,
                ys,
                _PLANE_MARKERS[int(key[-1])],
                ms=4,
                color=_DIODE_COLOURS[k],
                label=f"photodiode {k}",
            )
        ax.axhline(0.0, color="0.5", lw=0.6)
        ax.set_ylabel(f"{key}\nresidual (mrad)")
        ax.grid(alpha=0.3)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, ncol=4, fontsize=8, loc="lower center")
    fig.suptitle("Sweep-angle residuals per point (measured mean − model; ○ plane 1, □ plane 2)")
    axes[-1, 0].set_xlabel("point index")
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    paths.append(_save(fig, out / "angle_residuals.png"))
    # --- floor map and error per point ------------------------------------------------------
    fig = Figure(figsize=(13, 5.2))
    ax_map, ax_bar = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.35, 1]})
    xy = np.array([p["position_m"] for p in points])
    errors = np.array(
        [np.nan if p["position_error_m"] is None else p["position_error_m"] for p in points],
        dtype=float,
    )
    ax_map.plot(xy[:, 0], xy[:, 1], "k.", ms=6, label="known point")
    if fixes is not None:
        for (x, y), fix in zip(xy, fixes, strict=True):
            if fix is not None:
                ax_map.annotate(
                    "",
                    xy=(x + ARROW_SCALE * (fix[0] - x), y + ARROW_SCALE * (fix[1] - y)),
                    xytext=(x, y),
                    arrowprops={"arrowstyle": "->", "color": "tab:red"},
                )
    for i, (x, y) in enumerate(xy):
        ax_map.text(x, y, f" {i}", fontsize=7, color="0.3", va="bottom")
    for i, station in enumerate(summary["stations"]):
        sx, sy, sz = station["position_m"]
        ax_map.plot(
            sx,
            sy,
            "^",
            ms=10,
            color="tab:purple",
            label="station (floor projection)" if i == 0 else None,
        )
        ax_map.text(sx, sy, f"  bs{i} (z {sz:.2f} m)", fontsize=8, color="tab:purple")
    ax_map.set_aspect("equal")
    ax_map.set_xlabel("x (m)")
    ax_map.set_ylabel("y (m)")
    ax_map.set_title(f"Reprojection error, arrows ×{ARROW_SCALE:g}")
    ax_map.grid(alpha=0.3)
    ax_map.legend(fontsize=8, loc="best")
    ax_bar.bar(np.arange(len(points)), 1e3 * errors, color="tab:red")
    mean = np.nanmean(errors) if np.isfinite(errors).any() else np.nan
    ax_bar.axhline(1e3 * mean, color="k", ls="--", lw=1, label=f"mean {1e3 * mean:.2f} mm")
    ax_bar.set_xlabel("point index")
    ax_bar.set_ylabel("position error (mm)")
    ax_bar.set_title("Reprojected position error per point")
    ax_bar.grid(alpha=0.3, axis="y")
    ax_bar.legend(fontsize=8)
    fig.tight_layout()
    paths.append(_save(fig, out / "position_residuals.png"))
    # --- mean/max vs n ----------------------------------------------------------------------
    rows = summary["versus_n"]["rows"]
    if rows:
        fig = Figure(figsize=(7.5, 4.5))
        ax = fig.subplots()
        n = [r["n"] for r in rows]

        def series(key):
            return [np.nan if r[key] is None else 1e3 * r[key] for r in rows]

        ax.plot(n, series("all_mean"), "o-", color="tab:blue", label="mean, all points")
        ax.plot(n, series("all_max"), "s-", color="tab:red", label="max, all points")
        ax.plot(
            n,
            series("fitted_mean"),
            "o--",
            color="tab:blue",
            alpha=0.55,
            label="mean, fitted points",
        )
        ax.plot(
            n, series("fitted_max"), "s--", color="tab:red", alpha=0.55, label="max, fitted points"
        )
        ax.set_xlabel("number of calibration points n")
        ax.set_ylabel("reprojected position error (mm)")
        ax.set_title("Calibration residual vs number of points")
        ax.set_ylim(bottom=0)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        paths.append(_save(fig, out / "residual_vs_n.png"))
    return paths


def moving_figures(out: Path, calibration, fixes) -> list[Path]:
    """Draw the moving figures into ``out``; returns their paths."""
    from matplotlib.figure import Figure

    recording = calibration.recording
    obs, residuals = recording.observations, calibration.fit.residuals
    t0 = float(recording.stamps[0])
    keys = sorted({(int(s), int(p)) for s, p in zip(obs.station, obs.plane, strict=True)})
    fig = Figure(figsize=(11, 2.2 + 1.8 * (len(keys) + 1)))
    axes = fig.subplots(len(keys) + 1, 1, sharex=True, squeeze=False)
    for ax, (s, plane) in zip(axes[:-1, 0], keys, strict=True):
        rows = (obs.station == s) & (obs.plane == plane)
        for k in range(4):
            ax.plot(
                recording.stamps[rows] - t0,
                1e3 * residuals[rows, k],
                ".",
                ms=2,
                color=_DIODE_COLOURS[k],
                label=f"photodiode {k}",
            )
        limit = 1e3 * max(np.percentile(np.abs(residuals[rows]), 99.5), 1e-4) * 1.3
        ax.set_ylim(-limit, limit)
        ax.set_ylabel(f"lighthouse/{s}/{plane}\nresidual (mrad)")
        ax.grid(alpha=0.3)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, ncol=4, fontsize=8, markerscale=4, loc="lower center")
    fig.suptitle(f"Sweep-angle residuals (clock offset {1e3 * calibration.offset:.2f} ms)")
    ax = axes[-1, 0]
    if fixes.stamps.size:
        ax.plot(fixes.stamps - t0, 1e3 * fixes.errors, ".", ms=2, color="tab:red")
        ax.set_ylim(0, 1e3 * np.percentile(fixes.errors, 99.5) * 1.3 + 1e-3)
    ax.set_ylabel("pose-fix error (mm)\nincl. motion\nbetween planes")
    ax.set_xlabel("time since first sweep (s)")
    ax.grid(alpha=0.3)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    paths = [_save(fig, out / "moving_residuals.png")]
    offsets, costs = calibration.scan
    if offsets.size:
        fig = Figure(figsize=(7.5, 4.2))
        ax = fig.subplots()
        ax.plot(1e3 * offsets, costs, "-", color="tab:blue", label="cost, start stations")
        ax.axvline(
            1e3 * calibration.offset,
            color="tab:red",
            ls="--",
            label=f"fitted offset {1e3 * calibration.offset:.2f} ms",
        )
        ax.set_xlabel("clock offset τ = motion capture − car (ms)")
        ax.set_ylabel("robust cost (soft L1)")
        ax.set_yscale("log")
        ax.set_title("Clock-offset scan (before the joint fit)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        paths.append(_save(fig, out / "offset_scan.png"))
    return paths


def _save(fig, path: Path) -> Path:
    fig.savefig(path, dpi=110)
    return path
