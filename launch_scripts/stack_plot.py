"""The figure of a ``crs launch sim`` run: paths on the track and estimation errors over time."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from crs_core.analysis.figures import (
    BAND_ALPHA,
    BAND_LABEL,
    ERROR_COMPONENTS,
    clip_to_band,
    draw_error_band,
    label_band_panel,
)
from crs_core.analysis.metrics import band_statistics, interpolate_pose, pose_errors
from crs_core.track import Track, load_demo_track

if TYPE_CHECKING:
    from ros4crs.bag_replay import BagContents


@dataclass
class StateTrack:
    """``chronos_msgs/CarState`` messages of one topic, in stamp order.

    ``t`` (n,) header stamps, s; ``x`` (n, 6) states; ``sigma`` (n, 6) standard deviations
    from the diagonal of the message's covariance (NaN where the covariance is all zeros, i.e.
    unknown, or not finite).
    """

    t: np.ndarray
    x: np.ndarray
    sigma: np.ndarray


def state_track(
    states: Sequence[tuple[float, np.ndarray]], sigmas: Sequence[np.ndarray] | None = None
) -> StateTrack:
    """A :class:`StateTrack` of ``(stamp, state)`` pairs in any order and their standard
    deviations (None: unknown, NaN)."""
    stamps = np.asarray([t for t, _ in states], dtype=float)
    x = np.asarray([state for _, state in states], dtype=float).reshape(-1, 6)
    sigma = np.full_like(x, np.nan) if sigmas is None else np.asarray(sigmas, dtype=float)
    order = np.argsort(stamps, kind="stable")
    return StateTrack(stamps[order], x[order], sigma.reshape(-1, 6)[order])


def estimate_errors(estimates: StateTrack, truth: StateTrack) -> tuple[np.ndarray, np.ndarray]:
    """Errors ``x, y, yaw`` (n, 3) of the estimates against the truth interpolated to their
    stamps (yaw unwrapped before interpolating, the error wrapped), in mm, mm, mrad, NaN
    outside the span of the truth; and the estimates' σ (n, 3) in the same units."""
    factors = np.array([factor for _, _, factor in ERROR_COMPONENTS])
    errors = np.full((estimates.t.size, 3), np.nan)
    if truth.t.size >= 2:
        truth_at = interpolate_pose(estimates.t, truth.t, truth.x)
        errors = pose_errors(estimates.x, truth_at) * factors
        errors[(estimates.t < truth.t[0]) | (estimates.t > truth.t[-1])] = np.nan
    return errors, estimates.sigma[:, :3] * factors


def plot(
    contents_of: dict[str, BagContents],
    cars: int,
    out: Path,
    estimator: str = "",
    track: Track | None = None,
    truths: dict[int, StateTrack] | None = None,
    title: str | None = None,
) -> None:
    """``path.png``: every car's truth and estimate on the track (with a zoomed inset), and the
    x, y and yaw estimation error over time (mm, mrad; against the simulator's truth) inside the
    ±2σ band of the covariance the estimator published, from ``contents_of``, what the bag
    holds of each car (:func:`~launch_scripts.sim_stack.read_cars`). ``truths`` (per car
    number) replaces the bag's ``ground_truth`` (e.g. a car emulator's log); ``title`` the
    figure's title."""
    from matplotlib.figure import Figure
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    track = track or load_demo_track()
    runs = {}
    for i in range(1, cars + 1):
        contents = contents_of[f"car{i}"]
        estimates = state_track(contents.estimates, contents.estimate_sigmas)
        if truths is not None:
            truth = truths.get(i) or StateTrack(np.zeros(0), np.zeros((0, 6)), np.zeros((0, 6)))
        else:
            truth = state_track(contents.truth)
        if estimates.t.size and truth.t.size:
            runs[i] = (estimates, truth, *estimate_errors(estimates, truth))
    t0 = min((run[0].t[0] for run in runs.values()), default=0.0)

    fig = Figure(figsize=(13.5, 7.5), layout="constrained")
    grid = fig.add_gridspec(3, 2, width_ratios=(1.2, 1))
    ax = fig.add_subplot(grid[:, 0])
    error_axes = [fig.add_subplot(grid[0, 1])]
    error_axes += [fig.add_subplot(grid[k, 1], sharex=error_axes[0]) for k in (1, 2)]
    for edge, label in zip(track.borders(), ("track borders", None), strict=True):
        ax.plot(edge[:, 0], edge[:, 1], color="0.7", lw=1, label=label)
    # inside the left loop of the DEMO_TRACK (data coordinates), clear of the track
    inset = ax.inset_axes((-1.21, -0.45, 0.62, 0.62), transform=ax.transData)
    zoom = None
    for i, (estimates, truth, _, _) in runs.items():
        # the truth wide and pale under the estimate; labelled once, in the main axes
        lines = (
            (truth, "truth", 2 * i - 2, 2.2, 0.45),
            (estimates, "estimate", 2 * i - 1, 0.8, 1.0),
        )
        for axis in (ax, inset):
            for states, what, colour, width, alpha in lines:
                axis.plot(
                    states.x[:, 0],
                    states.x[:, 1],
                    "-",
                    color=f"C{colour}",
                    lw=width,
                    alpha=alpha,
                    label=f"car{i} {what}" if axis is ax else None,
                )
        middle = estimates.x[len(estimates.x) // 2]
        zoom = zoom or (middle[0], middle[1])
    if zoom is not None:
        inset.set_xlim(zoom[0] - 0.05, zoom[0] + 0.05)
        inset.set_ylim(zoom[1] - 0.05, zoom[1] + 0.05)
        inset.set_aspect("equal")
        inset.set_title("10 cm × 10 cm around\ncar 1 mid-run", fontsize=7)
        inset.tick_params(labelleft=False, labelbottom=False, length=0)
        ax.indicate_inset_zoom(inset, edgecolor="0.3")
    else:
        inset.set_visible(False)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m] (world)")
    ax.set_ylabel("y [m] (world)")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)

    for k, (axis, (name, unit, _)) in enumerate(zip(error_axes, ERROR_COMPONENTS, strict=True)):
        errors, sigmas, stats = [], [], []
        for i, (estimates, _, error, sigma) in runs.items():
            draw_error_band(axis, estimates.t - t0, error[:, k], sigma[:, k], f"C{2 * i - 1}", None)
            errors.append(error[:, k])
            sigmas.append(sigma[:, k])
            who = "" if len(runs) == 1 else f"car{i}"
            stats.append((who, band_statistics(error[:, k], sigma[:, k])))
        axis.axhline(0.0, color="0.3", lw=0.6)
        off_scale = clip_to_band(axis, errors, sigmas, unit) if runs else ""
        label_band_panel(axis, name, unit, stats or [("", band_statistics([], []))], off_scale)
        axis.grid(alpha=0.3)
        if k < 2:
            axis.tick_params(labelbottom=False)
    handles = [
        Line2D([], [], color=f"C{2 * i - 1}", lw=0.8, label=f"car{i} estimate − truth")
        for i in runs
    ]
    band_colour = f"C{2 * next(iter(runs)) - 1}" if len(runs) == 1 else "0.5"
    handles.append(
        Patch(color=band_colour, alpha=BAND_ALPHA, label=f"{BAND_LABEL}, published covariance")
    )
    fig.legend(handles=handles, loc="outside lower right", fontsize=8, ncol=min(len(handles), 5))
    error_axes[-1].set_xlabel("time since the first estimate [s]")
    name = estimator.upper() or "estimator"
    fig.suptitle(
        title or f"ROS 2 stack in simulation: {cars} car(s), {name} vs the simulator's truth"
    )
    fig.savefig(out / "path.png", dpi=110)
