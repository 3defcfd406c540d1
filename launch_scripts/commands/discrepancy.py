"""``crs discrepancy``: which physical effect the model misses (argument handling only; the
workflow is :mod:`crs_core.discrepancy`)."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from crs_core.identification.data import FieData
from crs_core.identification.problem import FieSettings
from crs_core.model import EFFECTS
from launch_scripts.arguments import (
    Command,
    add_effect,
    add_model,
    add_out,
    add_process_scale,
    bounded_number,
)
from launch_scripts.commands.sysid import add_fit, identification_model, parse_fit
from launch_scripts.output_folder import prepare_output
from launch_scripts.recording import RECORDING_HELP, add_bag_options, load_recording


def parse_candidates(text: str | None) -> tuple[str, ...] | None:
    """``--candidates a,b`` -> effect names (None: every registry effect)."""
    if text is None:
        return None
    names = tuple(part.strip() for part in text.split(",") if part.strip())
    if not names:
        raise ValueError("--candidates: name at least one effect")
    for name in names:
        if name not in EFFECTS:
            raise ValueError(f"--candidates: unknown effect {name!r}; known: {', '.join(EFFECTS)}")
    return names


def run_discrepancy(args: argparse.Namespace) -> int:
    """Fit, diagnose, test every effect, write DIR/report.json, report.md, params.yaml, PNGs."""
    from crs_core.discrepancy.hypotheses import TestSettings
    from crs_core.discrepancy.report import write_discrepancy_report
    from crs_core.discrepancy.workflow import DiscrepancySettings, find_discrepancy

    train = load_recording(args.train, args, "TRAIN")
    validation = load_recording(args.validate, args, "--validate") if args.validate else None
    model = identification_model(train, args.effect or [], args.params, "--params", args.model)
    identification = FieSettings(fit=parse_fit(args.fit, model), process_scale=args.process_scale)
    FieData.from_dataset(train, identification.noise)  # refuse bad data before touching --out
    if validation is not None:
        FieData.from_dataset(validation, identification.noise)
    settings = DiscrepancySettings(
        identification=identification,
        test=TestSettings(false_alarm_rate=args.false_alarm_rate),
        candidates=parse_candidates(args.candidates),
        workers=args.workers,
        propose=not args.no_propose,
    )
    out = prepare_output(args.out, "discrepancy", args.overwrite)
    started = time.perf_counter()

    def progress(line: str) -> None:
        print(f"[{time.perf_counter() - started:6.1f} s] {line}", file=sys.stderr, flush=True)

    result = find_discrepancy(train, model, validation, settings, progress)
    summary = write_discrepancy_report(
        result, out, str(args.train), str(args.validate) if args.validate else None
    )
    gap = (
        f"; held-out {result.gap['horizon_s']:g} s position RMSE "
        f"{summary['gap_before']:.3f} -> {summary['gap_after']:.3f} m"
        if summary["gap_before"] is not None
        else ""
    )
    named = ", ".join([*result.effects, *(term.equation() for term in result.terms)])
    print(
        f"discrepancy: {result.verdict}{' ' + named if named else ''}{gap}; "
        f"{result.time_s:.0f} s; wrote {out}/report.json, report.md, params.yaml"
    )
    return 0


def add_arguments(sub: argparse.ArgumentParser) -> None:
    """``crs discrepancy``'s arguments."""
    sub.add_argument("train", type=Path, help="training recording: " + RECORDING_HELP)
    sub.add_argument("--validate", type=Path, help="held-out recording (the same kinds)")
    add_bag_options(sub)
    add_out(sub, "output folder", required=True)
    sub.add_argument(
        "--params",
        help="the current model's parameter YAML, or 'rough' (default: the Chronos values)",
    )
    add_effect(sub, "an effect the current model already has (repeatable)")
    add_model(sub)
    add_fit(sub, "parameters identified in every fit")
    sub.add_argument(
        "--candidates",
        help=f"comma-separated effects to test (default: all: {','.join(EFFECTS)})",
    )
    sub.add_argument(
        "--false-alarm-rate",
        type=bounded_number("false-alarm-rate", "", 0.0, 0.5),
        default=0.01,
        help="designed probability of a finding per round on data that need no effect "
        "(default 0.01)",
    )
    add_process_scale(
        sub,
        "factor on the FIE's process noise std (default 1.0 for real data; 0.1 suits simulated "
        "data, whose truth has no process noise)",
    )
    sub.add_argument(
        "--no-propose",
        action="store_true",
        help="do not propose terms beyond the registry (sparse regression on what the fit "
        "leaves, each term tested on held-out data as an effect is)",
    )
    sub.add_argument(
        "--workers",
        type=bounded_number("workers", "", 0, 64, int),
        default=min(2, os.cpu_count() or 1),
        help="processes fitting hypotheses at once (default: 2, or 1 on a one-core machine)",
    )


COMMAND = Command(
    "discrepancy",
    help="find the physical effect the model misses, add it, show the gap shrink",
    description="Identify the current model on TRAIN, diagnose its residuals channel by "
    "channel, fit every effect of the registry as a hypothesis and test it on held-out "
    "data (--validate, or the last 30 % of TRAIN) with a test designed for a false-alarm "
    "rate of --false-alarm-rate per round; propose terms beyond the registry from what the "
    "fit leaves and test them the same way; name the winner (or 'none', or 'unexplained' "
    "with the channel and regime of the misfit), and report the held-out gap before and "
    "after. Writes OUT/report.json, report.md, params.yaml (the final model: --params "
    "everywhere) and figures; one progress line per step on stderr.",
    arguments=add_arguments,
    handler=run_discrepancy,
)
