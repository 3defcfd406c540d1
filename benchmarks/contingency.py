"""``crs bench contingency``: the MPCC through link outages, its commands hold-safe or not.

Each seed draws outage windows (``--outage`` s long, 3.5-6.5 s apart, so they fall all along
the lap) and races ``--duration`` s through them twice with :func:`sim.outage_loop.run_outage_loop`:
once with the MPCC's racing commands, once hold-safe
(:class:`~crs_core.control.contingency.HoldSafetyFilter`). Per run: time off the track, spells
off it, the flying laps (the lap from rest left out), commands the filter replaced. The
summary compares the two over all seeds: the same outages, the same car, only the commands
held through them differ.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from crs_core.analysis.statistics import summary
from crs_core.control.mpcc import Mpcc
from crs_core.track import load_demo_track
from sim.outage_loop import random_outages, run_outage_loop

__all__ = ["contingency_benchmark", "format_table"]

#: The two ways of racing compared: name, hold-safe.
MODES = (("racing", False), ("hold-safe", True))


def contingency_benchmark(
    seeds: int,
    duration: float,
    outage: float,
    first_seed: int = 100,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """Race ``seeds`` outage draws (seeds ``first_seed`` on) of ``duration`` s each with
    ``outage``-second outages, racing and hold-safe; the rows and a summary per mode."""
    mpcc = Mpcc(load_demo_track())
    rows = []
    started = time.perf_counter()
    for seed in range(first_seed, first_seed + seeds):
        windows = random_outages(duration, outage, np.random.default_rng(seed))
        for mode, hold_safe in MODES:
            run = run_outage_loop(mpcc, duration, windows, hold_safe)
            flying = run.lap_times[1:]
            rows.append(
                {
                    "seed": seed,
                    "mode": mode,
                    "outages": len(windows),
                    "off_track_s": run.off_track_s,
                    "episodes": run.episodes,
                    "flying_laps": len(flying),
                    "mean_flying_lap_s": round(float(np.mean(flying)), 3) if flying else None,
                    "replaced": run.replaced,
                }
            )
            if progress is not None:
                progress(_row_line(rows[-1]))
    result = {
        "settings": {
            "seeds": seeds,
            "first_seed": first_seed,
            "duration_s": duration,
            "outage_s": outage,
        },
        "rows": rows,
        "summary": {mode: _summary([r for r in rows if r["mode"] == mode]) for mode, _ in MODES},
        "wall_time_s": round(time.perf_counter() - started, 1),
    }
    racing, safe = (result["summary"][mode]["mean_flying_lap_s"] for mode, _ in MODES)
    result["summary"]["lap_ratio"] = round(safe / racing, 4) if racing and safe else None
    return result


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    laps = [r["mean_flying_lap_s"] for r in rows if r["mean_flying_lap_s"] is not None]
    return {
        "outages": sum(r["outages"] for r in rows),
        "off_track_s": round(sum(r["off_track_s"] for r in rows), 2),
        "episodes": sum(r["episodes"] for r in rows),
        "runs_off_track": sum(r["off_track_s"] > 0 for r in rows),
        "runs": len(rows),
        "mean_flying_lap_s": summary(laps, ("mean",), 3)["mean"] if laps else None,
        "replaced": sum(r["replaced"] for r in rows),
    }


def _row_line(row: dict[str, Any]) -> str:
    return (
        f"seed {row['seed']} {row['mode']}: {row['outages']} outages, off track "
        f"{row['off_track_s']:.2f} s in {row['episodes']} spell(s), {row['flying_laps']} flying "
        f"laps of {row['mean_flying_lap_s']} s, {row['replaced']} commands replaced"
    )


def format_table(result: dict[str, Any]) -> str:
    """The summary as a Markdown table."""
    settings = result["settings"]
    lines = [
        f"{settings['seeds']} seeds x {settings['duration_s']:g} s, "
        f"{settings['outage_s']:g} s outages every 3.5-6.5 s",
        "",
        "| commands | outages | off track [s] | spells off | runs off / runs | "
        "mean flying lap [s] | commands replaced |",
        "|---|---|---|---|---|---|---|",
    ]
    for mode, _ in MODES:
        s = result["summary"][mode]
        lines.append(
            f"| {mode} | {s['outages']} | {s['off_track_s']:.2f} | {s['episodes']} | "
            f"{s['runs_off_track']} / {s['runs']} | {s['mean_flying_lap_s']} | {s['replaced']} |"
        )
    lines.append(f"\nhold-safe lap / racing lap: {result['summary']['lap_ratio']}")
    return "\n".join(lines)
