"""The identification benchmark (``crs bench sysid``): speed, real-data cross-validation and
the simulated coverage study, as one JSON-ready dict."""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.machine import REAL_DATA, machine
from crs_core.dataset import Dataset
from crs_core.identification.models import ROUGH, identification_model
from crs_core.identification.problem import DEFAULT_FIT, DYNAMICS_FIT, FieSettings
from crs_core.model import CarModel
from sim.scenarios import SIM_PROCESS_SCALE, simulate_dataset

#: The benchmark's fit: the 15 dynamics parameters, wheel radius and track width.


def simulated_study(seeds: Sequence[int], duration: float = 60.0) -> dict[str, Any]:
    """Identify from the rough prior on simulated runs (truth: Chronos defaults).

    Per seed: the parameters flagged identifiable within 3 sigma of the truth, and the share of
    all (parameter, seed) pairs with the truth inside +-2 sigma; the first seed's run is
    validated open loop (2 s) on the next seed's run (held out).
    """
    from crs_core.identification.solve import identify
    from crs_core.identification.validation import validate

    truth = CarModel().parameters
    rows, inside2, total, identifiable_ok, identifiable_n = [], 0, 0, 0, 0
    validation = None
    for seed in seeds:
        dataset = simulate_dataset(duration, seed)
        model = identification_model(dataset, [], ROUGH)
        settings = FieSettings(fit=DEFAULT_FIT, process_scale=SIM_PROCESS_SCALE)
        result = identify(dataset, model, settings)
        z = (result.theta - np.array([truth.value(n) for n in result.fit])) / result.uncertainty.std
        inside2 += int(np.sum(np.abs(z) <= 2))
        total += len(z)
        ok = result.uncertainty.identifiable
        identifiable_ok += int(np.sum(np.abs(z[ok]) <= 3))
        identifiable_n += int(ok.sum())
        rows.append(
            {
                "seed": seed,
                "samples": len(dataset.t),
                "iterations": result.iterations,
                "time_s": round(result.time_s, 2),
                "z": {n: round(float(v), 2) for n, v in zip(result.fit, z, strict=True)},
                "not_identifiable": [n for n, o in zip(result.fit, ok, strict=True) if not o],
            }
        )
        if validation is None:
            held_out = simulate_dataset(duration, seed + 1000)
            summary, _ = validate(held_out, model, result.parameters, model.parameters)
            validation = {
                "position_rmse_m": summary["position_rmse_m"],
                "position_rmse_at_horizon_m": summary["position_rmse_at_horizon_m"],
            }
        _say(f"simulated: seed {seed} done")
    return {
        "duration_s": duration,
        "seeds": list(seeds),
        "truth_inside_2sigma_fraction": inside2 / max(total, 1),
        "identifiable_within_3sigma": f"{identifiable_ok}/{identifiable_n}",
        "open_loop_2s_held_out": validation,
        "runs": rows,
    }


def real_study() -> dict[str, Any]:
    """Identify on one real run, validate on the other, both ways (rough prior)."""
    from crs_core.identification.solve import identify
    from crs_core.identification.validation import validate

    runs = [REAL_DATA / "fie_mpc_lighthouse_1", REAL_DATA / "fie_mpc_lighthouse_2"]
    out = {}
    for train, test in ((runs[0], runs[1]), (runs[1], runs[0])):
        _say(f"real: identify on {train.name}, validate on {test.name}, prediction-error floor")
        dataset = Dataset.load(train)
        model = identification_model(dataset, [], ROUGH)
        result = identify(dataset, model, FieSettings(fit=DEFAULT_FIT))
        summary, _ = validate(Dataset.load(test), model, result.parameters, model.parameters)
        out[f"{train.name} -> {test.name}"] = {
            "samples": len(dataset.t),
            "iterations": result.iterations,
            "time_s": round(result.time_s, 2),
            "build_s": round(result.build_s, 2),
            "time_per_iteration_s": round(result.time_per_iteration_s, 4),
            "solver_status": result.solver_status,
            "position_rmse_m": summary["position_rmse_m"],
            "position_rmse_at_horizon_m": summary["position_rmse_at_horizon_m"],
            "paper_position_rmse_m": {"prior": 0.24, "identified": 0.09},
            "not_identifiable": result.uncertainty.warnings(),
            "prediction_error_floor": prediction_error_floor(dataset, Dataset.load(test), model),
        }
    return out


def prediction_error_floor(train: Dataset, test: Dataset, model: CarModel) -> dict[str, Any]:
    """The 15 dynamics parameters fitted to the validation metric itself on ``train``
    (:mod:`crs_core.identification.prediction_error`), validated on ``test``: the held-out error
    no parameter vector of this model structure is expected to beat."""
    from crs_core.identification.prediction_error import fit_prediction_error
    from crs_core.identification.validation import validate

    fitted = fit_prediction_error(train, model, DYNAMICS_FIT)
    summary, _ = validate(test, model, fitted.parameters)
    return {
        "fit": list(fitted.fit),
        "train_position_rmse_m": {"prior": fitted.rmse_initial_m, "fitted": fitted.rmse_m},
        "held_out_position_rmse_m": summary["position_rmse_m"]["identified"],
        "evaluations": fitted.evaluations,
        "time_s": round(fitted.time_s, 1),
        "values": {name: fitted.parameters.value(name) for name in fitted.fit},
    }


def speed_study() -> dict[str, Any]:
    """Wall time of one identification: a real run (17 parameters, all sensors) and 3000
    simulated samples."""
    from crs_core.identification.solve import identify

    out = {}
    cases = {
        "real_run_1": Dataset.load(REAL_DATA / "fie_mpc_lighthouse_1"),
        "simulated_3000": None,
    }
    for label, dataset in cases.items():
        _say(f"speed: {label}")
        if dataset is None:
            dataset = simulate_dataset(70.0, 7).samples(0, 3000)
        model = identification_model(dataset, [], ROUGH)
        scale = SIM_PROCESS_SCALE if label.startswith("simulated") else 1.0
        started = time.perf_counter()
        result = identify(dataset, model, FieSettings(fit=DEFAULT_FIT, process_scale=scale))
        out[label] = {
            "samples": len(dataset.t),
            "parameters": len(DEFAULT_FIT),
            "time_s": round(time.perf_counter() - started, 2),
            "build_s": round(result.build_s, 2),
            "iterations": result.iterations,
            "time_per_iteration_s": round(result.time_per_iteration_s, 4),
            "solver_status": result.solver_status,
        }
    return out


def _say(line: str) -> None:
    """A progress line on stderr (the JSON goes to stdout)."""
    print(f"bench sysid: {line}", file=sys.stderr, flush=True)


def sysid_benchmark(out: Path | None, seeds: int = 10) -> dict[str, Any]:
    """``crs bench sysid``: speed, real-data cross-validation and the simulated coverage study.

    Returns (and writes to ``out`` as JSON when given) a JSON-ready dict.
    """
    started = time.perf_counter()
    result = {
        "machine": machine(),
        "speed": speed_study(),
        "real": real_study(),
        "simulated": simulated_study(list(range(seeds))),
    }
    result["wall_time_s"] = round(time.perf_counter() - started, 1)
    if out is not None:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(result, indent=2))
    return result


def _rmse_change(rmse: dict[str, float]) -> str:
    return f"prior {rmse['prior']:.3f} m → identified **{rmse['identified']:.3f} m**"


def format_markdown(result: dict[str, Any]) -> str:
    """The docs' table of the benchmark (Markdown): the speed of one identification, the
    simulated coverage study, and the real runs cross-validated with their prediction-error
    floor (2 s open-loop position RMSE, m)."""
    lines = ["| | figure |", "|---|---|"]
    for label, what in (("real_run_1", "one real run"), ("simulated_3000", "simulated samples")):
        s = result["speed"].get(label)
        if s is None:
            continue
        head = (
            f"{what} ({s['samples']} samples, all sensors, {s['parameters']} parameters)"
            if label.startswith("real")
            else f"{s['samples']} {what} ({s['parameters']} parameters)"
        )
        lines.append(
            f"| {head} | {s['time_s']:.1f} s including the {s['build_s']:.1f} s build, "
            f"{s['iterations']} IPOPT iterations, {s['time_per_iteration_s']:.2f} s each |"
        )
    sim = result.get("simulated")
    if sim:
        runs = sim["runs"]
        pairs = sum(len(run["z"]) for run in runs)
        inside = round(sim["truth_inside_2sigma_fraction"] * pairs)
        ok, flagged = sim["identifiable_within_3sigma"].split("/")
        never = [n for n in runs[0]["z"] if all(n in run["not_identifiable"] for run in runs)]
        lines.append(
            f"| simulation, known truth (the Chronos values), {sim['duration_s']:g} s runs from "
            f"`ROUGH_PRIOR`, {len(runs)} seeds | within 3σ of the truth: {ok} of the {flagged} "
            f"(parameter, seed) pairs flagged identifiable; truth inside ±2σ for {inside} / "
            f"{pairs} = {100 * sim['truth_inside_2sigma_fraction']:.1f} % of (parameter, seed) "
            "pairs; "
            f"{', '.join(never) or 'none'} flagged unidentifiable on every seed |"
        )
        held = sim.get("open_loop_2s_held_out")
        if held:
            lines.append(
                "| simulation, held-out run, 2 s open-loop position RMSE | "
                f"{_rmse_change(held['position_rmse_m'])} |"
            )
    floors = []
    for direction, real in result.get("real", {}).items():
        train, test = (name.rsplit("_", 1)[-1] for name in direction.split(" -> "))
        lines.append(
            f"| real, identify on run {train}, validate on run {test} "
            f"({len(DEFAULT_FIT)} parameters) | {_rmse_change(real['position_rmse_m'])} |"
        )
        floor = real.get("prediction_error_floor")
        if floor:
            floors.append((train, test, floor))
    if floors:
        cells = "; ".join(
            f"run {train} → {test}: {f['train_position_rmse_m']['fitted']:.3f} m on run {train}, "
            f"**{f['held_out_position_rmse_m']:.3f} m** held out"
            for train, test, f in floors
        )
        counts = " / ".join(str(f["evaluations"]) for _, _, f in floors)
        times = " / ".join(f"{f['time_s']:.0f}" for _, _, f in floors)
        lines.append(
            f"| real, prediction-error floor: the {len(floors[0][2]['fit'])} dynamics parameters "
            "fitted to the metric itself on the training run "
            f"(`crs_core/identification/prediction_error.py`) | {cells} ({counts} open-loop "
            f"predictions, {times} s) |"
        )
    if "wall_time_s" in result:
        lines += ["", f"The whole benchmark: {result['wall_time_s']:.0f} s."]
    return "\n".join(lines)
