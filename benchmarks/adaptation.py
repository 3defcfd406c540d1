"""``crs bench adaptation``: a car that changes while it races, raced with and without online
parameters.

Each schedule of changes (:mod:`sim.drift`: the issue's, one of our own, and ``steady``, a car
that does not change) drives an emulated
car behind a ``typical`` Wi-Fi link (``crs launch car --emulate --link typical --car-drift``),
once with the plain estimator and once with ``Cm1``, ``gyro_bias`` and ``grip`` estimated online
(:data:`ONLINE`), ``repeats`` times each. Per race: laps, lap times, the mean flying lap before
and after the grip changes, the contouring error (the true path's distance from the centreline),
time off the track, motor cut-offs and the estimation RMSE. With online parameters, per
parameter: each estimate against the emulator's truth at its stamp (the truth log's drifted
parameters; ``grip`` is the front tyre peak over its start), judged from :data:`SETTLE_S` after
each change of that parameter ends (and after the start) until its next change begins: the share
of that time within :data:`TOLERANCES`, the share with the truth inside ±2σ, the largest error,
and how far the final value lies from the prior in its own final σ (a car that does not change:
no false drift); the course at 1 Hz for :func:`plot`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from crs_core.analysis.metrics import lap_statistics
from crs_core.estimation.noise import EstimatorNoise
from crs_core.model import CarModel
from crs_core.track import load_demo_track
from sim.closed_loop import off_track
from sim.drift import DriftSchedule, parse_drift

#: Estimates per second kept in a race's course (:func:`plot`).
COURSE_HZ = 1.0

#: The online parameters of the races with them.
ONLINE = ("Cm1", "gyro_bias", "grip")
#: The schedules raced, by name: the issue's, and ours (a battery that sags in two stages while
#: the grip first drops and then partly returns, a gyro bias that creeps in).
SCHEDULES: dict[str, dict[str, Any]] = {
    "issue": {
        "drift": [
            {"parameter": "Cm1", "from_s": 10, "to_s": 100, "factor": 0.8},
            {"parameter": "Df", "at_s": 60, "factor": 0.85},
            {"parameter": "Dr", "at_s": 60, "factor": 0.85},
            {"effect": "gyro_bias", "at_s": 30, "value": 0.05},
        ]
    },
    "own": {
        "drift": [
            {"parameter": "Cm1", "from_s": 20, "to_s": 30, "factor": 0.9},
            {"parameter": "Cm1", "from_s": 70, "to_s": 80, "factor": 0.75},
            {"parameter": "Df", "at_s": 40, "factor": 0.8},
            {"parameter": "Dr", "at_s": 40, "factor": 0.8},
            {"parameter": "Df", "from_s": 80, "to_s": 90, "factor": 0.9},
            {"parameter": "Dr", "from_s": 80, "to_s": 90, "factor": 0.9},
            {"effect": "gyro_bias", "from_s": 15, "to_s": 60, "value": -0.04},
        ]
    },
    "steady": {"drift": []},
}
#: How close an online estimate must be to its truth: relative (``rel``) or absolute.
TOLERANCES = {"Cm1": ("rel", 0.05), "grip": ("rel", 0.10), "gyro_bias": ("abs", 0.01)}
#: Estimates are judged from this long after a change of their parameter ends, s.
SETTLE_S = 10.0
#: The parameters a schedule entry changes, by online parameter.
SOURCES = {"Cm1": ("Cm1",), "gyro_bias": ("gyro_bias",), "grip": ("Df", "Dr")}


def adaptation_benchmark(
    work_dir: Path,
    duration: float = 120.0,
    repeats: int = 3,
    schedules: tuple[str, ...] = ("issue", "own"),
    seed: int = 0,
    tune_noise: bool = True,
) -> dict[str, Any]:
    """Race every schedule with and without online parameters, ``repeats`` times each
    (JSON-ready: the settings, the estimators' noise, then one row per race). With
    ``tune_noise`` the estimators' process noise is first fitted to a steady race of the same
    car (:func:`tuned_params`), as ``crs tune-noise`` fits it to a recording of a real car."""
    from launch_scripts.car_stack import EmulatedLink, run_car_stack
    from launch_scripts.sim_stack import CarTruth, StackOptions

    rows = []
    work_dir.mkdir(parents=True, exist_ok=True)
    params, noise = tuned_params(work_dir, seed) if tune_noise else (None, None)
    for name in schedules:
        path: Path | None = None
        schedule = DriftSchedule(())
        if SCHEDULES[name]["drift"]:
            path = work_dir / f"{name}.yaml"
            path.write_text(yaml.safe_dump(SCHEDULES[name]))
            schedule = parse_drift(SCHEDULES[name])
        for online in (False, True):
            for repeat in range(repeats):
                mode = "online" if online else "plain"
                run = work_dir / f"{name}_{mode}_{repeat + 1}"
                print(f"[bench] {name}, {mode}, repeat {repeat + 1} of {repeats}", flush=True)
                options = StackOptions(
                    "mhe",
                    after_start_up=True,
                    record="estimates",
                    seed=seed + repeat,
                    params_file=params,
                    car=CarTruth(drift_file=path),
                    online_parameters=ONLINE if online else (),
                )
                link = EmulatedLink(both="typical", seed=seed + repeat)
                report = run_car_stack(1, options, duration, run, True, link=link)
                row = race_row(report, run, schedule)
                rows.append({"schedule": name, "online": online, "repeat": repeat + 1, **row})
    return {
        "duration_s": duration,
        "repeats": repeats,
        "link": "typical",
        "online_parameters": list(ONLINE),
        "schedules": {name: SCHEDULES[name] for name in schedules},
        "tolerances": {k: list(v) for k, v in TOLERANCES.items()},
        "settle_s": SETTLE_S,
        "noise": noise,
        "rows": rows,
    }


#: Length of the steady race the estimators' noise is fitted to, s.
TUNING_S = 60.0


def tuned_params(work_dir: Path, seed: int) -> tuple[Path, dict[str, Any]]:
    """Race the car that does not change for :data:`TUNING_S` behind the same link (plain
    estimator, every sensor recorded; seed ``seed + 100``, no race's), fit the pose's process
    noise to the recording (:func:`~crs_core.estimation.noise_fit.fit_process_noise`) and write
    it into ``work_dir/tuning/params.yaml``; that file and the fit (JSON-ready)."""
    from crs_core.estimation.noise import with_noise
    from crs_core.estimation.noise_fit import fit_process_noise
    from crs_core.estimation.offline import dataset_model
    from launch_scripts.car_stack import EmulatedLink, run_car_stack
    from launch_scripts.sim_stack import StackOptions
    from ros4crs.bag_dataset import dataset_from_bag

    folder = work_dir / "tuning"
    print(f"[bench] a steady {TUNING_S:g} s race to fit the estimators' noise to", flush=True)
    options = StackOptions("mhe", after_start_up=True, record="all", seed=seed + 100)
    link = EmulatedLink(both="typical", seed=seed + 100)
    run_car_stack(1, options, TUNING_S, folder / "race", True, link=link)
    dataset = dataset_from_bag(folder / "race" / "bag", "car1", reference="none")
    fit = fit_process_noise(
        dataset, dataset_model(dataset), progress=lambda line: print(f"[bench] {line}", flush=True)
    )
    path = folder / "params.yaml"
    document = with_noise({"parameters": {}}, fit.noise, ["process_std"])
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    return path, fit.to_dict()


def race_row(report: dict[str, Any], run: Path, schedule: DriftSchedule) -> dict[str, Any]:
    """One race's figures (see the module docstring)."""
    from ros4crs.bag_replay import read_car

    car = report["cars"]["car1"]
    track = load_demo_track()
    with np.load(run / "truth_car1.npz") as log:
        truth = {key: log[key] for key in log.files}
    origin = float(truth["command_read_t"][0])  # the drift's: the first command the car read
    laps = lap_statistics(truth["t"] - origin, truth["x"], track)  # times since the origin
    grip_at = _grip_change(schedule)
    flying = _flying_laps(laps)
    row: dict[str, Any] = {
        "folder": str(run),
        "laps": car["laps_completed"],
        "lap_times_s": car["lap_times_s"],
        "mean_flying_lap_s": _mean([lap for _, lap in flying]),
        "mean_flying_lap_after_grip_change_s": _mean(
            [lap for start, lap in flying if grip_at is not None and start >= grip_at]
        ),
        "contouring_rms_m": laps["rms_lateral_error_m"],
        "contouring_max_m": laps["max_lateral_error_m"],
        "off_track": off_track(truth["t"], truth["x"], track),
        "motor_cutoffs": int(truth["pause_t"].size),
        "estimation_rmse": car.get("estimation_rmse"),
        "node_deaths": report.get("node_deaths", []),
    }
    contents = read_car(run / "bag", "/car1")
    if contents.online_parameters:
        row["parameters"] = parameter_figures(contents.online_parameters, truth, origin, schedule)
    return row


def parameter_figures(
    estimates: list[tuple[float, dict[str, Any]]],
    truth: dict[str, np.ndarray],
    origin: float,
    schedule: DriftSchedule,
) -> dict[str, Any]:
    """Per online parameter: its estimates against the truth where they are judged."""
    stamps = np.array([stamp for stamp, _ in estimates])
    since = stamps - origin
    out: dict[str, Any] = {}
    for name in ONLINE:
        have = [k for k, (_, values) in enumerate(estimates) if name in values]
        if not have:
            continue
        value = np.array([estimates[k][1][name].value for k in have])
        std = np.array([estimates[k][1][name].std for k in have])
        actual = _truth_of(name, truth, stamps[have])
        judged = _judged(name, since[have], schedule, float(since[-1]))
        prior = float(value[0])  # each parameter's first estimate is its prior
        kind, tolerance = TOLERANCES[name]
        error = np.abs(value - actual)
        allowed = tolerance * np.abs(actual) if kind == "rel" else np.full(actual.size, tolerance)
        figures: dict[str, Any] = {"judged_s": round(float(np.sum(judged)) / 60.0, 1)}
        if judged.any():
            figures |= {
                "within_tolerance": round(float(np.mean(error[judged] <= allowed[judged])), 3),
                "inside_2sigma": round(float(np.mean(error[judged] <= 2 * std[judged])), 3),
                "max_error": round(float(np.max(error[judged])), 4),
                "final": {
                    "value": round(float(value[-1]), 4),
                    "truth": round(float(actual[-1]), 4),
                    "std": round(float(std[-1]), 5),
                    "from_prior_sigmas": round(abs(float(value[-1]) - prior) / float(std[-1]), 2),
                },
            }
        keep = _every(since[have], 1.0 / COURSE_HZ)
        figures["course"] = {
            "t_s": [round(float(t), 2) for t in since[have][keep]],
            **{
                key: [round(float(v), 5) for v in series[keep]]
                for key, series in (("value", value), ("std", std), ("truth", actual))
            },
        }
        out[name] = figures
    return out


def _every(t: np.ndarray, period: float) -> np.ndarray:
    """Indices of the first sample of ``t`` in each ``period`` (s)."""
    _, first = np.unique(np.floor(t / period), return_index=True)
    return first


def plot(result: dict[str, Any], path: Path) -> None:
    """Each online parameter (rows) on each schedule (columns): the first race's estimate with
    its ±2σ band against the truth."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names, schedules = result["online_parameters"], list(result["schedules"])
    figure, axes = plt.subplots(
        len(names), len(schedules), figsize=(4.2 * len(schedules), 2.4 * len(names)),
        sharex=True, squeeze=False,
    )  # fmt: skip
    for column, schedule in enumerate(schedules):
        race = next(
            (r for r in result["rows"] if r["schedule"] == schedule and r.get("parameters")), None
        )
        for row, name in enumerate(names):
            ax = axes[row, column]
            course = (race or {}).get("parameters", {}).get(name, {}).get("course")
            if course:
                t, value, std = (np.array(course[k]) for k in ("t_s", "value", "std"))
                ax.fill_between(t, value - 2 * std, value + 2 * std, alpha=0.25, label="±2σ")
                ax.plot(t, value, lw=1.2, label="online estimate")
                ax.plot(t, course["truth"], "k--", lw=1.0, label="truth")
            ax.grid(alpha=0.3)
            if column == 0:
                ax.set_ylabel(name)
            if row == 0:
                ax.set_title(f"schedule {schedule}")
            if row == len(names) - 1:
                ax.set_xlabel("s since the first command")
    axes[0, 0].legend(fontsize=7, loc="best")
    figure.suptitle("crs bench adaptation: online parameters against the emulated car's truth")
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def _truth_of(name: str, truth: dict[str, np.ndarray], stamps: np.ndarray) -> np.ndarray:
    """The truth of online parameter ``name`` at ``stamps`` (the truth log's drifted values;
    a parameter the schedule leaves alone: the car's own value)."""
    t = truth["t"]
    if name == "grip":
        key = "drift_Df"
        if key not in truth:
            return np.ones(stamps.size)
        return np.interp(stamps, t, truth[key] / truth[key][0])
    key = f"drift_{name}"
    if key in truth:
        return np.interp(stamps, t, truth[key])
    default = 0.0 if name == "gyro_bias" else CarModel().parameters.value(name)
    return np.full(stamps.size, default)


def _judged(name: str, since: np.ndarray, schedule: DriftSchedule, end: float) -> np.ndarray:
    """Where online parameter ``name``'s estimates are judged: from :data:`SETTLE_S` after the
    start and after each of its changes ends, until its next change begins."""
    changes = sorted((c.start_s, c.end_s) for c in schedule.changes if c.parameter in SOURCES[name])
    windows, start = [], SETTLE_S
    for begin, finish in changes:
        if begin > start:
            windows.append((start, begin))
        start = max(start, finish + SETTLE_S)
    windows.append((start, end))
    return np.any([(since >= a) & (since < b) for a, b in windows], axis=0)


def _grip_change(schedule: DriftSchedule) -> float | None:
    """When the schedule first changes the tyres, s since the first command (None: never)."""
    starts = [c.start_s for c in schedule.changes if c.parameter in SOURCES["grip"]]
    return min(starts) if starts else None


def _flying_laps(stats: dict[str, Any]) -> list[tuple[float, float]]:
    """(start, time) of each flying lap in :func:`~crs_core.analysis.metrics.lap_statistics`'s
    ``stats`` (s, on the clock it was given)."""
    starts, times = stats["crossings_s"], stats["lap_times_s"]
    return [(float(start), float(lap)) for start, lap in zip(starts[1:], times[1:], strict=False)]


def _mean(values: list[float]) -> float | None:
    return round(float(np.mean(values)), 3) if values else None


def format_markdown(result: dict[str, Any]) -> str:
    """Per schedule, the races without and with online parameters (ranges over the repeats),
    then the online parameters' figures."""
    rows = result["rows"]
    noise = result.get("noise")
    tuning = (
        "the estimators' process noise fitted to a steady race of the car (x, y, yaw: "
        f"{noise['process_std'][0]:.4g}; default {EstimatorNoise().process_std[0]:g})"
        if noise
        else "the estimators' default noise"
    )
    lines = [
        f"{result['repeats']} repeat(s) of {result['duration_s']:g} s per schedule and mode, "
        f"emulated car behind a `{result['link']}` link, MHE; online: "
        f"{', '.join(result['online_parameters'])}; {tuning}.",
        "",
        "| schedule | online | laps | flying lap | after the grip change | contouring RMS / max "
        "| off track | cut-offs | RMSE x / y |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name in result["schedules"]:
        for online in (False, True):
            group = [r for r in rows if r["schedule"] == name and r["online"] == online]
            if not group:
                continue
            lines.append(f"| {name} | {'yes' if online else 'no'} | {_race_cells(group)} |")
    lines += [
        "",
        f"Online parameters, judged from {result['settle_s']:g} s after each change ends "
        "(share of that time within the tolerance / with the truth inside ±2σ; largest error):",
        "",
        "| schedule | parameter | tolerance | within | inside ±2σ | largest error | final from"
        " the prior |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in result["schedules"]:
        group = [r for r in rows if r["schedule"] == name and r.get("parameters")]
        for parameter in result["online_parameters"]:
            figures = [
                r["parameters"][parameter]
                for r in group
                if "within_tolerance" in r["parameters"].get(parameter, {})
            ]
            if not figures:
                continue
            kind, tolerance = result["tolerances"][parameter]
            allowed = f"{100 * tolerance:g} %" if kind == "rel" else f"{tolerance:g}"
            lines.append(
                f"| {name} | {parameter} | {allowed} "
                f"| {_span([100 * f['within_tolerance'] for f in figures], '{:.0f} %')} "
                f"| {_span([100 * f['inside_2sigma'] for f in figures], '{:.0f} %')} "
                f"| {_span([f['max_error'] for f in figures], '{:.3g}')} "
                f"| {_span([f['final'].get('from_prior_sigmas') for f in figures], '{:.1f} σ')} |"
            )
    return "\n".join(lines)


def _race_cells(group: list[dict[str, Any]]) -> str:
    """The race columns of the table over ``group``'s repeats."""

    def span(key: str, form: str, scale: float = 1.0) -> str:
        return _span([None if r[key] is None else scale * r[key] for r in group], form)

    rmse = [r["estimation_rmse"] or {} for r in group]
    return " | ".join(
        [
            span("laps", "{:.0f}"),
            span("mean_flying_lap_s", "{:.2f} s"),
            span("mean_flying_lap_after_grip_change_s", "{:.2f} s"),
            f"{span('contouring_rms_m', '{:.0f}', 1e3)} / "
            f"{span('contouring_max_m', '{:.0f} mm', 1e3)}",
            _span([r["off_track"]["seconds"] for r in group], "{:.2f} s"),
            span("motor_cutoffs", "{:.0f}"),
            f"{_span([1e3 * e['x'] for e in rmse if 'x' in e], '{:.1f}')} / "
            f"{_span([1e3 * e['y'] for e in rmse if 'y' in e], '{:.1f} mm')}",
        ]
    )


def _span(values: list[float | None], form: str) -> str:
    """``low–high`` of the values (one when they agree; ``–`` without any)."""
    known = [v for v in values if v is not None and np.isfinite(v)]
    if not known:
        return "–"
    low, high = form.format(min(known)), form.format(max(known))
    return low if low == high else f"{form.format(min(known)).split(' ')[0]}–{high}"
