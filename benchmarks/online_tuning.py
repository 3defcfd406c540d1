"""``crs bench online-tuning``: how sharply the online gyro bias can be known, against what the
same tuning does to the real recordings.

The gyro's bias is told from the yaw rate through the heading: the Lighthouse's yaw and the
heading of the path its positions draw. How far the estimators let the pose move off what the
velocities integrate to is the process noise of ``x, y, yaw`` (``noise.process_std[:3]``; the
velocities' is left as it is); how hard the wheel speeds pull the velocities, their noise
(``noise.wheel_std``); how fast an online parameter may move, its relaxation time. One
race of the adaptation bench (:mod:`benchmarks.adaptation`: the issue's schedule, an emulated
car behind a ``typical`` link, ``Cm1``, ``gyro_bias`` and ``grip`` online) is recorded with
every sensor, then estimated again offline with each of :data:`VARIANTS` and judged as that
bench judges (each parameter against the emulator's truth, from 10 s after its changes end),
with the estimation RMSE against the truth. The two real recordings are estimated with the
same noises (MHE, the sensors as recorded): the Lighthouse residual (recorded minus
predicted sweep angle) and the distance from the car's own on-line estimate say whether the
real car's pose follows the tighter kinematics.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import yaml

from benchmarks.adaptation import ONLINE, SCHEDULES, parameter_figures, race_row
from benchmarks.machine import REAL_DATA
from benchmarks.online_real import RUNS
from crs_core.estimation.noise import EstimatorNoise
from crs_core.model.online import DEFAULT_REVERSION_S


class Variant(NamedTuple):
    """One setting of the estimators' tuning (see :data:`VARIANTS`)."""

    pose_std: tuple[float, float, float]
    wheel_std: float
    reversion_s: float


_ASSUMED = EstimatorNoise()
#: The estimators' own tuning.
DEFAULT = Variant(
    (_ASSUMED.process_std[0], _ASSUMED.process_std[1], _ASSUMED.process_std[2]),
    float(np.atleast_1d(_ASSUMED.wheel_std)[0]),  # one value for every wheel
    DEFAULT_REVERSION_S,
)
#: The variants tried, by name: the process noise of ``x, y, yaw`` (``noise.process_std[:3]``;
#: m/sqrt(s), m/sqrt(s), rad/sqrt(s)), the wheel speeds' noise (``noise.wheel_std``, rad/s)
#: and the online parameters' relaxation time ``online_reversion_s`` (s; an effect's is four
#: times it). The first is the default.
VARIANTS: dict[str, Variant] = {
    "default": DEFAULT,
    "x, y tighter": DEFAULT._replace(pose_std=(0.005, 0.005, DEFAULT.pose_std[2])),
    "yaw tighter": DEFAULT._replace(pose_std=(*DEFAULT.pose_std[:2], 0.005)),
    "pose 0.01": DEFAULT._replace(pose_std=(0.01, 0.01, 0.01)),
    "pose 0.005": DEFAULT._replace(pose_std=(0.005, 0.005, 0.005)),
    "pose 0.002": DEFAULT._replace(pose_std=(0.002, 0.002, 0.002)),
    "pose 0.005, wheels 10": DEFAULT._replace(pose_std=(0.005, 0.005, 0.005), wheel_std=10.0),
    "pose 0.005, wheels 25": DEFAULT._replace(pose_std=(0.005, 0.005, 0.005), wheel_std=25.0),
    "slower walk": DEFAULT._replace(reversion_s=4 * DEFAULT_REVERSION_S),
}
#: The schedule raced.
SCHEDULE = "issue"
#: Offline estimates every this many of the recording's samples (~10 Hz).
EVERY = 6


def online_tuning_benchmark(
    work_dir: Path,
    duration: float = 120.0,
    seed: int = 0,
    variants: dict[str, Variant] = VARIANTS,
    fit_noise: bool = True,
) -> dict[str, Any]:
    """Record one race, then estimate it with each of ``variants``, and the real recordings
    with each of their noises (JSON-ready). With ``fit_noise`` a variant ``fitted`` follows
    the default: the pose's process noise ``crs tune-noise`` fits to a steady race of the same
    car (:func:`benchmarks.adaptation.tuned_params`)."""
    from benchmarks.adaptation import tuned_params
    from launch_scripts.car_stack import EmulatedLink, run_car_stack
    from launch_scripts.sim_stack import CarTruth, StackOptions
    from sim.drift import parse_drift

    work_dir.mkdir(parents=True, exist_ok=True)
    if fit_noise:
        fitted = tuned_params(work_dir, seed)[1]["process_std"]
        first, *rest = variants.items()
        pose = (float(fitted[0]), float(fitted[1]), float(fitted[2]))
        variants = dict([first, ("fitted", first[1]._replace(pose_std=pose)), *rest])
    drift = work_dir / f"{SCHEDULE}.yaml"
    drift.write_text(yaml.safe_dump(SCHEDULES[SCHEDULE]))
    schedule = parse_drift(SCHEDULES[SCHEDULE])
    run = work_dir / "race"
    print(f"[bench] racing {duration:g} s on the {SCHEDULE} schedule, every sensor recorded")
    options = StackOptions(
        "mhe",
        after_start_up=True,
        record="all",
        seed=seed,
        car=CarTruth(drift_file=drift),
        online_parameters=ONLINE,
    )
    link = EmulatedLink(both="typical", seed=seed)
    report = run_car_stack(1, options, duration, run, True, link=link)
    race = race_row(report, run, schedule)
    rows, real = [], {}
    for k, (name, variant) in enumerate(variants.items(), 1):
        print(f"[bench] variant {k} of {len(variants)}: {name}", flush=True)
        noise = (variant.pose_std, variant.wheel_std)
        if noise not in real:  # the real runs carry no online parameters
            real[noise] = real_figures(variant)
        rows.append(
            {
                "variant": name,
                "pose_process_std": list(variant.pose_std),
                "wheel_std": variant.wheel_std,
                "online_reversion_s": variant.reversion_s,
                "race": offline_figures(run, variant, schedule),
                "real": real[noise],
            }
        )
    return {
        "schedule": SCHEDULE,
        "duration_s": duration,
        "online_parameters": list(ONLINE),
        "race": {key: race[key] for key in ("laps", "estimation_rmse")}
        | {"parameters": _without_course(race.get("parameters", {}))},
        "rows": rows,
    }


def variant_noise(variant: Variant) -> EstimatorNoise:
    """The estimators' noise with the process noise of ``x, y, yaw`` and the wheel speeds'
    noise of ``variant``."""
    return replace(
        _ASSUMED,
        process_std=(*variant.pose_std, *_ASSUMED.process_std[3:]),
        wheel_std=variant.wheel_std,
    )


def offline_figures(run: Path, variant: Variant, schedule: Any) -> dict[str, Any]:
    """The recorded race estimated offline (MHE, :data:`ONLINE` online) with ``variant``'s
    tuning: each online parameter judged as the adaptation bench does, and the RMSE of x, y
    (mm) and yaw (mrad) against the emulator's truth from 10 s on."""
    from crs_core.analysis.metrics import interpolate_states, state_rmse
    from crs_core.estimation import MheSettings
    from crs_core.estimation.base import OnlineValue
    from crs_core.estimation.offline import estimate_dataset
    from ros4crs.bag_dataset import dataset_from_bag

    dataset = dataset_from_bag(run / "bag", "car1", reference="none")
    settings = MheSettings(
        noise=variant_noise(variant),
        online_parameters=ONLINE,
        online_reversion_s=variant.reversion_s,
    )
    result = estimate_dataset(dataset, "mhe", settings=settings, at=dataset.t[::EVERY])
    with np.load(run / "truth_car1.npz") as log:
        truth = {key: log[key] for key in log.files}
    origin = float(truth["command_read_t"][0])
    online = result.online
    estimates = [
        (
            float(t),
            {
                name: OnlineValue(
                    float(online.value[i, k]), float(online.std[i, k]), bool(online.informed[i, k])
                )
                for i, name in enumerate(online.names)
            },
        )
        for k, t in enumerate(result.t)
        if result.status[k] != "lost"  # none while lost, as the estimator node publishes
    ]
    figures = _without_course(parameter_figures(estimates, truth, origin, schedule))
    reference = interpolate_states(result.t, truth["t"], truth["x"])
    rmse = state_rmse(result.x.T, reference, result.t - origin >= 10.0)
    assert rmse is not None
    return {
        "parameters": figures,
        "rmse": {
            "x_mm": round(1e3 * rmse["x"], 2),
            "y_mm": round(1e3 * rmse["y"], 2),
            "yaw_mrad": round(1e3 * rmse["yaw"], 2),
        },
    }


def real_figures(variant: Variant) -> dict[str, Any]:
    """The two real recordings estimated (MHE) with ``variant``'s noise: per run, the
    Lighthouse residual (median, p95; rad) and the distance from the on-board estimate (RMSE
    of x and y, mm)."""
    from benchmarks.estimation import real_rows

    rows = real_rows(
        [REAL_DATA / run for run in RUNS], noise=variant_noise(variant), kinds=("mhe",)
    )
    return {
        row["run"]: {
            "lighthouse_residual_rad": {
                key: round(value, 6) for key, value in row["lighthouse_residual_rad"].items()
            },
            "from_onboard_mm": {
                axis: round(1e3 * row["rmse_vs_onboard_estimate"][axis], 2) for axis in ("x", "y")
            },
        }
        for row in rows
    }


def _without_course(parameters: dict[str, Any]) -> dict[str, Any]:
    return {
        name: {key: value for key, value in figures.items() if key != "course"}
        for name, figures in parameters.items()
    }


def format_markdown(result: dict[str, Any]) -> str:
    """One row per variant: each online parameter's share within tolerance and
    inside ±2σ with its final σ, the race's RMSE, and both real runs' Lighthouse residual and
    distance from the on-board estimate."""
    names = result["online_parameters"]
    runs = list(result["rows"][0]["real"]) if result["rows"] else []
    head = ["variant", "x, y, yaw process noise", "wheels", "T"]
    head += [f"{name}: within / ±2σ / final σ" for name in names]
    head += ["race RMSE x / y / yaw"]
    head += [f"{run}: LH residual median / p95, from on-board x / y" for run in runs]
    lines = [
        f"One {result['duration_s']:g} s race on the `{result['schedule']}` schedule, "
        f"{', '.join(names)} online, estimated again offline with each variant (the process "
        "noise of the pose, the wheel speeds' noise, the online parameters' relaxation time T: "
        "an effect's is 4 T); the two real recordings with the same noise (MHE). The first row "
        "is the default.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    for row in result["rows"]:
        cells = [
            row["variant"],
            " / ".join(f"{v:g}" for v in row["pose_process_std"]),
            f"{row['wheel_std']:g} rad/s",
            f"{row['online_reversion_s']:g} s",
        ]
        for name in names:
            p = row["race"]["parameters"].get(name)
            cells.append(
                f"{100 * p['within_tolerance']:.0f} / {100 * p['inside_2sigma']:.0f} % / "
                f"{p['final']['std']:.3g}"
                if p and "final" in p
                else "–"
            )
        r = row["race"]["rmse"]
        cells.append(f"{r['x_mm']:.2f} / {r['y_mm']:.2f} mm / {r['yaw_mrad']:.1f} mrad")
        for run in runs:
            real = row["real"][run]
            lh, off = real["lighthouse_residual_rad"], real["from_onboard_mm"]
            cells.append(
                f"{1e3 * lh['median']:.2f} / {1e3 * lh['p95']:.1f} mrad, "
                f"{off['x']:.1f} / {off['y']:.1f} mm"
            )
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
