"""Benchmarks of robust estimation (part of ``crs bench estimation``).

Three row kinds, all on the standard drive (:func:`~sim.scenarios.standard_drive`)
with its simulated truth:

``inputs_withheld``
    EKF and MHE without commanded inputs and without a start state (blind start from the
    Lighthouse), beside the same estimator with inputs and the usual wrong start state, and
    beside the old behaviour (commanded model, no commands delivered, so ``u = 0``).
``pose_solver``
    The single-shot Lighthouse pose solver on every sweep pair of the stream.
``timing_robustness``
    EKF and MHE under pathological query and delivery patterns.

Positions in m, angles in rad, times in s in the rows; :func:`format_table` prints mm, mrad, ms.
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Sequence

import numpy as np
from scipy.stats import chi2

from crs_core.analysis.angles import wrap_angle
from crs_core.analysis.metrics import STATE_NAMES
from crs_core.analysis.statistics import summary
from crs_core.estimation import LighthousePoseSolver, SweepPairer, make_estimator
from crs_core.estimation.base import Estimator
from crs_core.measurements import Measurement
from crs_core.model import CarModel
from sim.replay import (
    SETTLING_S,
    Run,
    errors,
    query_grid,
    replay,
    replay_schedule,
    rmse,
    start_state,
    stream_events,
    time_summary,
)
from sim.scenarios import standard_drive
from sim.simulator import LIGHTHOUSE_VIEW_LIMIT, SimulationResult

RATE_HZ = 60.0
#: "Converged": position error below this (m) ...
CONVERGED_POSITION_M = 0.01
#: ... and yaw error below this (rad), from then on to the end of the run.
CONVERGED_YAW_RAD = 0.1

# --- 1. inputs withheld, blind start ----------------------------------------------------------
#: Variants of :func:`inputs_withheld_rows`: (input mode, commands delivered, start).
INPUT_VARIANTS = {
    "estimated_blind": ("estimated", False, "blind"),
    "estimated_x0": ("estimated", False, "x0"),
    "commanded_no_inputs": ("commanded", False, "x0"),
    "inputs_given": ("auto", True, "x0"),
}


def run_metrics(run: Run, result: SimulationResult, estimator: Estimator) -> dict:
    """Start-up and supervision figures of one run.

    ``first_estimate_s``: stamp of the first estimate that is not ``lost``. "In bounds": the
    position error below :data:`CONVERGED_POSITION_M` and the yaw error below
    :data:`CONVERGED_YAW_RAD`. ``first_in_bounds_s``: the first query stamp in bounds;
    ``converged_s``: the first query stamp from which the estimate stays in bounds to the end
    of the run (``None``: never); ``out_of_bounds_after_2s``: the fraction of the queries
    stamped after :data:`SETTLING_S` that are not. ``max_position_error_after_1s_m`` includes
    ``lost`` estimates (they hold a guess). Status counts are of the queries stamped after
    :data:`SETTLING_S`.
    """
    error = errors(run, result)
    position = np.hypot(error[:, 0], error[:, 1])
    good = (position < CONVERGED_POSITION_M) & (np.abs(error[:, 2]) < CONVERGED_YAW_RAD)
    bad = np.nonzero(~good)[0]
    if not bad.size:
        converged = float(run.stamps[0])
    elif bad[-1] + 1 < len(good):
        converged = float(run.stamps[bad[-1] + 1])
    else:
        converged = None
    found = [t for t, s in zip(run.stamps, run.statuses, strict=True) if s != "lost"]
    late = [s for t, s in zip(run.stamps, run.statuses, strict=True) if t >= SETTLING_S]
    within = np.nonzero(good)[0]
    d = estimator.diagnostics
    return {
        "first_estimate_s": round(float(found[0]), 4) if found else None,
        "first_in_bounds_s": round(float(run.stamps[within[0]]), 4) if within.size else None,
        "converged_s": None if converged is None else round(converged, 4),
        "out_of_bounds_after_2s": round(float(np.mean(~good[run.stamps >= SETTLING_S])), 4),
        "max_position_error_after_1s_m": round(float(position[run.stamps >= 1.0].max()), 6),
        "lost_after_2s": late.count("lost"),
        "degraded_after_2s": late.count("degraded"),
        "reinitializations": int(d.reinitializations),
        "fallbacks": int(d.fallbacks),
    }


def inputs_withheld_rows(
    seeds: Sequence[int],
    duration: float = 20.0,
    kinds: Sequence[str] = ("ekf", "mhe"),
    sensor_sets: Sequence[str] = ("lh", "lh+imu+we"),
) -> list[dict]:
    """Estimation without commanded inputs and without a start state.

    For each estimator and sensor set, four variants (:data:`INPUT_VARIANTS`), queried at 60 Hz:

    * ``estimated_blind``: ``inputs="estimated"`` (steering and torque are random-walk states),
      no commands delivered, blind start ``reset(0.0)``;
    * ``estimated_x0``: the same from the usual wrong start state (separates the two effects);
    * ``commanded_no_inputs``: the old behaviour, the commanded model with no commands
      delivered (it silently uses ``u = 0``), from the usual start state;
    * ``inputs_given``: the accuracy rows' set-up (``inputs="auto"``, commands delivered, usual
      start state); the same numbers as the ``accuracy`` rows.

    RMSE after :data:`SETTLING_S` (mean and std over seeds) and per run :func:`run_metrics`.
    """
    drives = {seed: standard_drive(seed, duration) for seed in seeds}
    rows = []
    for kind in kinds:
        for sensors in sensor_sets:
            for variant, (mode, delivered, start) in INPUT_VARIANTS.items():
                values, runs = [], []
                for seed, result in drives.items():
                    estimator = make_estimator(kind, sensors, inputs=mode)
                    x0 = None if start == "blind" else start_state(result)
                    run = replay(estimator, result, RATE_HZ, x0, inputs=delivered)
                    values.append([rmse(run, result)[s] for s in STATE_NAMES])
                    runs.append({"seed": seed, **run_metrics(run, result, estimator)})
                values = np.array(values)
                rows.append(
                    {
                        "benchmark": "inputs_withheld",
                        "estimator": kind,
                        "sensors": sensors,
                        "variant": variant,
                        "inputs": mode,
                        "commands_delivered": delivered,
                        "start": start,
                        "rate_hz": RATE_HZ,
                        "rmse": dict(
                            zip(STATE_NAMES, values.mean(0).round(6).tolist(), strict=True)
                        ),
                        "rmse_std": dict(
                            zip(STATE_NAMES, values.std(0).round(6).tolist(), strict=True)
                        ),
                        "runs": runs,
                        "worst": _worst(runs),
                        "seeds": list(seeds),
                        "duration_s": duration,
                    }
                )
    return rows


def _worst(runs: list[dict]) -> dict:
    """The worst value of each per-run figure over the runs (``None`` = never converged)."""
    out = {}
    for key in runs[0]:
        if key == "seed":
            continue
        values = [r[key] for r in runs]
        out[key] = None if any(v is None for v in values) else max(values)
    return out


# --- 2. the Lighthouse pose solver -----------------------------------------------------------
def pose_solver_rows(seeds: Sequence[int], duration: float = 20.0) -> list[dict]:
    """Accuracy of single-shot Lighthouse pose fixes, per sweep pair, against the truth.

    Every Lighthouse sweep of the standard drive's stream goes through
    :class:`~crs_core.estimation.SweepPairer` (``max_gap`` 30 ms); each pair is solved without
    a guess (closed-form start) and compared with the truth at the pair stamp (the mean of the
    two plane stamps). The solver's angle std is the simulator's angle noise (1 mrad), so the
    mean NEES should be 3 (the number of pose coordinates).

    Two variants:

    ``stream``
        The simulated sweeps as they are. **The car moves between the two planes' stamps**
        (the simulator sweeps plane 2 half a period, 10 ms, after plane 1): the solver treats
        both planes as taken at one instant, so its error includes that motion
        (``motion_between_planes_mm`` gives its size), and the NEES is far above 3.
    ``static``
        The same pair stamps, but both planes computed from the truth *at* the pair stamp
        plus the simulator's angle noise: the solver's own error, without motion.

    A pair counts as solved when the solver returns a fix (``None``: no credible solution).
    """
    model = CarModel()
    p = model.parameters.vector()
    rows = []
    for variant in ("stream", "static"):
        position, yaw, nees, times, motion = [], [], [], [], []
        pairs = solved = 0
        for seed in seeds:
            result = standard_drive(seed, duration)
            angle_std = float(result.sensors.lighthouse.noise_std[0])
            solver = LighthousePoseSolver(model, angle_std)
            pairer = SweepPairer(0.03)
            rng = np.random.default_rng([seed, 2024])
            for measurement in result.measurements:
                paired = pairer.add(measurement)
                if paired is None:
                    continue
                stamp, sweeps = paired
                truth = result.truth_at(np.array([stamp]))[0]
                if variant == "static":
                    u = result.input_at(np.array([stamp]))[0]
                    outputs = model.numeric.outputs(model.initial_state(truth, u), u, p)
                    sweeps = {k: outputs[k] + angle_std * rng.standard_normal(4) for k in sweeps}
                    if not all(np.all(np.abs(v) <= LIGHTHOUSE_VIEW_LIMIT) for v in sweeps.values()):
                        continue  # out of view: the simulator would have dropped it
                else:
                    other = 2.0 * stamp - measurement.stamp  # the partner plane's stamp
                    ends = result.truth_at(np.array([other, measurement.stamp]))
                    motion.append(float(np.hypot(*(ends[1, :2] - ends[0, :2]))))
                pairs += 1
                start = time.perf_counter()
                fix = solver.solve(sweeps, stamp)
                times.append(time.perf_counter() - start)
                if fix is None:
                    continue
                solved += 1
                e = fix.pose - truth[:3]
                e[2] = wrap_angle(e[2])
                position.append(float(np.hypot(e[0], e[1])))
                yaw.append(abs(float(e[2])))
                nees.append(float(e @ np.linalg.solve(fix.covariance, e)))
        nees_array = np.array(nees)
        row = {
            "benchmark": "pose_solver",
            "variant": variant,
            "angle_std_rad": angle_std,
            "pairs": pairs,
            "solved_fraction": round(solved / max(pairs, 1), 4),
            "position_error_mm": summary(np.array(position) * 1e3, digits=4),
            "yaw_error_mrad": summary(np.array(yaw) * 1e3, digits=4),
            "nees": {
                **summary(nees_array, ("mean", "median"), digits=3),
                "within_95_percent": round(float(np.mean(nees_array < chi2.ppf(0.95, 3))), 4),
                "ideal_mean": 3.0,
            },
            "solve_time_ms": summary(np.array(times) * 1e3, ("median", "p95"), digits=4),
            "seeds": list(seeds),
            "duration_s": duration,
        }
        if motion:
            row["motion_between_planes_mm"] = summary(np.array(motion) * 1e3, digits=4)
        rows.append(row)
    return rows


# --- 3. pathological timing ------------------------------------------------------------------
#: Query / delivery patterns of :func:`timing_robustness_rows`.
TIMING_PATTERNS = ("normal", "late_queries", "stall", "shuffled", "duplicates", "past_queries")


def timing_schedule(
    pattern: str, result: SimulationResult, seed: int
) -> tuple[list[tuple[float, object]], list[tuple[float, float]]]:
    """Deliveries ``(arrival time, item)`` and queries ``(query time, stamp asked)``.

    ``normal``
        Data arrive at their stamps; queries at 60 Hz ask for their own time.
    ``late_queries``
        5 % of the 60 Hz ticks come 0.5 s late (the ticks in between are skipped), as a
        starved timer would.
    ``stall``
        No query for 1 s from ``0.4 * duration`` (8 s on the 20 s drive); the data keep
        arriving and are delivered at once when the queries resume.
    ``shuffled``
        Out-of-order delivery: the data are cut into 200 ms batches by stamp and each batch's
        items are delivered in a random order at the batch's arrival instants, so a sample can
        arrive up to 200 ms after newer ones (and after queries that passed its stamp).
    ``duplicates``
        Every measurement is delivered twice (same stamp, same values).
    ``past_queries``
        The normal pattern plus, after 5 % of the ticks, an extra query for the estimate
        0.5 s in the past (a consumer catching up on an old stamp).
    """
    rng = np.random.default_rng([seed, 7])
    events = stream_events(result)
    grid = query_grid(result, RATE_HZ)
    queries = [(t, t) for t in grid]
    deliveries = events
    if pattern == "late_queries":
        queries, t = [], 0.0
        while True:
            t += 0.5 if rng.random() < 0.05 else 1.0 / RATE_HZ
            if t >= result.duration:
                break
            queries.append((t, t))
    elif pattern == "stall":
        start = 0.4 * result.duration
        queries = [(t, t) for t in grid if not start <= t < start + 1.0]
    elif pattern == "shuffled":
        batch = np.floor(np.array([stamp for stamp, _ in events]) / 0.2).astype(int)
        items = [item for _, item in events]
        order = np.arange(len(events))
        for b in np.unique(batch):
            index = np.nonzero(batch == b)[0]
            order[index] = rng.permutation(index)
        deliveries = [(events[i][0], items[order[i]]) for i in range(len(events))]
    elif pattern == "duplicates":
        deliveries = [
            (stamp, item)
            for stamp, item in events
            for _ in range(2 if isinstance(item, Measurement) else 1)
        ]
    elif pattern == "past_queries":
        queries = []
        for t in grid:
            queries.append((t, t))
            if t > 0.5 and rng.random() < 0.05:
                queries.append((t, t - 0.5))
    elif pattern != "normal":
        raise ValueError(f"pattern: must be one of {', '.join(TIMING_PATTERNS)}, got {pattern!r}")
    return deliveries, queries


def timing_robustness_rows(
    seeds: Sequence[int],
    duration: float = 20.0,
    kinds: Sequence[str] = ("ekf", "mhe"),
    patterns: Sequence[str] = TIMING_PATTERNS,
) -> list[dict]:
    """EKF and MHE (``lh+imu+we``, inputs given, usual start state) under pathological timing.

    Per pattern (:func:`timing_schedule`): the largest position error of the estimates stamped
    after :data:`SETTLING_S`, the position RMSE there, the number of non-finite estimates (must
    be 0), the estimator's fallbacks, late (dropped) samples, skipped seconds and
    re-initialisations, the statuses of all estimates, and the time per query (delivery plus
    estimate). For ``past_queries`` also the largest error of the queries into the past alone.
    """
    drives = {seed: standard_drive(seed, duration) for seed in seeds}
    rows = []
    for kind in kinds:
        for pattern in patterns:
            runs, times = [], []
            for seed, result in drives.items():
                deliveries, queries = timing_schedule(pattern, result, seed)
                estimator = make_estimator(kind, "lh+imu+we")
                run = replay_schedule(estimator, deliveries, queries, start_state(result))
                times.extend(run.update_times_s)
                finite = np.all(np.isfinite(run.estimates), axis=1)
                error = errors(Run(*_subset(run, finite)), result)
                position = np.hypot(error[:, 0], error[:, 1])
                settled = run.stamps[finite] >= SETTLING_S
                d = estimator.diagnostics
                metrics = {
                    "seed": seed,
                    "queries": len(run.stamps),
                    "max_position_error_m": round(float(position[settled].max()), 6),
                    "position_rmse_m": round(float(np.sqrt(np.mean(position[settled] ** 2))), 6),
                    "non_finite": int(np.sum(~finite)),
                    "fallbacks": int(d.fallbacks),
                    "late": int(d.late),
                    "skipped_s": round(float(d.skipped_s), 4),
                    "reinitializations": int(d.reinitializations),
                    "statuses": dict(Counter(run.statuses)),
                }
                if pattern == "past_queries":
                    query_times = np.array([now for now, _ in queries])
                    past = (run.stamps < query_times) & finite & (run.stamps >= SETTLING_S)
                    metrics["max_position_error_past_queries_m"] = round(
                        float(np.hypot(*(errors(Run(*_subset(run, past)), result)[:, :2].T)).max()),
                        6,
                    )
                runs.append(metrics)
            rows.append(
                {
                    "benchmark": "timing_robustness",
                    "estimator": kind,
                    "sensors": "lh+imu+we",
                    "pattern": pattern,
                    "max_position_error_m": max(r["max_position_error_m"] for r in runs),
                    "non_finite": sum(r["non_finite"] for r in runs),
                    "fallbacks": sum(r["fallbacks"] for r in runs),
                    "statuses": dict(sum((Counter(r["statuses"]) for r in runs), Counter())),
                    "time_ms": time_summary(times),
                    "runs": runs,
                    "seeds": list(seeds),
                    "duration_s": duration,
                }
            )
    return rows


def _subset(run: Run, mask: np.ndarray) -> tuple:
    statuses = [s for s, keep in zip(run.statuses, mask, strict=True) if keep]
    return run.stamps[mask], run.estimates[mask], run.update_times_s[mask], statuses


# --- table -----------------------------------------------------------------------------------
def format_rows(rows: list[dict]) -> list[str]:
    """Table lines of the rows of this module (mm, mrad, mm/s, ms)."""
    lines = []
    withheld = [r for r in rows if r["benchmark"] == "inputs_withheld"]
    if withheld:
        lines.append(
            "inputs withheld (RMSE after 2 s, mean over seeds; worst over seeds: first "
            "non-lost estimate, first in bounds (1 cm, 0.1 rad), converged = in bounds from then "
            "on, share out of bounds after 2 s, max position error after 1 s, lost/degraded "
            "queries after 2 s, re-initialisations):"
        )
        lines.append(
            f"{'est':4s} {'sensors':10s} {'variant':20s} {'x mm':>6s} {'y mm':>6s} "
            f"{'yaw mrad':>8s} {'vx mm/s':>8s} {'vy mm/s':>8s} {'ω mrad/s':>8s} "
            f"{'first s':>7s} {'in s':>5s} {'conv s':>6s} {'out %':>5s} {'max1s mm':>8s} "
            f"{'lost/degr':>9s} {'reinit':>6s}"
        )
        for row in withheld:
            r, w = row["rmse"], row["worst"]
            conv, first, within = (
                "never" if w[key] is None else f"{w[key]:.{digits}f}"
                for key, digits in (
                    ("converged_s", 2),
                    ("first_estimate_s", 3),
                    ("first_in_bounds_s", 2),
                )
            )
            lines.append(
                f"{row['estimator']:4s} {row['sensors']:10s} {row['variant']:20s} "
                f"{r['x'] * 1e3:6.1f} {r['y'] * 1e3:6.1f} {r['yaw'] * 1e3:8.1f} "
                f"{r['vx'] * 1e3:8.1f} {r['vy'] * 1e3:8.1f} {r['omega'] * 1e3:8.1f} "
                f"{first:>7s} {within:>5s} {conv:>6s} {w['out_of_bounds_after_2s']:5.1%} "
                f"{w['max_position_error_after_1s_m'] * 1e3:8.1f} "
                f"{w['lost_after_2s']:>4d}/{w['degraded_after_2s']:<4d} "
                f"{w['reinitializations']:6d}"
            )
    for row in rows:
        if row["benchmark"] != "pose_solver":
            continue
        pos, yaw, nees, t = (
            row["position_error_mm"],
            row["yaw_error_mrad"],
            row["nees"],
            row["solve_time_ms"],
        )
        motion = row.get("motion_between_planes_mm")
        lines.append(
            f"pose solver ({row['variant']}, {row['pairs']} pairs, {row['solved_fraction']:.1%} "
            f"solved): position median/p95/max {pos['median']:.2f}/{pos['p95']:.2f}/"
            f"{pos['max']:.2f} mm, yaw {yaw['median']:.1f}/{yaw['p95']:.1f}/{yaw['max']:.1f} "
            f"mrad, mean NEES {nees['mean']:.2f} (ideal 3), solve {t['median']:.3f}/"
            f"{t['p95']:.3f} ms"
            + (f"; car moved {motion['median']:.1f} mm (median) between planes" if motion else "")
        )
    timing = [r for r in rows if r["benchmark"] == "timing_robustness"]
    if timing:
        lines.append(
            "timing robustness (lh+imu+we, inputs given; max position error after 2 s, worst "
            "over seeds; counts summed over seeds):"
        )
        for row in timing:
            statuses = ", ".join(f"{k} {v}" for k, v in sorted(row["statuses"].items()))
            late = sum(r["late"] for r in row["runs"])
            past = [r.get("max_position_error_past_queries_m") for r in row["runs"]]
            extra = f", past queries {max(past) * 1e3:.1f} mm" if past[0] is not None else ""
            lines.append(
                f"  {row['estimator']:4s} {row['pattern']:13s} max error "
                f"{row['max_position_error_m'] * 1e3:7.1f} mm{extra}; non-finite "
                f"{row['non_finite']}, fallbacks {row['fallbacks']}, late {late}; {statuses}; "
                f"query median/max {row['time_ms']['median']:.2f}/{row['time_ms']['max']:.1f} ms"
            )
    return lines


#: The docs' words for the :data:`INPUT_VARIANTS`.
VARIANT_LABELS = {
    "estimated_blind": "no inputs, blind",
    "estimated_x0": "no inputs, from x0",
    "commanded_no_inputs": "u = 0 (old behaviour)",
    "inputs_given": "with inputs",
}


def format_markdown(rows: list[dict]) -> str:
    """The docs' table of the inputs-withheld rows (Markdown; mm, mrad, mm/s, s): RMSE after
    2 s (mean over seeds) and, worst over seeds, the first estimate, the first query in bounds,
    the share out of bounds after 2 s and the largest position error after 1 s."""
    withheld = [r for r in rows if r["benchmark"] == "inputs_withheld"]
    lines = [
        "| est | sensors | variant | x mm | y mm | yaw mrad | v_x mm/s | v_y mm/s | ω mrad/s "
        "| first estimate s | in bounds from s | out of bounds after 2 s "
        "| max pos. error after 1 s mm |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in withheld:
        r, w = row["rmse"], row["worst"]
        first, within = (
            "never" if w[key] is None else f"{w[key]:.{digits}f}"
            for key, digits in (("first_estimate_s", 3), ("first_in_bounds_s", 2))
        )
        lines.append(
            f"| {row['estimator'].upper()} | {row['sensors']} "
            f"| {VARIANT_LABELS.get(row['variant'], row['variant'])} "
            f"| {r['x'] * 1e3:.1f} | {r['y'] * 1e3:.1f} | {r['yaw'] * 1e3:.1f} "
            f"| {r['vx'] * 1e3:.1f} | {r['vy'] * 1e3:.1f} | {r['omega'] * 1e3:.0f} "
            f"| {first} | {within} | {100 * w['out_of_bounds_after_2s']:.1f} % "
            f"| {w['max_position_error_after_1s_m'] * 1e3:.1f} |"
        )
    return "\n".join(lines)
