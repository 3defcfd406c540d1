"""``crs bench discrepancy``: does the workflow name the right effect, and never one on clean data?

Cases: every registry effect hidden in the simulated car at two magnitudes (three for the steering
gain), changes outside the registry (:data:`OUTSIDE`: a battery losing torque over each run), and
clean runs (no effect; every third with sensor noise the estimator does not assume),
each a training run and a held-out run of another seed. Half of the cases are read as
an *independent source*: a joystick driver instead of the path follower, and the datasets saved
in the layout of the real recordings (``t.npy``, ``u.npy``, ``y.npy``, ``x.npy`` only: no
``dataset.yaml``, no full-rate stream, so the geometry is the real recordings' and the first
plane's sweep lag is unknown, as on real data). The current model is the Chronos model, the fit
the 15 dynamics parameters. Reported: per case the verdict, the named effects, the fitted value
against the truth, the held-out gap before / after and the time; the confusion table (truth
-> named), the detection rate per effect and magnitude, the false-alarm rate over the clean
seeds, and the speed of one run on 60 s of data.
"""

from __future__ import annotations

import json
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

from benchmarks.machine import machine
from crs_core.dataset import Dataset
from crs_core.discrepancy.workflow import (
    DiscrepancyResult,
    DiscrepancySettings,
    find_discrepancy,
)
from crs_core.identification.problem import DYNAMICS_FIT, FieSettings
from crs_core.model import EFFECTS, CarModel
from crs_core.model.terms import Term
from sim.drift import DriftSchedule, parse_drift
from sim.scenarios import SIM_PROCESS_SCALE, simulate_dataset
from sim.sensors import SensorSpec, SensorSuite

#: Names of the hidden magnitudes, smallest first.
LEVELS = ("small", "large", "larger")
#: Hidden magnitudes per effect, one ``{parameter: value}`` per level of :data:`LEVELS`
#: (steering gain errors up to 20 % were absorbed by the fitted front tire: a third level).
MAGNITUDES: dict[str, tuple[dict[str, float], ...]] = {
    "steering_offset": ({"steering_offset": 0.01}, {"steering_offset": 0.03}),
    "input_delay": ({"input_delay": 0.03}, {"input_delay": 0.06}),
    "steering_lag": ({"tau_steer": 0.05}, {"tau_steer": 0.1}),
    "motor_lag": ({"tau_motor": 0.1}, {"tau_motor": 0.2}),
    "gyro_bias": ({"gyro_bias": 0.02}, {"gyro_bias": 0.05}),
    "wheel_radius_error": ({"wheel_radius_error": 0.0005}, {"wheel_radius_error": 0.001}),
    "gyro_scale": ({"gyro_scale_error": 0.03}, {"gyro_scale_error": 0.08}),
    "steering_gain": (
        {"steering_gain_error": 0.1},
        {"steering_gain_error": 0.2},
        {"steering_gain_error": 0.4},
    ),
    "torque_deadzone": ({"torque_deadzone": 0.05}, {"torque_deadzone": 0.1}),
    "lighthouse_offset": (
        {"lh_plane1_offset": 0.003, "lh_plane2_offset": -0.002},
        {"lh_plane1_offset": 0.006, "lh_plane2_offset": -0.004},
    ),
}
#: Changes outside the registry, per kind one truth per level of :data:`LEVELS`:
#:
#: * ``battery``: the motor constant falling linearly from each recording's start by
#:   ``loss_per_minute`` of its value per minute (time is in no registry effect; the FIE's state
#:   absorbs it, open-loop prediction does not; a term in ``t`` can have it);
#: * ``slip``: the wheels spinning faster under drive torque, ``wheel_speeds += k torque vx``
#:   (rad/s per m/s: the longitudinal slip of 0.2 per unit torque is ``k`` 11.4);
#: * ``scrub``: the tyres scrubbing speed when steered, ``d vx/dt += -c steer^2 vx`` (1/(s rad^2));
#: * ``g_sensitivity``: a gyro that reads the lateral acceleration, ``yaw_rate += g vx omega``
#:   (rad/s per m/s^2; MEMS gyros' g-sensitivity, here far larger than a good part's).
OUTSIDE: dict[str, tuple[dict[str, float], ...]] = {
    "battery": ({"loss_per_minute": 0.15}, {"loss_per_minute": 0.3}),
    "slip": ({"k": 5.7}, {"k": 11.4}),
    "scrub": ({"c": 1.0}, {"c": 2.0}),
    "g_sensitivity": ({"g": 0.01}, {"g": 0.02}),
}
#: Length of a battery case's training run, s (a drift needs time to show: the issue's 60 s).
BATTERY_S = 60.0
#: The right shape of a term proposed for each kind: its target and the variables it must use.
OUTSIDE_SHAPES: dict[str, tuple[str, set[str]]] = {
    "battery": ("vx", {"t", "torque"}),
    "slip": ("wheel_speeds", {"vx", "torque"}),
    "scrub": ("vx", {"steer", "vx"}),
    "g_sensitivity": ("yaw_rate", {"vx", "omega"}),
}


def outside_truth(kind: str, values: dict[str, float]) -> CarModel:
    """The simulated car of an outside-the-registry case without its drift (``battery`` is a
    drift schedule, :func:`_battery`)."""
    terms = {
        "slip": lambda: Term("slip", "wheel_speeds", (("torque", "vx"),), (values["k"],)),
        "scrub": lambda: Term("scrub", "vx", (("steer", "steer", "vx"),), (-values["c"],)),
        "g_sensitivity": lambda: Term(
            "g_sensitivity", "yaw_rate", (("vx", "omega"),), (values["g"],)
        ),
    }
    return CarModel(terms=[terms[kind]()]) if kind in terms else CarModel()


#: A named parameter counts as recovered within this relative error.
RELATIVE_TOLERANCE = 0.15
#: Length of every held-out run, s (the test's power grows with it; scoring costs little).
HELD_OUT_S = 30.0
#: Every third clean run is simulated with these sensors, not the ones the estimator assumes:
#: twice the noise on every channel, three times the Lighthouse drop-outs, more jitter.
MISMATCHED_SENSORS = SensorSuite(
    imu=SensorSpec(250.0, (1.0, 1.0, 0.1)),
    wheel_encoders=SensorSpec(250.0, (4.0,) * 4),
    lighthouse=SensorSpec(50.0, (2e-3,) * 4, dropout_probability=0.15, jitter_std_s=5e-4),
)


def _battery(values: dict[str, float], duration: float) -> DriftSchedule:
    """The motor constant falling linearly by ``values["loss_per_minute"]`` of its value per
    minute over ``duration`` s."""
    change = {"parameter": "Cm1", "from_s": 0.0, "to_s": duration}
    factor = 1.0 - values["loss_per_minute"] * duration / 60.0
    return parse_drift({"drift": [{**change, "factor": factor}]})


def _case_datasets(
    effect: str | None,
    values: dict[str, float],
    seed: int,
    duration: float,
    held_out_s: float,
    independent: bool,
    noise: str,
    outside: str | None = None,
) -> tuple[Dataset, Dataset]:
    truth = CarModel({effect: values}) if effect else CarModel()
    if outside:
        truth = outside_truth(outside, values)
    driver = "joystick" if independent else "path"
    sensors = MISMATCHED_SENSORS if noise == "mismatched" else None
    battery = outside == "battery"
    train = simulate_dataset(
        duration, seed, truth, driver, sensors, _battery(values, duration) if battery else None
    )
    held_out = simulate_dataset(
        held_out_s,
        seed + 1000,
        truth,
        driver,
        sensors,
        _battery(values, held_out_s) if battery else None,
    )
    if not independent:
        return train, held_out
    with tempfile.TemporaryDirectory() as folder:
        loaded = []
        for name, dataset in (("train", train), ("held_out", held_out)):
            loaded.append(Dataset.load(dataset.save(Path(folder) / name, metadata=False)))
    return loaded[0], loaded[1]


def _workflow(
    train: Dataset, held_out: Dataset | None, workers: int
) -> tuple[DiscrepancyResult, dict[str, Any], float]:
    """The workflow on simulated data as the benchmark runs it: the result, its summary and the
    wall time (s)."""
    settings = DiscrepancySettings(
        identification=FieSettings(fit=DYNAMICS_FIT, process_scale=SIM_PROCESS_SCALE),
        workers=workers,
    )
    started = time.perf_counter()
    result = find_discrepancy(train, CarModel(), held_out, settings)
    return result, result.summary(), round(time.perf_counter() - started, 1)


def run_case(case: dict[str, Any], workers: int = 1) -> dict[str, Any]:
    """One case: simulate, run the workflow (hypotheses on ``workers`` processes), compare with
    the truth (JSON-ready)."""
    effect, values = case["effect"], case["values"]
    train, held_out = _case_datasets(
        effect,
        values,
        case["seed"],
        case["duration_s"],
        case["held_out_s"],
        case["independent"],
        case["noise"],
        case.get("outside"),
    )
    result, summary, seconds = _workflow(train, held_out, workers)
    row = {
        **case,
        "verdict": result.verdict,
        "named": list(result.effects),
        "time_s": seconds,
        "gap_before_m": summary["gap_before"],
        "gap_after_m": summary["gap_after"],
        "parameters": summary["parameters"],
        "plane1_lag": summary["plane1_lag"],
        "where": summary["where"],
        "prediction": {
            key: summary["prediction_before"][key]
            for key in ("gap", "shuffled_gap", "coherence", "structured", "strongest")
        },
        "hypotheses": {
            "+".join(h["effects"]): {
                "improvement": h["held_out"]["improvement"] if h["held_out"] else None,
                "p_value": h["held_out"]["p_value"] if h["held_out"] else None,
                "significant": h["significant"],
            }
            for h in summary["hypotheses"]
        },
    }
    if effect:
        fitted = summary["parameters"].get(effect, {})
        errors = {
            name: abs(fitted[name]["value"] - truth) / abs(truth)
            for name, truth in values.items()
            if name in fitted
        }
        row["relative_error"] = errors
        row["correct"] = result.effects == (effect,) or effect in result.effects
        row["within_tolerance"] = bool(errors) and max(errors.values()) <= RELATIVE_TOLERANCE
    elif case.get("outside"):
        row["proposed"] = [
            {k: entry[k] for k in ("target", "variables", "equation", "accepted", "significant")}
            for entry in summary["proposed_terms"]
        ]
        accepted = [entry for entry in summary["proposed_terms"] if entry["accepted"]]
        shape = OUTSIDE_SHAPES[case["outside"]]
        row["shape_right"] = (
            bool(accepted)
            and shape is not None
            and any(
                entry["target"] == shape[0] and shape[1] <= set(entry["variables"])
                for entry in accepted
            )
        )
        row["correct"] = row["shape_right"] or (not accepted and result.verdict == "unexplained")
    else:
        row["correct"] = result.verdict == "none"
    return row


def cases(seeds: int, clean_seeds: int, duration: float) -> list[dict[str, Any]]:
    """The case list: every effect at every magnitude for ``seeds`` seeds, and the clean runs
    (every third with :data:`MISMATCHED_SENSORS`); every other case is read as an independent
    source (alternating over effects, magnitudes and seeds)."""
    out = []
    for seed in range(seeds):  # every effect once before any twice: a run stopped early covers all
        for e, (effect, magnitudes) in enumerate(MAGNITUDES.items()):
            for m, (level, values) in enumerate(zip(LEVELS, magnitudes, strict=False)):
                out.append(
                    {
                        "effect": effect,
                        "magnitude": level,
                        "values": values,
                        "seed": 100 + seed,
                        "independent": bool((e + m + seed) % 2),
                        "noise": "nominal",
                        "duration_s": duration,
                        "held_out_s": HELD_OUT_S,
                        "outside": None,
                    }
                )
        for kind, magnitudes in OUTSIDE.items():
            for m, (level, values) in enumerate(zip(LEVELS, magnitudes, strict=False)):
                out.append(
                    {
                        "effect": None,
                        "magnitude": level,
                        "values": values,
                        "seed": 100 + seed,
                        "independent": bool((m + seed) % 2),
                        "noise": "nominal",
                        "duration_s": BATTERY_S if kind == "battery" else duration,
                        "held_out_s": HELD_OUT_S,
                        "outside": kind,
                    }
                )
    clean = [
        {
            "effect": None,
            "magnitude": None,
            "values": {},
            "seed": 200 + seed,
            "independent": bool(seed % 2),
            "noise": "mismatched" if seed % 3 == 2 else "nominal",
            "duration_s": duration,
            "held_out_s": HELD_OUT_S,
            "outside": None,
        }
        for seed in range(clean_seeds)
    ]
    # interleaved, so that a run stopped early has measured both kinds
    mixed = []
    for i in range(max(len(out), len(clean))):
        mixed += out[i : i + 1] + clean[i : i + 1]
    return mixed


def tabulate(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Confusion table, detection rates, false-alarm rate and parameter accuracy."""
    confusion: dict[str, Counter] = {}
    for row in rows:
        truth = row["effect"] or row.get("outside") or "clean"
        answer = "+".join(row["named"]) if row["named"] else row["verdict"]
        confusion.setdefault(truth, Counter())[answer] += 1
    detection = {}
    for effect in MAGNITUDES:
        for level in LEVELS:
            hits = [r for r in rows if r["effect"] == effect and r["magnitude"] == level]
            if hits:
                detection[f"{effect}/{level}"] = {
                    "correct": sum(r["correct"] for r in hits),
                    "runs": len(hits),
                    "within_15_percent": sum(r.get("within_tolerance", False) for r in hits),
                    "gap_before_m": [r["gap_before_m"] for r in hits],
                    "gap_after_m": [r["gap_after_m"] for r in hits],
                }
    clean = [r for r in rows if r["effect"] is None and not r.get("outside")]
    alarms = [r for r in clean if r["verdict"] != "none"]
    outside = {}
    for kind in OUTSIDE:
        for level in LEVELS:
            hits = [r for r in rows if r.get("outside") == kind and r["magnitude"] == level]
            if hits:
                outside[f"{kind}/{level}"] = {
                    "runs": len(hits),
                    "verdicts": dict(Counter(r["verdict"] for r in hits)),
                    "registry_names": [r["named"] for r in hits if r["named"]],
                    "shape_right": sum(r.get("shape_right", False) for r in hits),
                    "proposed": [
                        [e["equation"] for e in r.get("proposed", []) if e["accepted"]]
                        for r in hits
                    ],
                    "gap_before_m": [r["gap_before_m"] for r in hits],
                    "coherence": [r["prediction"]["coherence"] for r in hits],
                }
    return {
        "confusion": {truth: dict(counts) for truth, counts in confusion.items()},
        "detection": detection,
        "outside": outside,
        "false_alarms": {
            "runs": len(clean),
            "findings": len(alarms),
            "rate": len(alarms) / len(clean) if clean else None,
            "verdicts": dict(Counter(r["verdict"] for r in clean)),
            "mismatched_noise": {
                "runs": sum(r["noise"] == "mismatched" for r in clean),
                "findings": sum(r["noise"] == "mismatched" for r in alarms),
            },
        },
        "wrong_names": [
            {"truth": r["effect"], "magnitude": r["magnitude"], "named": r["named"]}
            for r in rows
            if r["effect"] and r["named"] and r["effect"] not in r["named"]
        ],
    }


def markdown(rows: list[dict[str, Any]]) -> str:
    """The README's table of the hidden-effect cases (one line each, effects in registry order,
    then magnitude and seed) and a line on the clean runs."""
    order = list(MAGNITUDES)
    lines = [
        "| hidden effect | truth | seed, source | named | fitted ± σ | held-out test of that "
        "effect | gap before → after (m) |",
        "|---|---|---|---|---|---|---|",
    ]
    hidden = [r for r in rows if r["effect"]]
    hidden.sort(key=lambda r: (order.index(r["effect"]), LEVELS.index(r["magnitude"]), r["seed"]))
    for r in hidden:
        truth = ", ".join(f"{name} {value:g}" for name, value in r["values"].items())
        source = f"{r['seed']}, {'independent' if r['independent'] else 'simulator'}"
        named = "+".join(r["named"]) if r["named"] else f"*{r['verdict']}*"
        fitted = "; ".join(
            f"{p['value']:.4g} ± {p['std']:.2g}"
            for p in r["parameters"].get(r["effect"], {}).values()
        )
        test = r["hypotheses"].get(r["effect"]) or {}
        held_out = (
            f"{100 * test['improvement']:+.0f} %, p {test['p_value']:.1g}"
            if test.get("improvement") is not None
            else "—"
        )
        lines.append(
            f"| {r['effect']} | {truth} | {source} | {named} | {fitted or '—'} | {held_out} | "
            f"{r['gap_before_m']:.3f} → {r['gap_after_m']:.3f} |"
        )
    clean = [r for r in rows if not r["effect"] and not r.get("outside")]
    verdicts = Counter(r["verdict"] for r in clean)
    mismatched = [r for r in clean if r["noise"] == "mismatched"]
    lines.append("")
    lines.append(
        f"Clean runs: {len(clean)} ({', '.join(f'{v} {n}' for v, n in verdicts.items())}); "
        f"{len(mismatched)} with mismatched sensor noise "
        f"({sum(r['verdict'] != 'none' for r in mismatched)} not `none`)."
    )
    return "\n".join(lines)


def _speed_line(run: dict[str, Any]) -> str:
    """The speed run's bullet: its wall time and what it named against the truth."""
    named = "; ".join(
        f"{effect} " + ", ".join(f"{p['value']:.4g} ± {p['std']:.2g}" for p in parameters.values())
        for effect, parameters in run["parameters"].items()
    )
    truth = ", ".join(
        f"{name} {value:g}" for values in run["truth"].values() for name, value in values.items()
    )
    found = f"{named} named" if named else f"*{run['verdict']}*"
    return (
        f"- **Time:** one run on a {run['recording_s']:g} s recording (`crs discrepancy REC` with "
        f"its defaults: held out the {run['held_out']}, every hypothesis, `--workers "
        f"{run['workers']}`) took **{run['time_s']:.0f} s** ({found} for a hidden {truth}, gap "
        f"{run['gap_before_m']:.3f} → {run['gap_after_m']:.3f} m)."
    )


def format_markdown(result: dict[str, Any]) -> str:
    """The docs' account of a run (Markdown): its settings, the false alarms, the hidden
    effects named, the speed run, then the table of :func:`markdown`.

    Parameters
    ----------
    result : dict
        The benchmark's JSON (:func:`discrepancy_benchmark`): ``settings`` (durations in s),
        ``cases``, ``summary`` (:func:`tabulate`), optionally ``speed_60s`` (times in s, gaps
        in m) and ``wall_time_s``.

    Returns
    -------
    str
        Markdown: a settings line, three bullets and the per-case table.
    """
    settings, rows = result["settings"], result["cases"]
    hidden = [r for r in rows if r["effect"]]
    clean = result["summary"]["false_alarms"]
    correct = [r for r in hidden if r["correct"]]
    independent = [r for r in hidden if r["independent"]]
    seeds = sorted({r["seed"] for r in hidden})
    wall = f"; the whole benchmark {result['wall_time_s']:.0f} s" if "wall_time_s" in result else ""
    lines = [
        f"Training runs of {settings['duration_s']:g} s, held-out runs of "
        f"{settings['held_out_s']:g} s (another seed); {len(hidden)} hidden-effect cases (seed"
        f"{'s' if len(seeds) > 1 else ''} {', '.join(map(str, seeds))}) and {clean['runs']} clean "
        f"runs{wall}.",
        "",
        f"- **False alarms: {clean['findings']} findings in {clean['runs']} clean runs** "
        f"({clean['mismatched_noise']['runs']} of them with mismatched sensor noise, "
        f"{clean['mismatched_noise']['findings']} findings there); designed: ≤ "
        f"{100 * settings['false_alarm_rate_designed']:g} % per round.",
        f"- **Hidden effects: {len(correct)} of {len(hidden)} named correctly** "
        f"({sum(r['correct'] for r in independent)} of {len(independent)} independent), the "
        f"parameter within {100 * RELATIVE_TOLERANCE:g} % of the truth in "
        f"{sum(r.get('within_tolerance', False) for r in correct)} of those {len(correct)}; "
        f"**wrong names: {len(result['summary']['wrong_names'])}**.",
    ]
    if result["summary"].get("outside"):
        lines.append(_outside_line(rows))
    if "speed_60s" in result:
        lines.append(_speed_line(result["speed_60s"]))
    tables = [markdown(rows)]
    if result["summary"].get("outside"):
        tables += ["", outside_markdown(rows)]
    return "\n".join([*lines, "", *tables])


def _outside_line(rows: list[dict[str, Any]]) -> str:
    """The bullet on the changes outside the registry (:func:`outside_markdown` has the cases)."""
    outside = [r for r in rows if r.get("outside")]
    verdicts = Counter(r["verdict"] for r in outside)
    named = [r for r in outside if r["named"]]
    return (
        f"- **Outside the registry: {sum(r['shape_right'] for r in outside)} of {len(outside)} "
        "proposed a term of the right shape** (target and variables, table below); verdicts "
        + ", ".join(f"{v} {n}" for v, n in sorted(verdicts.items()))
        + f"; a registry effect named in {len(named)}."
    )


def outside_markdown(rows: list[dict[str, Any]]) -> str:
    """The table of the outside-the-registry cases: truth, verdict, the accepted term, whether
    its shape is right, the open-loop coherence of the current model and the held-out gap."""
    lines = [
        "| change | truth | seed, source | verdict | term added (held-out test passed) | right "
        "shape | coherence | gap before → after (m) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    outside = [r for r in rows if r.get("outside")]
    order = list(OUTSIDE)
    outside.sort(key=lambda r: (order.index(r["outside"]), LEVELS.index(r["magnitude"]), r["seed"]))
    for r in outside:
        truth = ", ".join(f"{name} {value:g}" for name, value in r["values"].items())
        source = f"{r['seed']}, {'independent' if r['independent'] else 'simulator'}"
        added = [e["equation"] for e in r["proposed"] if e["accepted"]]
        verdict = r["verdict"] + (f" ({'+'.join(r['named'])})" if r["named"] else "")
        lines.append(
            f"| {r['outside']} | {truth} | {source} | {verdict} | {'; '.join(added) or '—'} | "
            f"{'yes' if r['shape_right'] else 'no'} | {r['prediction']['coherence']:.2f} | "
            f"{r['gap_before_m']:.3f} → {r['gap_after_m']:.3f} |"
        )
    return "\n".join(lines)


def speed(duration: float = 60.0, workers: int = 2) -> dict[str, Any]:
    """Wall time of one workflow run on a ``duration`` s recording as ``crs discrepancy REC``
    runs it by default: the last 30 % held out, every hypothesis, ``workers`` processes."""
    values = MAGNITUDES["gyro_bias"][1]
    recording = simulate_dataset(duration, 300, CarModel({"gyro_bias": values}))
    result, summary, seconds = _workflow(recording, None, workers)
    return {
        "workers": workers,
        "recording_s": duration,
        "held_out": summary["held_out"],
        "time_s": seconds,
        "truth": {"gyro_bias": values},
        "verdict": result.verdict,
        "named": list(result.effects),
        "parameters": summary["parameters"],
        "gap_before_m": summary["gap_before"],
        "gap_after_m": summary["gap_after"],
    }


#: What identifies a case across runs of the benchmark (``--resume``).
CASE_KEY = ("effect", "outside", "magnitude", "seed", "independent", "noise")


def _case_key(case: dict[str, Any]) -> tuple:
    return tuple(case.get(name) for name in CASE_KEY)


def _resumed(out: Path, settings: dict[str, Any]) -> dict[str, Any]:
    """The earlier result in ``out`` to continue; ``ValueError`` when it was measured with other
    settings (its cases would not be comparable)."""
    try:
        earlier = json.loads(Path(out).read_text())
    except (OSError, ValueError) as error:
        raise ValueError(f"--resume: cannot read {out} ({error})") from None
    if not isinstance(earlier, dict) or earlier.get("settings") != json.loads(json.dumps(settings)):
        raise ValueError(
            f"--resume: {out} was measured with other settings (durations, fit, magnitudes or "
            "sensors); start a new file"
        )
    return earlier


def discrepancy_benchmark(
    out: Path | None,
    seeds: int = 2,
    clean_seeds: int = 20,
    duration: float = 20.0,
    workers: int = 2,
    progress: Callable[[str], None] | None = None,
    speed_run: bool = True,
    resume: bool = False,
) -> dict[str, Any]:
    """Run the 60 s speed run (hypotheses on ``workers`` processes; unless not ``speed_run``)
    and then every case
    (``workers`` at once, each in one process; training runs of
    ``duration`` s, held-out runs of :data:`HELD_OUT_S`); JSON to ``out``, written again after every
    case so a stopped run keeps what it measured. With ``resume`` an existing ``out`` is
    continued: its cases (and speed run) are kept, only the missing ones are run."""
    say = progress or (lambda line: None)
    started = time.perf_counter()
    todo = cases(seeds, clean_seeds, duration)
    result: dict[str, Any] = {
        "machine": machine(),
        "settings": {
            "duration_s": duration,
            "held_out_s": HELD_OUT_S,
            "fit": list(DYNAMICS_FIT),
            "false_alarm_rate_designed": 0.01,
            "effects": list(EFFECTS),
            "magnitudes": {
                effect: dict(zip(LEVELS, levels, strict=False))
                for effect, levels in MAGNITUDES.items()
            },
            "mismatched_sensors": MISMATCHED_SENSORS.to_dict(),
            "outside": {
                kind: dict(zip(LEVELS, levels, strict=False)) for kind, levels in OUTSIDE.items()
            },
        },
        "cases": [],
    }

    def save() -> None:
        if out is not None:
            Path(out).parent.mkdir(parents=True, exist_ok=True)
            Path(out).write_text(json.dumps(result, indent=2))

    if resume and out is not None and Path(out).exists() and Path(out).stat().st_size > 0:
        earlier = _resumed(out, result["settings"])
        wanted = {_case_key(case) for case in todo}
        result["cases"] = [row for row in earlier.get("cases", []) if _case_key(row) in wanted]
        if "speed_60s" in earlier:
            result["speed_60s"] = earlier["speed_60s"]
        done = {_case_key(row) for row in result["cases"]}
        todo = [case for case in todo if _case_key(case) not in done]
        say(f"resuming {out}: {len(done)} cases kept, {len(todo)} to run")
        if result["cases"]:
            result["summary"] = tabulate(result["cases"])
    if speed_run and "speed_60s" not in result:
        say("speed: one run on a 60 s recording, alone on the machine ...")
        result["speed_60s"] = speed(workers=workers)
        save()
    first = len(result["cases"])
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for i, row in enumerate(pool.map(run_case, todo), first + 1):
            result["cases"].append(row)
            result["summary"] = tabulate(result["cases"])
            say(
                f"[{i}/{first + len(todo)}] {row['effect'] or row.get('outside') or 'clean'} "
                f"{row['magnitude'] or ''} "
                f"seed {row['seed']}: {row['verdict']} {'+'.join(row['named'])} "
                f"({row['time_s']:.0f} s)"
            )
            save()
    result["wall_time_s"] = round(time.perf_counter() - started, 1)
    save()
    return result
