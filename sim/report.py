"""Short human-readable report of a simulation run: numbers (text + JSON) and PNG plots."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from crs_core.measurements import lighthouse_sensor
from crs_core.track import LapCounter, Track
from sim.simulator import SimulationResult


def lap_statistics(result: SimulationResult, track: Track) -> dict[str, Any]:
    """Laps completed, lap times and path-following errors of the true trajectory."""
    counter = LapCounter(track.length)
    lateral = []
    s_hint = None
    s_start = None
    for t, state in zip(result.truth_t, result.truth_x, strict=True):
        projection = track.project(state[0], state[1], s_hint)
        s_hint = projection.s
        s_start = projection.s if s_start is None else s_start
        lateral.append(projection.lateral_error)
        counter.update(t, projection.s)
    lateral_arr = np.abs(np.array(lateral))
    return {
        "laps_completed": counter.laps_completed,
        "lap_times_s": [round(v, 3) for v in counter.lap_times],
        "distance_m": round(counter.progress - (s_start or 0.0), 3),
        "max_lateral_error_m": round(float(lateral_arr.max()), 4),
        "rms_lateral_error_m": round(float(np.sqrt(np.mean(lateral_arr**2))), 4),
    }


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


def write_report(
    result: SimulationResult, track: Track, folder: str | Path, extra: dict[str, Any] | None = None
) -> Path:
    """Write ``summary.txt``, ``summary.json``, ``path.png`` and ``sensors.png`` into ``folder``."""
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
        **lap_statistics(result, track),
        "sensors": sensor_statistics(result),
        **(extra or {}),
    }
    (folder / "summary.json").write_text(json.dumps(summary, indent=2))
    lines = [f"Chronos simulation: {result.duration:.1f} s, seed {result.seed}"]
    for key, value in summary.items():
        if key == "sensors":
            lines.append("sensors:")
            lines += [f"  {n}: {v['samples']} samples, {v['rate_hz']} Hz" for n, v in value.items()]
        else:
            lines.append(f"{key}: {value}")
    (folder / "summary.txt").write_text("\n".join(lines) + "\n")
    _plot_path(result, track, folder / "path.png")
    _plot_sensors(result, folder / "sensors.png")
    return folder


def _plot_path(result: SimulationResult, track: Track, path: Path) -> None:
    fig, ax = plt.subplots(figsize=(8, 6))
    normal = np.stack([-np.sin(track.heading), np.cos(track.heading)], axis=1)
    centre = np.stack([track.x, track.y], axis=1)
    for side in (-1, 1):
        edge = centre + side * track.width / 2 * normal
        ax.plot(edge[:, 0], edge[:, 1], color="0.3", lw=1)
    ax.plot(track.x, track.y, "--", color="0.6", lw=0.8, label="centerline")
    points = ax.scatter(
        result.truth_x[::5, 0],
        result.truth_x[::5, 1],
        c=result.truth_x[::5, 3],
        s=2,
        cmap="viridis",
        label="driven path (true)",
    )
    ax.plot(*result.truth_x[0, :2], "r^", label="start")
    fig.colorbar(points, ax=ax, label="v_x [m/s]")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("Chronos on DEMO_TRACK (simulated)")
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _plot_sensors(result: SimulationResult, path: Path) -> None:
    fig, axes = plt.subplots(5, 1, figsize=(10, 11), sharex=True)
    for plane, style in ((1, "."), (2, "x")):
        t, v = result.measurements_of(lighthouse_sensor(0, plane))
        if t.size:
            axes[0].plot(t, v[:, 0], style, ms=2, label=f"plane {plane}, diode 0")
    axes[0].set_ylabel("Lighthouse [rad]")
    t, v = result.measurements_of("wheel_encoders")
    for i, name in enumerate(("fl", "fr", "rl", "rr")):
        axes[1].plot(t, v[:, i], lw=0.5, label=name)
    axes[1].set_ylabel("wheel speed [rad/s]")
    t, v = result.measurements_of("imu")
    axes[2].plot(t, v[:, 0], lw=0.5, label="a_x")
    axes[2].plot(t, v[:, 1], lw=0.5, label="a_y")
    axes[2].set_ylabel("accel [m/s²]")
    axes[3].plot(t, v[:, 2], lw=0.5, label="gyro")
    axes[3].plot(result.truth_t, result.truth_x[:, 5], "k", lw=0.8, label="true ω")
    axes[3].set_ylabel("yaw rate [rad/s]")
    stamps = np.array([s.stamp for s in result.inputs])
    inputs = np.stack([s.u for s in result.inputs])
    axes[4].step(stamps, inputs[:, 0], where="post", label="steer [rad]")
    axes[4].step(stamps, inputs[:, 1], where="post", label="torque [-]")
    axes[4].set_ylabel("input")
    axes[4].set_xlabel("t [s]")
    for ax in axes:
        ax.legend(loc="upper right", fontsize=7, ncol=4)
        ax.grid(alpha=0.3)
    fig.suptitle("Simulated sensor signals (with noise)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
