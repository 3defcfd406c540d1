"""``crs bench workflow``: a researcher's day on an emulated car that is not the model (issue 27).

The emulated car (``crs car-emulator``, its truth its own: :data:`TRUTH_FACTORS` on the default
parameters and the hidden effect :data:`HIDDEN_EFFECT`) is

1. raced by the stack with the default model and recorded
   (``crs launch car --emulate --car-params truth.yaml --car-effect ...``);
2. identified from that bag (``crs sysid BAG``: the FIE from the default parameters);
3. searched for what the model misses (``crs discrepancy BAG``: every registry effect tested on
   the last part of the recording), which writes the final model's ``params.yaml``;
4. raced again by the stack with that model (``crs launch car --emulate --params
   discrepancy/params.yaml``, the same car).

Every step is the command of the docs, run as a user runs it (a process of its own), and
timed. Per race: laps, the mean flying lap, the contouring error (RMS and largest distance of
the emulator's true path from the centreline, the MPCC's contouring reference) and the
estimation RMSE against the emulator's truth. The open-loop 2 s prediction error (the paper's
metric) of the default and of the final model are measured on the same held-out data, the
second race's recording (not used to identify), against the emulator's truth. The parameters
identified are compared with the truth (relative error); the effect named with the hidden one.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from crs_core.analysis.metrics import interpolate_states, lap_statistics
from crs_core.dataset import Dataset
from crs_core.identification.models import identification_model
from crs_core.identification.problem import DEFAULT_FIT
from crs_core.identification.validation import validate
from crs_core.model import CarModel
from crs_core.model.bicycle import cornering_stiffness, grip_used, peak_slip
from crs_core.model.effects import effect_text, parse_effect
from crs_core.track import load_demo_track
from crs_core.yaml_io import load_yaml
from ros4crs.bag_dataset import dataset_from_bag

#: The emulated car's parameters: the defaults times these (tyres and motor off by 10-20 %).
TRUTH_FACTORS = {"Df": 0.85, "Dr": 0.88, "Br": 1.15, "Cm1": 0.87, "Cd2": 1.2}
#: The emulated car's hidden effect (a gyro bias, rad/s), as ``--car-effect`` reads it.
HIDDEN_EFFECT = "gyro_bias=0.15"
#: The open-loop horizon of the prediction error, s (the paper's).
HORIZON_S = 2.0
#: Identified within this relative error of the truth counts as recovered.
RECOVERED_WITHIN = 0.10
#: Grip used is taken above this forward speed, m/s (slip angles are defined at speed).
GRIP_SPEED = 0.5
#: The axles, as the figures name them, and their parameters' suffix (``Df``, ``Dr``).
AXLES = {"front": "f", "rear": "r"}
#: The two races of the day: the figures' name and the run folder.
RACES = {"default_model": "race_before", "identified_model": "race_after"}


def truth_parameters() -> dict[str, float]:
    """The emulated car's parameters that differ from the defaults."""
    defaults = CarModel().parameters
    return {name: defaults.value(name) * factor for name, factor in TRUTH_FACTORS.items()}


def run_crs(argv: list[str]) -> float:
    """``crs ARGV`` as a user runs it (a process of its own; its output passes through); the
    seconds it took. A failed command raises."""
    started = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "launch_scripts.cli", *argv], check=False)
    if done.returncode != 0:
        raise RuntimeError(f"crs {' '.join(argv)} exited with {done.returncode}")
    return time.perf_counter() - started


def load_race(run: Path) -> tuple[Dataset, dict[str, np.ndarray]]:
    """A ``crs launch car --emulate`` run folder's recording (its bag, no reference states)
    and the emulator's truth (``t``, s, and ``x``, the states)."""
    truth = np.load(run / "truth_car1.npz")
    return dataset_from_bag(run / "bag", reference="none"), {k: truth[k] for k in ("t", "x")}


def race_figures(
    run: Path, car: CarModel, recording: Dataset, truth: dict[str, np.ndarray]
) -> dict[str, Any]:
    """Laps, flying lap, contouring error, estimation RMSE and the grip each axle used (99th
    percentile and largest :func:`~crs_core.model.bicycle.grip_used` of the emulated ``car``'s
    true states at speed, with the recorded commands held) of a ``crs launch car --emulate``
    run folder, its recording and truth (:func:`load_race`)."""
    report = json.loads((run / "report.json").read_text())["cars"]["car1"]
    laps = lap_statistics(truth["t"], truth["x"], load_demo_track())
    flying = report["lap_times_s"][1:]
    held = np.clip(np.searchsorted(recording.t, truth["t"], side="right") - 1, 0, None)
    moving = truth["x"][:, 3] > GRIP_SPEED
    used = grip_used(truth["x"][moving], recording.u[held[moving]], car.parameters.value)
    return {
        "laps": report["laps_completed"],
        "lap_times_s": report["lap_times_s"],
        "mean_flying_lap_s": round(float(np.mean(flying)), 3) if flying else None,
        "contouring_rms_m": laps["rms_lateral_error_m"],
        "contouring_max_m": laps["max_lateral_error_m"],
        "estimation_rmse": report["estimation_rmse"],
        "motor_cutoffs": report.get("motor_cutoffs"),
        "grip_used": {
            axle: {
                "p99": round(float(np.percentile(column, 99)), 3),
                "max": round(float(column.max()), 3),
            }
            for axle, column in zip(AXLES, used.T, strict=True)
        },
    }


def held_out(recording: Dataset, truth: dict[str, np.ndarray]) -> Dataset:
    """A race's recording, where the emulator's truth covers it, with that truth as its
    reference states (:func:`load_race`)."""
    dataset, t = recording, truth["t"]
    keep = (dataset.t >= t[0]) & (dataset.t <= t[-1])
    dataset = dataset.samples(int(np.argmax(keep)), int(len(keep) - np.argmax(keep[::-1])))
    states = interpolate_states(dataset.t, t, truth["x"])
    meta = {**dataset.meta, "reference": "the emulator's truth"}
    return replace(dataset, x=states, meta=meta)


def prediction_error(dataset: Dataset, params: Path | None) -> dict[str, float]:
    """The open-loop position RMSE over :data:`HORIZON_S` (and at its end) of the model in
    ``params`` (None: the defaults) on ``dataset``, m."""
    model = identification_model(dataset, (), params)
    summary, _ = validate(dataset, model, model.parameters, horizon_s=HORIZON_S)
    return {
        "position_rmse_m": round(summary["position_rmse_m"]["identified"], 4),
        "position_rmse_at_horizon_m": round(summary["position_rmse_at_horizon_m"]["identified"], 4),
    }


def parameter_recovery(params: Path) -> dict[str, Any]:
    """Per fitted parameter of :data:`DEFAULT_FIT`: truth, identified, its one-sigma (the
    ``prior_std`` the identification writes), the relative error and the error in sigmas; the
    worst relative error of the parameters that differ from the defaults, whether all of them
    are within :data:`RECOVERED_WITHIN` and whether all are within two sigmas."""
    identified = load_yaml(params.read_text())["parameters"]
    defaults = CarModel().parameters
    changed = truth_parameters()
    rows = {}
    for name in DEFAULT_FIT:
        truth = changed.get(name, defaults.value(name))
        given = identified[name]
        entry = given if isinstance(given, dict) else {"value": given}
        value, std = float(entry["value"]), entry.get("prior_std")
        rows[name] = {
            "truth": truth,
            "identified": round(value, 6),
            "std": None if std is None else round(float(std), 6),
            "error": round(value / truth - 1.0, 4),
            "sigmas": None if not std else round((value - truth) / float(std), 2),
            "changed": name in changed,
        }
    worst = max(abs(rows[name]["error"]) for name in changed)
    sigmas = [rows[name]["sigmas"] for name in changed]
    return {
        "parameters": rows,
        "worst_changed_error": worst,
        "recovered": worst <= RECOVERED_WITHIN,
        "within_two_sigmas": all(s is not None and abs(s) <= 2.0 for s in sigmas),
    }


def workflow_benchmark(work: Path, duration: float = 40.0, seed: int = 0, domain: int = 57) -> dict:
    """Run the day in ``work`` (a new folder); JSON-ready figures."""
    work.mkdir(parents=True, exist_ok=True)
    truth_file = work / "truth.yaml"
    truth_file.write_text(yaml.safe_dump({"parameters": truth_parameters()}))
    effect = effect_text(parse_effect(HIDDEN_EFFECT))
    car = ["--car-params", str(truth_file), "--car-effect", effect]
    race = ["launch", "car", "--emulate", "--duration", str(duration), "--seed", str(seed)]
    race += ["--domain", str(domain), *car]
    steps: dict[str, float] = {}
    before, after = (work / RACES[name] for name in ("default_model", "identified_model"))
    steps["race_default_model_s"] = run_crs([*race, "--out", str(before)])
    bag = before / "bag"
    steps["sysid_s"] = run_crs(["sysid", str(bag), "--out", str(work / "sysid")])
    steps["discrepancy_s"] = run_crs(["discrepancy", str(bag), "--out", str(work / "discrepancy")])
    final = work / "discrepancy" / "params.yaml"
    steps["race_identified_model_s"] = run_crs([*race, "--params", str(final), "--out", str(after)])
    return summarise(work, duration, seed, steps)


def summarise(work: Path, duration: float, seed: int, steps: dict[str, float]) -> dict[str, Any]:
    """The figures of a day run in ``work`` (its races, sysid and discrepancy folders)."""
    final = work / "discrepancy" / "params.yaml"
    found = json.loads((work / "discrepancy" / "report.json").read_text())
    car = CarModel.from_file(work / "truth.yaml")
    races = {name: load_race(work / folder) for name, folder in RACES.items()}
    data = held_out(*races["identified_model"])
    return {
        "truth": {"factors": TRUTH_FACTORS, "effect": HIDDEN_EFFECT},
        "duration_s": duration,
        "seed": seed,
        "steps_s": {k: round(v, 1) for k, v in steps.items()},
        "races": {
            name: race_figures(work / folder, car, *races[name]) for name, folder in RACES.items()
        },
        "peak_slip_rad": {
            axle: round(peak_slip(*(car.parameters.value(f"{p}{a}") for p in "CB")), 3)
            for axle, a in AXLES.items()
        },
        "prediction_error": {
            "held_out": "the second race's recording against the emulator's truth",
            "horizon_s": HORIZON_S,
            "default_model": prediction_error(data, None),
            "identified_model": prediction_error(data, final),
        },
        "sysid": parameter_recovery(work / "sysid" / "params.yaml"),
        "discrepancy": {
            "named": found.get("effects", []),
            "hidden": parse_effect(HIDDEN_EFFECT)[0],
            "parameters": parameter_recovery(final),
            "gap_before_m": found.get("gap_before"),
            "gap_after_m": found.get("gap_after"),
        },
    }


def format_table(result: dict[str, Any]) -> str:
    """The figures as Markdown: the races and prediction error before and after, the steps."""
    before, after = result["races"]["default_model"], result["races"]["identified_model"]
    errors = result["prediction_error"]
    lines = [
        "| | default model | identified model |",
        "|---|---|---|",
        f"| laps in {result['duration_s']:g} s | {before['laps']} | {after['laps']} |",
        f"| mean flying lap | {before['mean_flying_lap_s']} s | {after['mean_flying_lap_s']} s |",
        f"| contouring error RMS / max | {1e3 * before['contouring_rms_m']:.0f} / "
        f"{1e3 * before['contouring_max_m']:.0f} mm | {1e3 * after['contouring_rms_m']:.0f} / "
        f"{1e3 * after['contouring_max_m']:.0f} mm |",
        f"| estimation RMSE x / y / yaw | {_rmse(before)} | {_rmse(after)} |",
        f"| open-loop {errors['horizon_s']:g} s position RMSE (held out) | "
        f"{errors['default_model']['position_rmse_m']:.3f} m | "
        f"{errors['identified_model']['position_rmse_m']:.3f} m |",
    ]
    sysid, found = result["sysid"], result["discrepancy"]
    changed = [n for n, row in sysid["parameters"].items() if row["changed"]]
    lines += [
        "",
        f"Effect named: {', '.join(found['named']) or 'none'} (hidden: {found['hidden']}; "
        f"gap on its held-out part {found['gap_before_m']:.3f} -> {found['gap_after_m']:.3f} m).",
        f"The changed parameters against the truth (error, and in the fit's σ): crs sysid "
        f"(no effect) {_recovery(sysid, changed)}; crs discrepancy's final model "
        f"{_recovery(found['parameters'], changed)}. Cornering stiffness D·C·B, front / rear: "
        f"crs sysid {_stiffness(sysid)}, the final model {_stiffness(found['parameters'])}.",
        f"Grip the first race used, |F_y| / D (99th percentile / most): front "
        f"{_grip(before, 'front')}, rear {_grip(before, 'rear')}; the tyre curves peak at "
        f"{result['peak_slip_rad']['front']:.2f} / {result['peak_slip_rad']['rear']:.2f} rad "
        "of slip.",
        "Steps: "
        + ", ".join(f"{k[:-2].replace('_', ' ')} {v:.0f} s" for k, v in result["steps_s"].items()),
    ]
    return "\n".join(lines)


def stiffness_errors(recovery: dict[str, Any]) -> dict[str, float]:
    """Relative error of each axle's cornering stiffness ``D C B``
    (:func:`~crs_core.model.bicycle.cornering_stiffness`), identified against the truth, from a
    :func:`parameter_recovery`'s rows: ``{"front": ..., "rear": ...}``."""
    rows = recovery["parameters"]

    def stiffness(axle: str, which: str) -> float:
        return cornering_stiffness(*(rows[f"{p}{axle}"][which] for p in "DCB"))

    return {
        name: round(stiffness(axle, "identified") / stiffness(axle, "truth") - 1.0, 4)
        for name, axle in AXLES.items()
    }


def _recovery(recovery: dict[str, Any], names: list[str]) -> str:
    rows = recovery["parameters"]
    return ", ".join(
        f"{n} {100 * rows[n]['error']:+.1f} %"
        + (f" ({rows[n]['sigmas']:+.1f} σ)" if rows[n]["sigmas"] is not None else "")
        for n in names
    )


def _stiffness(recovery: dict[str, Any]) -> str:
    return " / ".join(f"{100 * e:+.1f} %" for e in stiffness_errors(recovery).values())


def _grip(race: dict[str, Any], axle: str) -> str:
    used = race["grip_used"][axle]
    return f"{used['p99']:.2f} / {used['max']:.2f}"


def _rmse(race: dict[str, Any]) -> str:
    rmse = race["estimation_rmse"]
    return f"{1e3 * rmse['x']:.1f} / {1e3 * rmse['y']:.1f} mm / {1e3 * rmse['yaw']:.1f} mrad"
