"""``crs bench plan-drive-stack``: the designed drive through the launched stack (issue 40).

``crs bench plan-drive`` drives in the core's simulator; this one goes the way a user goes,
every step a ``crs`` command in a process of its own, on the emulated car with the same truth
(:func:`benchmarks.plan_drive.truth_model`: issue 27's car and a hidden motor lag): ``crs
launch car --emulate`` races the path follower, ``crs sysid`` identifies the bag with the
motor lag open, ``crs plan-drive`` designs a drive for the open parameters from that
identification, and ``crs launch car --emulate --drive ... --drive-after`` races and then
drives it, once the designed drive and once the slalom of the same length that the
benchmark's rule picks (:func:`benchmarks.plan_drive.slalom_design`). Each drive's bag is
cut where the drive began (the emulator's truth first at the drive's start after
``--drive-after``, :meth:`~crs_core.discrepancy.drive_file.DriveController.at_start`) and
where it ended, and ``crs sysid`` identifies the race alone and the race plus the drive:
per parameter the sigma and the error against the truth, and how far the footprint stayed
inside the track during the drive.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from benchmarks.plan_drive import OPEN, REPORTED, TRUTH_TAU_MOTOR, slalom_design, truth_model
from benchmarks.workflow import load_race, run_crs, truth_parameters
from crs_core.discrepancy.drive_design import DesignSettings
from crs_core.discrepancy.drive_file import Drive, DriveController, load_drive
from crs_core.track import Track, load_demo_track
from launch_scripts.commands.plan_drive import design_inputs
from sim.closed_loop import footprint_outside

#: ``crs sysid``'s and ``crs plan-drive``'s process-noise scale (simulated data).
PROCESS_SCALE = "0.1"
#: The kinds of drive after the race.
KINDS = ("designed", "slalom")


def drive_began(
    drive: Drive, track: Track, t: np.ndarray, x: np.ndarray, after_s: float
) -> float | None:
    """The first truth stamp ``after_s`` or more past ``t[0]`` where the car is at the drive's
    start (None: it never was)."""
    truth = truth_model().parameters
    wheelbase = truth.value("lf") + truth.value("lr")
    controller = DriveController(drive, track, wheelbase, None)
    for k in np.flatnonzero(t >= t[0] + after_s):
        if controller.at_start(x[k]):
            return float(t[k])
    return None


def identify_cut(
    run: Path, drive: Drive, track: Track, after_s: float, work: Path
) -> dict[str, Any]:
    """``run``'s bag identified up to the drive's start and up to its end (``crs sysid`` on
    each cut), with the drive's start and the footprint's largest excursion during it."""
    recording, truth = load_race(run)
    began = drive_began(drive, track, truth["t"], truth["x"], after_s)
    if began is None:
        raise RuntimeError(f"{run}: the car never reached the drive's start")
    during = np.flatnonzero((truth["t"] >= began) & (truth["t"] < began + drive.duration_s))
    outside = max(footprint_outside(track, *truth["x"][k, :3], None) for k in during[::5])
    start = int(np.searchsorted(recording.t, began))
    end = int(np.searchsorted(recording.t, began + drive.duration_s))
    out: dict[str, Any] = {
        "drive_began_s": round(began - float(recording.t[0]), 2),
        "footprint_outside_max_m": round(float(outside), 4),
    }
    for case, last in (("race", start), ("race_plus_drive", end)):
        folder = recording.samples(0, last).save(work / f"{run.name}_{case}")
        fitted = work / f"{run.name}_{case}_sysid"
        seconds = run_crs(sysid_argv(folder, fitted))
        out[case] = {
            "recording_s": round(float(recording.t[last - 1] - recording.t[0]), 1),
            "sysid_s": round(seconds, 1),
            "parameters": parameter_rows(fitted / "result.json"),
        }
    return out


def sysid_argv(data: Path, out: Path) -> list[str]:
    """``crs sysid`` of ``data`` into ``out`` with the motor lag open (simulated data's
    process noise)."""
    return [
        "sysid",
        str(data),
        "--effect",
        "motor_lag",
        "--process-scale",
        PROCESS_SCALE,
        "--out",
        str(out),
    ]


def parameter_rows(result_json: Path) -> dict[str, dict[str, float]]:
    """Per reported parameter of a ``crs sysid`` result: fitted, sigma, error against the
    truth."""
    fitted = json.loads(result_json.read_text())["parameters"]
    truth = truth_model().parameters
    return {
        name: {
            "truth": truth.value(name),
            "fitted": round(float(fitted[name]["value"]), 6),
            "sigma": round(float(fitted[name]["std"]), 6),
            "error": round(float(fitted[name]["value"]) / truth.value(name) - 1.0, 4),
        }
        for name in REPORTED
    }


def plan_drive_stack_benchmark(
    work: Path, race_s: float = 40.0, after_s: float = 30.0, seed: int = 0, domain: int = 93
) -> dict[str, Any]:
    """The route of the module docstring in ``work`` (a new folder); JSON-ready figures."""
    work.mkdir(parents=True, exist_ok=True)
    truth_file = work / "truth.yaml"
    truth_file.write_text(yaml.safe_dump({"parameters": truth_parameters()}))
    car = [
        "--car-params",
        str(truth_file),
        "--car-effect",
        f"motor_lag.tau_motor={TRUTH_TAU_MOTOR}",
    ]
    launch = ["launch", "car", "--emulate", "--seed", str(seed), "--domain", str(domain), *car]
    steps: dict[str, float] = {}
    race = [*launch, "--controller", "path", "--duration", str(race_s)]
    steps["race_s"] = run_crs([*race, "--out", str(work / "race")])
    steps["sysid_s"] = run_crs(sysid_argv(work / "race" / "bag", work / "sysid"))
    params = work / "sysid" / "params.yaml"
    open_text = ",".join(OPEN)
    plan = ["plan-drive", "--params", str(params), "--open", open_text, "--seed", str(seed)]
    steps["plan_drive_s"] = run_crs(
        [*plan, "--process-scale", PROCESS_SCALE, "--out", str(work / "plan")]
    )
    track = load_demo_track()
    designed = load_drive(work / "plan" / "drive.yaml")
    model, open_names, fit, prior, _ = design_inputs(params, open_text)
    settings = DesignSettings(
        duration_s=designed.duration_s, v_ref=designed.v_ref, process_scale=float(PROCESS_SCALE)
    )
    slalom = slalom_design(model, fit, open_names, prior, track, settings).drive
    files = {"designed": work / "plan" / "drive.yaml", "slalom": slalom.save(work / "slalom.yaml")}
    drives = {"designed": designed, "slalom": slalom}
    # long enough to race after_s, reach the drive's start at speed and drive it
    duration = after_s + 14.0 + designed.duration_s
    cases: dict[str, Any] = {}
    for kind in KINDS:
        run = work / f"run_{kind}"
        with_drive = [*launch, "--drive", str(files[kind]), "--drive-after", str(after_s)]
        steps[f"run_{kind}_s"] = run_crs(
            [*with_drive, "--duration", str(duration), "--out", str(run)]
        )
        cases[kind] = identify_cut(run, drives[kind], track, after_s, work / "cuts")
    predicted = json.loads((work / "plan" / "report.json").read_text())["sigma"]
    return {
        "settings": {
            "race_s": race_s,
            "drive_after_s": after_s,
            "drive_s": designed.duration_s,
            "seed": seed,
            "open": list(OPEN),
            "truth_tau_motor": TRUTH_TAU_MOTOR,
        },
        "predicted_by_plan_drive": predicted,
        "cases": cases,
        "steps_s": {k: round(v, 1) for k, v in steps.items()},
    }


def format_table(result: dict[str, Any]) -> str:
    """A Markdown table: per kind of drive and open parameter, the sigma from the race alone
    and from race plus drive (the change), and the error against the truth after."""
    lines = ["| drive | " + " | ".join(f"σ {n}: race → race + drive" for n in OPEN) + " |"]
    lines.append("|---|" + "---|" * len(OPEN))
    for kind in KINDS:
        case = result["cases"][kind]
        cells = []
        for name in OPEN:
            before = case["race"]["parameters"][name]
            after = case["race_plus_drive"]["parameters"][name]
            change = after["sigma"] / before["sigma"] - 1.0
            cells.append(
                f"{before['sigma']:.4g} → {after['sigma']:.4g} ({change:+.0%}; error "
                f"{after['error']:+.1%})"
            )
        lines.append(f"| {kind} | " + " | ".join(cells) + " |")
    predicted = result["predicted_by_plan_drive"]
    lines.append(
        "\npredicted by `crs plan-drive` from the race's identification: "
        + ", ".join(
            f"{n} {predicted[n]['before']:.4g} → {predicted[n]['after']:.4g}"
            for n in OPEN
            if n in predicted
        )
    )
    for kind in KINDS:
        case = result["cases"][kind]
        inside = -case["footprint_outside_max_m"]
        where = (
            f"{inside * 100:.1f} cm inside" if inside >= 0 else f"{-inside * 100:.1f} cm outside"
        )
        lines.append(
            f"\n{kind}: began {case['drive_began_s']:.1f} s into the recording; the "
            f"footprint at most {where} the track's edge"
        )
    return "\n".join(lines)
