"""``crs bench plan-drive``: does a designed drive decide what a race leaves open (issue 40)?

The car is issue 27's benchmark truth (:data:`benchmarks.workflow.TRUTH_FACTORS` on the
defaults: front and rear tyre peaks 15 % and 12 % low, the rear shape 15 % high, the motor 13 %
weaker, the drag 20 % higher) with a hidden motor lag (:data:`TRUTH_TAU_MOTOR`), simulated with
its sensors (``sim``, noise as the default suite). It races the path follower (:data:`RACE`)
and is identified by the FIE from the defaults with the motor lag open (``tau_motor`` at its
prior): the race alone. From that identification (its values and covariance, its last state as
the start) :func:`~crs_core.discrepancy.drive_design.design_drive` designs a drive of
``--drive-duration`` s; the slalom of the same length is the follower plus the largest steering
sine at :data:`SLALOM_HZ` that the model keeps on the track. Each drive follows the race in one
recording (the car goes on from where the race left it), and the FIE identifies again from the
defaults on race plus drive. A third drive is designed for the rear tyre alone (``Dr``, ``Br``):
how far the track lets a drive bend the rear curve. Per case and parameter: the sigma
predicted (the race's FIE covariance, then the design's prediction from it) and the sigma the
FIE reports, the fitted value against the truth; per drive how much grip and peak slip the
truth reached and whether it stayed on the track and in the Lighthouse's view.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from benchmarks.workflow import truth_parameters
from crs_core.control.path_following import PathFollower, PathFollowerSettings
from crs_core.dataset import Dataset
from crs_core.discrepancy.drive_design import (
    DesignSettings,
    DriveDesign,
    design_drive,
    evaluate_drive,
    slalom_drive,
    with_open_effects,
)
from crs_core.discrepancy.drive_file import Drive, DriveController
from crs_core.discrepancy.drive_reach import drive_summary, slip_used
from crs_core.identification.problem import DEFAULT_FIT, FieSettings
from crs_core.identification.solve import FieResult, identify
from crs_core.model import CarModel
from crs_core.model.bicycle import grip_used
from crs_core.track import Track, load_demo_track
from sim.scenarios import SIM_PROCESS_SCALE
from sim.sensors import SensorSuite
from sim.simulator import Simulator

#: The hidden motor lag's time constant, s (the identification's prior: 0.05 s).
TRUTH_TAU_MOTOR = 0.09
#: The race: the path follower's speed reference (m/s) and lateral-acceleration limit (m/s^2).
RACE = {"v_ref": 1.5, "a_lat_max": 4.0}
#: The parameters the race leaves open (the rear tyre's peak and shape, the motor lag) and the
#: front tyre's, reported beside them.
OPEN = ("Dr", "Br", "tau_motor")
#: The rear tyre alone: a second design, to see how far the track lets a drive bend its curve.
REAR = ("Dr", "Br")
REPORTED = ("Df", "Bf", "Dr", "Br", "tau_motor")
#: The slalom's frequency, Hz, and the amplitudes tried, largest first (rad).
SLALOM_HZ = 1.5
SLALOM_AMPLITUDES = (0.3, 0.25, 0.2, 0.15, 0.1, 0.05)


def truth_model() -> CarModel:
    """Issue 27's emulated car with the hidden motor lag."""
    model = CarModel(["motor_lag"])
    values = {**truth_parameters(), "tau_motor": TRUTH_TAU_MOTOR}
    return model.with_parameters(model.parameters.updated(values))


class RaceThenDrive:
    """``(t, x) -> u``: the race's path follower until ``race_s``, then ``drive``."""

    def __init__(self, track: Track, wheelbase: float, race_s: float, drive: Drive | None):
        settings = PathFollowerSettings(**RACE)
        self.race = PathFollower(track, wheelbase, settings)
        self.race_s = race_s
        self.drive = None if drive is None else DriveController(drive, track, wheelbase, race_s)

    def __call__(self, t: float, x: np.ndarray) -> np.ndarray:
        if t < self.race_s or self.drive is None:
            return self.race(t, x)
        return self.drive(t, x)


def simulate(truth: CarModel, race_s: float, drive: Drive | None, seed: int) -> Dataset:
    """The truth raced for ``race_s`` s, then ``drive`` (none: the race alone), one recording."""
    track = load_demo_track()
    wheelbase = truth.parameters.value("lf") + truth.parameters.value("lr")
    duration = race_s + (drive.duration_s if drive is not None else 0.0)
    controller = RaceThenDrive(track, wheelbase, race_s, drive)
    simulator = Simulator(truth, SensorSuite(), seed=seed)
    return simulator.run(controller, duration, track.start_state()).to_dataset()


def fie(dataset: Dataset, model: CarModel, fit: tuple[str, ...]) -> FieResult:
    """The FIE from ``model``'s values (the defaults), ``crs sysid``'s settings on simulated
    data."""
    return identify(dataset, model, FieSettings(fit=fit, process_scale=SIM_PROCESS_SCALE))


def reach(dataset: Dataset, truth: CarModel, race_s: float) -> dict[str, Any]:
    """Grip used and peak slip fraction the truth reached in the drive part (largest, at
    speed), and the share of its samples with Lighthouse sweeps."""
    drive = dataset.t >= race_s
    moving = drive & (dataset.x[:, 3] > 0.5)
    grip = grip_used(dataset.x[moving], dataset.u[moving], truth.parameters.value)
    slip = slip_used(dataset.x[moving], dataset.u[moving], truth)
    seen = np.all(np.isfinite(dataset.y[drive, :8]), axis=1)
    track = load_demo_track()
    lateral = [track.project(px, py).lateral_error for px, py in dataset.x[drive, :2]]
    return {
        "grip_used_max": {"front": float(grip[:, 0].max()), "rear": float(grip[:, 1].max())},
        "peak_slip_fraction_max": {
            "front": float(slip[:, 0].max()),
            "rear": float(slip[:, 1].max()),
        },
        "max_lateral_error_m": float(np.max(np.abs(lateral))),
        "track_half_width_m": float(np.min(track.width)) / 2,
        "lighthouse_fraction": float(np.mean(seen)),
    }


def rows(
    result: FieResult, truth: CarModel, predicted: dict[str, float] | None
) -> dict[str, dict[str, Any]]:
    """Per reported parameter: truth, fitted, the FIE's sigma, the error in sigmas, and the
    predicted sigma (open parameters)."""
    out = {}
    for name in REPORTED:
        i = result.fit.index(name)
        value, std, true = result.theta[i], result.uncertainty.std[i], truth.parameters.value(name)
        out[name] = {
            "truth": true,
            "fitted": round(float(value), 6),
            "error": round(float(value / true - 1.0), 4),
            "sigma_fie": round(float(std), 6),
            "sigmas_off": round(float((value - true) / std), 2) if std > 0 else None,
            "sigma_predicted": None if predicted is None else predicted.get(name),
        }
    return out


def slalom_design(
    model: CarModel,
    fit: tuple[str, ...],
    open_names: tuple[str, ...],
    prior: np.ndarray,
    track: Track,
    settings: DesignSettings,
) -> DriveDesign:
    """The largest slalom of :data:`SLALOM_AMPLITUDES` (at :data:`SLALOM_HZ`) the model keeps
    on the track and in view (the smallest if none)."""
    design = None
    for amplitude in SLALOM_AMPLITUDES:
        drive = slalom_drive(settings, open_names, track, amplitude, SLALOM_HZ)
        design = evaluate_drive(model, drive, fit, open_names, prior, track, settings)
        if design.penalty == 0.0:
            break
    assert design is not None
    return design


def plan_drive_benchmark(
    race_s: float = 30.0, drive_s: float = 8.0, seed: int = 0, evaluations: int = 400
) -> dict[str, Any]:
    """The cases (module docstring; and a drive designed for the rear tyre alone,
    :data:`REAR`); JSON-ready figures."""
    track = load_demo_track()
    truth = truth_model()
    prior_model = with_open_effects(CarModel(), OPEN)
    fit = (*DEFAULT_FIT, "tau_motor")
    timings: dict[str, float] = {}

    started = time.perf_counter()
    race = simulate(truth, race_s, None, seed)
    alone = fie(race, prior_model, fit)
    timings["race_fie_s"] = time.perf_counter() - started

    identified = prior_model.with_parameters(alone.parameters)
    last = alone.states[-1]  # where the race leaves the car: the drive begins there
    spec = SensorSuite().lighthouse  # a sample needs both planes of a rotation
    rate = spec.rate_hz * (1.0 - spec.dropout_probability) ** 2
    settings = DesignSettings(
        duration_s=drive_s,
        process_scale=SIM_PROCESS_SCALE,
        sample_period=1.0 / rate,
        evaluations=evaluations,
        seed=seed,
        start=(float(last[0]), float(last[1]), float(last[2]), float(last[3])),
    )
    started = time.perf_counter()
    designed = design_drive(identified, fit, OPEN, alone.uncertainty.covariance, track, settings)
    timings["design_s"] = time.perf_counter() - started
    started = time.perf_counter()
    rear = design_drive(identified, fit, REAR, alone.uncertainty.covariance, track, settings)
    timings["design_rear_s"] = time.perf_counter() - started
    slalom = slalom_design(identified, fit, OPEN, alone.uncertainty.covariance, track, settings)

    cases: dict[str, Any] = {
        "race": {
            "parameters": rows(alone, truth, dict(zip(fit, alone.uncertainty.std, strict=True)))
        }
    }
    drives = (("race_designed", designed), ("race_slalom", slalom), ("race_designed_rear", rear))
    for name, design in drives:
        started = time.perf_counter()
        data = simulate(truth, race_s, design.drive, seed)
        result = fie(data, prior_model, fit)
        timings[f"{name}_fie_s"] = time.perf_counter() - started
        after = np.sqrt(np.diag(design.covariance_after))
        predicted = {n: round(float(after[fit.index(n)]), 6) for n in REPORTED}
        cases[name] = {
            "open": list(design.open),
            "parameters": rows(result, truth, predicted),
            "drive_on_model": drive_summary(design, identified, track, settings.track_margin),
            "drive_on_truth": reach(data, truth, race_s),
            "drive": design.drive.to_dict(),
        }
    return {
        "truth": {"factors": truth_parameters(), "tau_motor": TRUTH_TAU_MOTOR},
        "race": {"duration_s": race_s, **RACE},
        "drive_duration_s": drive_s,
        "open": list(OPEN),
        "seed": seed,
        "design_evaluations": designed.evaluations,
        "slalom": {"frequency_hz": SLALOM_HZ},
        "cases": cases,
        "designed_beats_slalom": beats(cases),
        "timings_s": {k: round(v, 1) for k, v in timings.items()},
    }


def beats(cases: dict[str, Any]) -> dict[str, Any]:
    """Per open parameter whether the designed drive's sigma (predicted and FIE) is below the
    slalom's, and the D-criterion (product of the FIE's sigmas) of both."""
    out: dict[str, Any] = {}
    for kind in ("sigma_predicted", "sigma_fie"):
        designed = [cases["race_designed"]["parameters"][n][kind] for n in OPEN]
        slalom = [cases["race_slalom"]["parameters"][n][kind] for n in OPEN]
        out[kind] = {
            "per_parameter": {n: d < s for n, d, s in zip(OPEN, designed, slalom, strict=True)},
            "product_designed": float(np.prod(designed)),
            "product_slalom": float(np.prod(slalom)),
            "designed_better": bool(np.prod(designed) < np.prod(slalom)),
        }
    return out


def format_table(result: dict[str, Any]) -> str:
    """A Markdown table: per open parameter, sigma (predicted / FIE) and the error per case."""
    cases = result["cases"]
    names = [
        c for c in ("race", "race_designed", "race_slalom", "race_designed_rear") if c in cases
    ]
    header = {
        "race": "race: σ pred / FIE, error",
        "race_designed": "race + designed",
        "race_slalom": "race + slalom",
        "race_designed_rear": "race + designed for Dr, Br",
    }
    lines = [
        "| parameter | truth | " + " | ".join(header[c] for c in names) + " |",
        "|---|---|" + "---|" * len(names),
    ]
    for name in REPORTED:
        cells = []
        for case in names:
            row = cases[case]["parameters"][name]
            pred = row["sigma_predicted"]
            text = f"{pred:.4g}" if pred is not None else "-"
            cells.append(f"{text} / {row['sigma_fie']:.4g}, {row['error']:+.1%}")
        truth = cases["race"]["parameters"][name]["truth"]
        lines.append(f"| {name} | {truth:.4g} | " + " | ".join(cells) + " |")
    for case in names[1:]:
        reach_ = cases[case]["drive_on_truth"]
        lines.append(
            f"\n{case}: rear grip {reach_['grip_used_max']['rear']:.2f}, rear peak slip "
            f"{reach_['peak_slip_fraction_max']['rear']:.2f}, largest distance from the "
            f"centreline {reach_['max_lateral_error_m']:.3f} m of "
            f"{reach_['track_half_width_m']:.2f}, Lighthouse {reach_['lighthouse_fraction']:.0%}; "
            f"limited by {', '.join(cases[case]['drive_on_model']['limited_by']) or 'nothing'}"
        )
    verdict = result["designed_beats_slalom"]
    lines.append(
        f"\ndesigned beats slalom: predicted {verdict['sigma_predicted']['designed_better']}, "
        f"FIE {verdict['sigma_fie']['designed_better']}"
    )
    return "\n".join(lines)
