"""Estimation benchmarks (``crs bench estimation``): accuracy, blackout, speed, peers, real data.

Every row is computed on simulated data with known truth, except the real-data rows, whose
reference is the car's own on-line estimate (not ground truth). The rows of robust estimation
(inputs withheld and blind start, the Lighthouse pose solver, pathological timing) live in
:mod:`benchmarks.robust_estimation`; :func:`run_all` and :func:`format_table` include them.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from benchmarks.machine import format_ms
from benchmarks.robust_estimation import (
    format_rows,
    inputs_withheld_rows,
    pose_solver_rows,
    timing_robustness_rows,
)
from crs_core.analysis.consistency import predicted_samples
from crs_core.analysis.metrics import STATE_NAMES
from crs_core.analysis.statistics import summary
from crs_core.dataset import Dataset
from crs_core.estimation import make_estimator
from crs_core.estimation.ekf import EkfSettings
from crs_core.estimation.mhe import MheSettings
from crs_core.estimation.noise import EstimatorNoise
from crs_core.measurements import InputSample
from crs_core.model import CarModel
from sim.replay import (
    errors,
    replay,
    rmse,
    start_state,
    time_summary,
)
from sim.scenarios import standard_drive
from sim.sensors import Blackout

#: Sensor combinations of the paper's Table I.
SENSOR_SETS = ("lh", "lh+imu", "lh+we", "lh+imu+we")
# --- the benchmark suite ---------------------------------------------------------------------
PAPER_TABLE_I = {  # real car, motion-capture reference (paper Table I): mm, mrad, mm/s
    ("ekf", "lh"): (31, 21, 42, 69, 67),
    ("mhe", "lh"): (29, 18, 71, 99, 83),
    ("ekf", "lh+imu"): (25, 16, 44, 375, 290),
    ("mhe", "lh+imu"): (23, 15, 62, 262, 241),
    ("ekf", "lh+we"): (30, 20, 49, 31, 42),
    ("mhe", "lh+we"): (32, 21, 74, 34, 44),
    ("ekf", "lh+imu+we"): (30, 20, 45, 26, 36),
    ("mhe", "lh+imu+we"): (32, 21, 45, 25, 32),
}


def accuracy_rows(seeds: Sequence[int], kinds=("ekf", "mhe"), progress=None) -> list[dict]:
    """Table I on simulation: every sensor set x estimator, mean and std over seeds."""
    drives = {seed: standard_drive(seed) for seed in seeds}
    rows = []
    for kind in kinds:
        for sensors in SENSOR_SETS:
            per_seed, times = [], []
            for result in drives.values():
                run = replay(make_estimator(kind, sensors), result, 60.0, start_state(result))
                per_seed.append([rmse(run, result)[s] for s in STATE_NAMES])
                times.extend(run.update_times_s)
                if progress:
                    progress()
            values = np.array(per_seed)
            rows.append(
                {
                    "benchmark": "accuracy",
                    "estimator": kind,
                    "sensors": sensors,
                    "rate_hz": 60.0,
                    "rmse": dict(zip(STATE_NAMES, values.mean(0).round(6).tolist(), strict=True)),
                    "rmse_std": dict(
                        zip(STATE_NAMES, values.std(0).round(6).tolist(), strict=True)
                    ),
                    "time_ms": time_summary(times),
                    "seeds": list(seeds),
                }
            )
    return rows


def blackout_rows(seeds: Sequence[int], start: float = 9.0, duration: float = 1.127) -> list[dict]:
    """Lighthouse off for ``duration`` s mid-lap: error at its end and time to recover.

    Recovered means the position error is back below ``max(3 * nominal, 3 mm)`` and stays there
    for at least 0.5 s, where nominal is the estimator's own position RMSE on the same run
    without blackout.
    """
    rows = []
    for kind in ("ekf", "mhe"):
        end_errors, recover_times = [], []
        for seed in seeds:
            clean = standard_drive(seed)
            dark = standard_drive(seed, blackouts=[Blackout("lighthouse", start, duration)])
            reference = rmse(
                replay(make_estimator(kind, "lh+imu+we"), clean, 60.0, start_state(clean)), clean
            )
            nominal = float(np.hypot(reference["x"], reference["y"]))
            run = replay(make_estimator(kind, "lh+imu+we"), dark, 60.0, start_state(dark))
            error = errors(run, dark)
            position = np.hypot(error[:, 0], error[:, 1])
            end = start + duration
            end_errors.append(float(np.interp(end, run.stamps, position)))
            recover_times.append(
                _time_to_recover(run.stamps, position, end, max(3 * nominal, 3e-3))
            )
        rows.append(
            {
                "benchmark": "blackout",
                "estimator": kind,
                "sensors": "lh+imu+we",
                "blackout_s": [start, duration],
                "position_error_at_end_m": {
                    "mean": float(np.mean(end_errors)),
                    "max": float(np.max(end_errors)),
                },
                "time_to_recover_s": {
                    "mean": float(np.mean(recover_times)),
                    "max": float(np.max(recover_times)),
                },
                "seeds": list(seeds),
            }
        )
    return rows


def _time_to_recover(stamps: np.ndarray, error: np.ndarray, start: float, bound: float) -> float:
    """Seconds after ``start`` until ``error`` stays below ``bound`` for 0.5 s (inf if never)."""
    good_since = None
    for t, e in zip(stamps, error, strict=True):
        if t < start:
            continue
        if e < bound:
            good_since = t if good_since is None else good_since
            if t - good_since >= 0.5:
                return float(good_since - start)
        else:
            good_since = None
    return float("inf")


#: The online parameters of the speed table's MHE with online parameters (docs/online.md).
SPEED_ONLINE = ("Cm1", "gyro_bias", "grip")


def speed_rows(seed: int = 0) -> list[dict]:
    """MHE M = 40 per update at 60 and 250 Hz, and at 60 Hz with :data:`SPEED_ONLINE` online;
    EKF per measurement."""
    result = standard_drive(seed)
    rows = []
    for rate, online in ((60.0, ()), (250.0, ()), (60.0, SPEED_ONLINE)):
        settings = MheSettings(rate_hz=rate, online_parameters=online)
        estimator = make_estimator("mhe", "lh+imu+we", settings=settings, inputs="commanded")
        run = replay(estimator, result, rate, start_state(result))
        rows.append(
            {
                "benchmark": "speed",
                "estimator": "mhe",
                "sensors": "lh+imu+we",
                "rate_hz": rate,
                "online_parameters": list(online),
                "horizon": 40,
                "time_ms": time_summary(run.update_times_s),
                "fallbacks": estimator.diagnostics.fallbacks,
                "not_ok_updates": sum(s != "ok" for s in run.statuses),
                "deadline_misses": int(np.sum(run.update_times_s > 1.0 / rate)),
                "seeds": [seed],
            }
        )
    ekf = make_estimator("ekf", "lh+imu+we", inputs="commanded")
    ekf.reset(0.0, start_state(result))
    for sample in result.inputs:
        ekf.add_input(sample)
    per_measurement = []
    for measurement in result.measurements:
        start = time.perf_counter()
        ekf.add_measurement(measurement)
        ekf.process(measurement.stamp)
        per_measurement.append(time.perf_counter() - start)
    rows.append(
        {
            "benchmark": "speed",
            "estimator": "ekf",
            "sensors": "lh+imu+we",
            "per": "measurement (predict to its stamp + update)",
            "time_ms": time_summary(per_measurement),
            "seeds": [seed],
        }
    )
    return rows


def real_rows(
    folders: Sequence[Path],
    plot_dir: Path | None = None,
    noise: EstimatorNoise | None = None,
    kinds: Sequence[str] = ("ekf", "mhe"),
) -> list[dict]:
    """``kinds`` of estimator over real recordings (LH + WE + yaw rate, as recorded), assuming
    ``noise`` (default: the estimators' own).

    The reference is the car's own on-line estimate ``x.npy``, not ground truth. Also reported:
    the Lighthouse angle residuals of each estimate (recorded minus predicted sweep angles).
    """
    rows = []
    for folder in folders:
        dataset = Dataset.load(folder)
        t0 = float(dataset.t[0])
        shifted = Dataset(
            t=dataset.t - t0, u=dataset.u, y=dataset.y, x=dataset.x, geometry=dataset.geometry
        )
        stream = shifted.sample_stream()
        inputs = [InputSample(float(t), u) for t, u in zip(shifted.t, shifted.u, strict=True)]
        model = CarModel().parameters.updated(
            {n: p.value for n, p in dataset.geometry.parameters().items()}
        )
        reference = shifted.x
        trajectories = {}
        assumed = noise or EstimatorNoise()
        for kind in kinds:
            settings = (
                MheSettings(rate_hz=50.0, noise=assumed)
                if kind == "mhe"
                else EkfSettings(noise=assumed)
            )
            estimator = make_estimator(
                kind, "lh+we+gyro", CarModel(parameters=model), settings, inputs="commanded"
            )
            estimator.reset(0.0, reference[0].copy())
            for item in inputs:
                estimator.add_input(item)
            for item in stream:
                estimator.add_measurement(item)
            estimates, times = [], []
            for t in shifted.t[1:]:
                start = time.perf_counter()
                estimates.append(estimator.estimate(float(t)).x)
                times.append(time.perf_counter() - start)
            estimate = np.array(estimates)
            trajectories[kind] = estimate
            difference = estimate - reference[1:]
            residual = (
                shifted.y[1:, :8]
                - predicted_samples(
                    Dataset(
                        t=shifted.t[1:],
                        u=shifted.u[1:],
                        y=shifted.y[1:],
                        x=estimate,
                        geometry=dataset.geometry,
                    ),
                    CarModel(parameters=model),
                )[:, :8]
            )
            rows.append(
                {
                    "benchmark": "real",
                    "estimator": kind,
                    "sensors": "lh+we+gyro",
                    "run": Path(folder).name,
                    "rmse_vs_onboard_estimate": dict(
                        zip(
                            STATE_NAMES,
                            np.sqrt(np.mean(difference**2, 0)).round(6).tolist(),
                            strict=True,
                        )
                    ),
                    "lighthouse_residual_rad": summary(np.abs(residual), ("median", "p95")),
                    "time_ms": time_summary(times),
                    "note": "reference is the car's on-line estimate, not ground truth",
                }
            )
        if plot_dir is not None:
            _plot_real(Path(folder).name, reference, trajectories, plot_dir)
    return rows


def _plot_real(name: str, reference: np.ndarray, trajectories: dict, folder: Path) -> None:
    from matplotlib.figure import Figure

    folder.mkdir(parents=True, exist_ok=True)
    fig = Figure(figsize=(8, 6))
    ax = fig.subplots()
    ax.plot(reference[:, 0], reference[:, 1], "k", lw=1.5, label="on-board estimate (x.npy)")
    for kind, estimate in trajectories.items():
        ax.plot(estimate[:, 0], estimate[:, 1], lw=0.8, label=kind)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{name}: EKF and MHE on the real recording (LH + WE + yaw rate)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(folder / f"real_{name}.png", dpi=110)


def peer_rows(seeds: Sequence[int], sensors: str = "lh+imu+we") -> list[dict]:
    """filterpy's EKF, do-mpc's MHE and acados's MHE beside ours: same model, noise settings
    and data.

    do-mpc averages the samples of an interval like our MHE (``combine="mean"``). acados solves
    our MHE's own problem (:class:`benchmarks.acados_mhe.AcadosMhe`), so it is compared with our
    MHE on the commanded model (the estimator whose solver it replaces; the other rows' ours
    start input-free until the first command); its row adds ``solve_ms`` (acados's ``solve()``
    alone), ``step_ms`` (its step: the data in and out of acados, ``solve()``, the
    marginalization; ours' Gauss-Newton step in ``ours``), both per update, and the fallbacks.
    Each peer row carries ``ratio_to_ours``: its RMSE and median time divided by ours (time > 1:
    slower). Without acados (:class:`~crs_core.acados_support.AcadosUnavailable`) its row says
    why it was skipped.
    """
    from benchmarks.peers import DoMpcMhe, FilterpyEkf
    from crs_core.acados_support import AcadosUnavailable

    drives = [standard_drive(seed) for seed in seeds]
    makers = {
        "ekf": lambda: make_estimator("ekf", sensors),
        "mhe": lambda: make_estimator("mhe", sensors),
        "filterpy-ekf": lambda: FilterpyEkf(CarModel(), sensors),
        "do-mpc-mhe": lambda: DoMpcMhe(CarModel(), sensors, MheSettings(), combine="mean"),
    }
    skipped = {}
    try:
        from benchmarks.acados_mhe import AcadosMhe, StepTimedMhe
        from crs_core.acados_support import acados_template

        acados_template()
        makers["mhe-commanded"] = lambda: StepTimedMhe(CarModel(), sensors, MheSettings())
        makers["acados-mhe"] = lambda: AcadosMhe(CarModel(), sensors, MheSettings())
    except AcadosUnavailable as error:
        skipped["acados-mhe"] = str(error)
    measured = {}
    for name, make in makers.items():
        values, times = [], []
        extra: dict[str, list] = {"solve": [], "step": [], "fallbacks": []}
        for result in drives:
            estimator = make()
            run = replay(estimator, result, 60.0, start_state(result))
            values.append([rmse(run, result)[s] for s in STATE_NAMES])
            times.extend(run.update_times_s)
            extra["solve"].extend(getattr(estimator, "solve_times_s", []))
            extra["step"].extend(getattr(estimator, "step_times_s", []))
            extra["fallbacks"].append(estimator.diagnostics.fallbacks)
        measured[name] = (np.mean(values, axis=0), time_summary(times), extra)
    rows = []
    pairs = [("filterpy-ekf", "ekf"), ("do-mpc-mhe", "mhe"), ("acados-mhe", "mhe-commanded")]
    for peer, ours in pairs:
        if peer in skipped:
            rows.append(
                {"benchmark": "peer", "estimator": peer, "skipped": skipped[peer],
                 "seeds": list(seeds)}
            )  # fmt: skip
            continue
        values, timing, extra = measured[peer]
        our_values, our_timing, our_extra = measured[ours]
        row = {
            "benchmark": "peer",
            "estimator": peer,
            "sensors": sensors,
            "rate_hz": 60.0,
            "rmse": dict(zip(STATE_NAMES, values.round(6).tolist(), strict=True)),
            "time_ms": timing,
            "compared_with": "mhe" if ours == "mhe-commanded" else ours,
            "ours": {
                "rmse": dict(zip(STATE_NAMES, our_values.round(6).tolist(), strict=True)),
                "time_ms": our_timing,
            },
            "ratio_to_ours": {
                "rmse": dict(
                    zip(STATE_NAMES, (values / our_values).round(3).tolist(), strict=True)
                ),
                "time_median": round(timing["median"] / our_timing["median"], 2),
            },
            "seeds": list(seeds),
        }
        if peer == "acados-mhe":
            row["solve_ms"] = time_summary(extra["solve"])
            row["step_ms"] = time_summary(extra["step"])
            row["fallbacks"] = int(sum(extra["fallbacks"]))
            row["ours"]["inputs"] = "commanded"
            row["ours"]["step_ms"] = time_summary(our_extra["step"])
            row["ours"]["fallbacks"] = int(sum(our_extra["fallbacks"]))
            row["ratio_to_ours"]["step_median"] = round(
                row["step_ms"]["median"] / row["ours"]["step_ms"]["median"], 2
            )
        rows.append(row)
    return rows


def run_all(
    seeds: Sequence[int] = (0, 1, 2, 3, 4),
    real_folders: Sequence[Path] = (),
    plot_dir: Path | None = None,
    peers: bool = True,
    robust: bool = True,
) -> list[dict]:
    """Every estimation benchmark, in the order of the issue: accuracy, blackout, speed, peers,
    real data; then (``robust``) inputs withheld with a blind start, the Lighthouse pose
    solver and pathological timing (:mod:`benchmarks.robust_estimation`)."""
    from tqdm import tqdm

    bar = tqdm(total=2 * len(SENSOR_SETS) * len(seeds), desc="accuracy", leave=False)
    rows = accuracy_rows(seeds, progress=lambda: bar.update())
    bar.close()
    rows += blackout_rows(seeds[:3])
    rows += speed_rows()
    if peers:
        rows += peer_rows(seeds[:2])
    rows += real_rows(real_folders, plot_dir)
    if robust:
        rows += inputs_withheld_rows(seeds)
        rows += pose_solver_rows(seeds)
        rows += timing_robustness_rows(seeds)
    return rows


def format_table(rows: list[dict]) -> str:
    """Readable summary of the benchmark rows (mm, mrad, mm/s, ms)."""
    lines = ["accuracy (simulation, mean ± std over seeds; paper Table I = real car):"]
    lines.append(
        f"{'est':4s} {'sensors':10s} {'x mm':>11s} {'y mm':>11s} {'yaw mrad':>11s} "
        f"{'vx mm/s':>11s} {'vy mm/s':>11s} {'ω mrad/s':>11s}   paper x/y/yaw/vx/vy"
    )
    for row in rows:
        if row["benchmark"] != "accuracy":
            continue
        cells = " ".join(
            f"{row['rmse'][s] * 1e3:5.1f}±{row['rmse_std'][s] * 1e3:<5.1f}" for s in STATE_NAMES
        )
        paper = PAPER_TABLE_I.get((row["estimator"], row["sensors"]), ())
        lines.append(f"{row['estimator']:4s} {row['sensors']:10s} {cells}   {paper}")
    for row in rows:
        kind = row["benchmark"]
        if kind == "blackout":
            end, recover = row["position_error_at_end_m"], row["time_to_recover_s"]
            lines.append(
                f"blackout {row['estimator']}: LH off {row['blackout_s'][1]} s -> position error "
                f"at its end {end['mean'] * 1e3:.1f} mm (max {end['max'] * 1e3:.1f}), recovered "
                f"after {recover['mean']:.2f} s (max {recover['max']:.2f})"
            )
        elif kind == "peer" and "skipped" in row:
            lines.append(f"peer {row['estimator']}: skipped ({row['skipped']})")
        elif kind in ("speed", "peer"):
            t = row["time_ms"]
            what = (
                f"{row['estimator']} at {row['rate_hz']:g} Hz"
                if "rate_hz" in row
                else f"{row['estimator']} per measurement"
            )
            if row.get("online_parameters"):
                what += f" with {','.join(row['online_parameters'])} online"
            extra = ""
            if kind == "peer":
                ratio = row["ratio_to_ours"]
                errors_mm = "/".join(f"{row['rmse'][s] * 1e3:.1f}" for s in STATE_NAMES[:5])
                ratios = "/".join(f"{ratio['rmse'][s]:.2f}" for s in STATE_NAMES[:5])
                extra = (
                    f"; rmse x/y/yaw/vx/vy {errors_mm}; vs {row['compared_with']}: time "
                    f"x{ratio['time_median']:g}, rmse ratios {ratios}"
                )
                if "solve_ms" in row:
                    extra += (
                        f"; solve() median {row['solve_ms']['median']:.3f} ms (p95 "
                        f"{row['solve_ms']['p95']:.3f}), step {row['step_ms']['median']:.3f} ms"
                        f" vs ours' {row['ours']['step_ms']['median']:.3f} ms, fallbacks "
                        f"{row['fallbacks']} vs {row['ours']['fallbacks']}"
                    )
            lines.append(
                f"{kind} {what}: median {t['median']:.3f} ms, p95 {t['p95']:.3f}, "
                f"p99 {t['p99']:.3f}, max {t['max']:.3f}{extra}"
            )
        elif kind == "real":
            r, lh = row["rmse_vs_onboard_estimate"], row["lighthouse_residual_rad"]
            lines.append(
                f"real {row['run']} {row['estimator']}: vs on-board estimate x {r['x'] * 1e3:.1f}"
                f" mm, y {r['y'] * 1e3:.1f} mm, yaw {r['yaw'] * 1e3:.1f} mrad, vx"
                f" {r['vx'] * 1e3:.0f} mm/s; LH residual median {lh['median'] * 1e3:.2f} mrad,"
                f" p95 {lh['p95'] * 1e3:.2f} mrad"
            )
    lines += format_rows(rows)
    return "\n".join(lines)


#: The per-update time targets of the speed table.
SPEED_TARGETS = {"mhe": "median ≤ 1 ms, p99 ≤ 3 ms", "ekf": "≤ 0.2 ms"}
#: The peers' names in the docs.
PEER_NAMES = {
    "filterpy-ekf": "filterpy `ExtendedKalmanFilter`",
    "do-mpc-mhe": "do-mpc `MHE` (IPOPT)",
    "acados-mhe": "acados OCP (SQP-RTI, HPIPM) on our MHE's problem",
}


def _seeds(seeds: Sequence[int]) -> str:
    """``0–4`` for consecutive seeds, else ``0, 2, 5``."""
    seeds = list(seeds)
    if len(seeds) > 1 and seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}–{seeds[-1]}"
    return ", ".join(str(s) for s in seeds)


def _solver_split(row: dict) -> str:
    """What of the acados peer's update is solver and what is Python, beside ours."""

    def pair(times: dict) -> str:
        return f"{format_ms(times['median'])} / {format_ms(times['p95'])} ms"

    ours = row["ours"]
    return (
        f"acados per update (median / p95): `solve()` {pair(row['solve_ms'])}; its step (the "
        "stage data assembled in numpy, set in and read back by a C helper, `solve()`, the "
        f"marginalization in numpy) {pair(row['step_ms'])}; the whole update "
        f"{pair(row['time_ms'])} (the rest is our MHE's bookkeeping, which it shares). Ours "
        f"(commanded model): Gauss-Newton step with marginalization {pair(ours['step_ms'])}, "
        f"update {pair(ours['time_ms'])}. Fallbacks: acados {row['fallbacks']}, ours "
        f"{ours['fallbacks']}."
    )


def format_markdown(rows: list[dict]) -> str:
    """The docs' estimation figures (Markdown): accuracy against the paper's Table I (by sensor
    set, then estimator), the blackout, the speed per update, the peers and the real recordings
    (mm, mrad, mm/s, ms). The robust-estimation rows are not shown (:func:`format_table` prints
    them)."""
    of = {kind: [r for r in rows if r["benchmark"] == kind] for kind in
          ("accuracy", "blackout", "speed", "peer", "real")}  # fmt: skip
    lines: list[str] = []
    if of["accuracy"]:
        lines += [
            f"Mean ± std over seeds {_seeds(of['accuracy'][0]['seeds'])}, queried at "
            f"{of['accuracy'][0]['rate_hz']:g} Hz:",
            "",
            "| est | sensors | x mm | y mm | yaw mrad | v_x mm/s | v_y mm/s | ω mrad/s "
            "| paper x / y / yaw / v_x / v_y |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        order = {sensors: k for k, sensors in enumerate(SENSOR_SETS)}
        for row in sorted(of["accuracy"], key=lambda r: (order.get(r["sensors"]), r["estimator"])):
            cells = [
                f"{row['rmse'][s] * 1e3:.{d}f}±{row['rmse_std'][s] * 1e3:.{d}f}"
                for s, d in zip(STATE_NAMES, (1, 1, 1, 1, 1, 0), strict=True)
            ]
            paper = PAPER_TABLE_I.get((row["estimator"], row["sensors"]))
            lines.append(
                f"| {row['estimator'].upper()} | {row['sensors'].upper()} | {' | '.join(cells)} "
                f"| {' / '.join(str(v) for v in paper) if paper else '–'} |"
            )
        lines.append("")
    if of["blackout"]:
        first = of["blackout"][0]
        start, duration = first["blackout_s"]
        ends = ", ".join(
            f"{r['estimator'].upper()} {r['position_error_at_end_m']['mean'] * 1e3:.1f} mm "
            f"(max {r['position_error_at_end_m']['max'] * 1e3:.1f})"
            for r in of["blackout"]
        )
        back = ", ".join(
            f"{r['estimator'].upper()} {r['time_to_recover_s']['mean'] * 1e3:.0f} ms "
            f"(max {r['time_to_recover_s']['max'] * 1e3:.0f})"
            for r in of["blackout"]
        )
        lines += [
            f"**Blackout** (Lighthouse off for {duration:g} s at t = {start:g} s, "
            f"{first['sensors'].upper()}, seeds {_seeds(first['seeds'])}): position error at the "
            f"end of the outage {ends}; back below 3× the estimator's normal error (at least "
            f"3 mm) for 0.5 s: {back} after the outage.",
            "",
        ]
    if of["speed"]:
        lines += [
            "**Speed** (per update including the Python call):",
            "",
            "| | median | p95 | p99 | max | target |",
            "|---|---|---|---|---|---|",
        ]
        for row in of["speed"]:
            what = (
                f"MHE M = {row['horizon']} at {row['rate_hz']:g} Hz"
                if "rate_hz" in row
                else f"{row['estimator'].upper()} per measurement"
            )
            if row.get("online_parameters"):
                what += f", {', '.join(row['online_parameters'])} online"
            t = row["time_ms"]
            cells = " | ".join(f"{format_ms(t[k])} ms" for k in ("median", "p95", "p99", "max"))
            lines.append(f"| {what} | {cells} | {SPEED_TARGETS.get(row['estimator'], '–')} |")
        lines.append("")
    if of["peer"]:
        first = of["peer"][0]
        lines += [
            f"**Peers on the same model, noise settings and data** (seeds "
            f"{_seeds(first['seeds'])}, {first['sensors'].upper()}, {first['rate_hz']:g} Hz; "
            "ratio = peer / ours):",
            "",
            "| peer | vs | median time | time ratio | RMSE ratio x / y / yaw / v_x / v_y |",
            "|---|---|---|---|---|",
        ]
        for row in of["peer"]:
            if "skipped" in row:
                continue
            ratio = row["ratio_to_ours"]
            slower = ratio["time_median"]
            pace = f"{slower:.3g}× slower" if slower >= 1 else f"{1 / slower:.3g}× faster"
            rmse_ratios = " / ".join(f"{ratio['rmse'][s]:.2f}" for s in STATE_NAMES[:5])
            lines.append(
                f"| {PEER_NAMES.get(row['estimator'], row['estimator'])} | our "
                f"{row['compared_with'].upper()} | {format_ms(row['time_ms']['median'])} ms "
                f"| {pace} | {rmse_ratios} |"
            )
        lines.append("")
        for row in of["peer"]:
            if "skipped" in row:
                lines += [f"{PEER_NAMES.get(row['estimator'], row['estimator'])}: skipped "
                          f"({row['skipped']}).", ""]  # fmt: skip
            elif "solve_ms" in row:
                lines += [_solver_split(row), ""]
    if of["real"]:
        lines += [
            "**Real recordings** (reference: the car's own on-line estimate, *not* ground truth):",
            "",
            "| run | est | sensors | x / y mm | yaw mrad | Lighthouse residual median / p95 mrad |",
            "|---|---|---|---|---|---|",
        ]
        for row in of["real"]:
            r, lh = row["rmse_vs_onboard_estimate"], row["lighthouse_residual_rad"]
            lines.append(
                f"| {row['run']} | {row['estimator'].upper()} | {row['sensors'].upper()} | "
                f"{r['x'] * 1e3:.1f} / {r['y'] * 1e3:.1f} | {r['yaw'] * 1e3:.0f} | "
                f"{lh['median'] * 1e3:.2f} / {lh['p95'] * 1e3:.2f} |"
            )
        lines.append("")
    return "\n".join(lines).rstrip("\n")
