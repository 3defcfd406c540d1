"""The figure of a ``crs launch sim`` run: paths on the track and estimation errors over time."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from crs_core.track import load_demo_track


def plot(bag: Path, cars: int, out: Path, estimator: str = "") -> None:
    """``path.png``: every car's truth and estimate on the track (with a zoomed inset), and the
    estimation error over time (position in mm, yaw in mrad; against the simulator's truth)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ros4crs.bag_replay import read_car

    track = load_demo_track()
    fig = plt.figure(figsize=(12, 6.5))
    grid = fig.add_gridspec(2, 2, width_ratios=(1.25, 1))
    ax = fig.add_subplot(grid[:, 0])
    ax_pos, ax_yaw = fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, 1])
    for edge, label in zip(track.borders(), ("track borders", None), strict=True):
        ax.plot(edge[:, 0], edge[:, 1], color="0.7", lw=1, label=label)
    # inside the loop of the DEMO_TRACK (data coordinates), clear of the track
    inset = ax.inset_axes((-1.0, -0.65, 0.85, 0.85), transform=ax.transData)
    zoom = None
    for i in range(1, cars + 1):
        contents = read_car(bag, f"/car{i}")
        if not (contents.truth and contents.estimates):
            continue
        truth_t = np.array([t for t, _ in contents.truth])
        truth = np.array([x for _, x in contents.truth])
        est_t = np.array([t for t, _ in contents.estimates])
        est = np.array([x for _, x in contents.estimates])
        for axis in (ax, inset):
            axis.plot(
                truth[:, 0],
                truth[:, 1],
                "-",
                color=f"C{2 * i - 2}",
                lw=2.2,
                alpha=0.45,
                label=f"car{i} truth" if axis is ax else None,
            )
            axis.plot(
                est[:, 0],
                est[:, 1],
                "-",
                color=f"C{2 * i - 1}",
                lw=0.8,
                label=f"car{i} estimate" if axis is ax else None,
            )
        zoom = zoom or (est[len(est) // 2, 0], est[len(est) // 2, 1])
        seconds = est_t - est_t[0]
        truth_at = np.stack([np.interp(est_t, truth_t, truth[:, k]) for k in range(3)], axis=1)
        error_mm = 1e3 * np.hypot(*(est[:, :2] - truth_at[:, :2]).T)
        yaw = est[:, 2] - truth_at[:, 2]
        yaw_mrad = 1e3 * np.arctan2(np.sin(yaw), np.cos(yaw))
        ax_pos.plot(seconds, error_mm, lw=0.8, color=f"C{2 * i - 1}", label=f"car{i}")
        ax_yaw.plot(seconds, yaw_mrad, lw=0.8, color=f"C{2 * i - 1}", label=f"car{i}")
    if zoom is not None:
        inset.set_xlim(zoom[0] - 0.05, zoom[0] + 0.05)
        inset.set_ylim(zoom[1] - 0.05, zoom[1] + 0.05)
        inset.set_aspect("equal")
        inset.set_title("10 cm around car 1 mid-run", fontsize=7)
        inset.tick_params(labelsize=6)
        ax.indicate_inset_zoom(inset, edgecolor="0.3")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m] (world)")
    ax.set_ylabel("y [m] (world)")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)
    ax_pos.set_ylabel("position error [mm]")
    ax_yaw.set_ylabel("yaw error [mrad]")
    ax_yaw.set_xlabel("time since the first estimate [s]")
    for axis in (ax_pos, ax_yaw):
        axis.grid(alpha=0.3)
        axis.legend(fontsize=8, loc="upper right")
    name = estimator.upper() or "estimator"
    fig.suptitle(f"ROS 2 stack in simulation: {cars} car(s), {name} vs the simulator's truth")
    fig.tight_layout()
    fig.savefig(out / "path.png", dpi=110)
    plt.close(fig)
