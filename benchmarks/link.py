"""``crs bench link``: racing over a Wi-Fi-like link on a busy machine (issue 25, "Must show").

For every link preset (:data:`chronos_bridge.impairment.PRESET_NAMES`) x CPU load (busy-looping
processes beside the stack, :func:`busy_loops`) x number of cars, one race of ``duration`` s of
``crs launch car --emulate`` (:func:`launch_scripts.car_stack.run_car_stack`, MHE, MPCC, torque
commands, ``EmulatedLink(both=PRESET)``) runs into a folder of its own, and per car:

- ``laps``, ``lap_times_s`` and ``mean_lap_s``: the mean of the *flying* laps (every lap after
  the first, which starts from standing; None with fewer than two laps), s, from the emulator's
  truth (``report.json``);
- ``off_track``: the emulator's **true** trajectory against the track's borders with the car's
  footprint (:func:`off_track`: seconds with any corner of the footprint outside, the largest
  distance outside, m, and the number of episodes);
- ``motor_cutoffs``: the emulator's cut-offs (no reference for 200 ms; its ``--truth-out`` log);
- ``rmse``: estimation RMSE x, y (m), yaw (rad) against the truth (``report.json``);
- ``qp_failure_seconds``: the controller's ``MPCC fallback`` / ``MPCC stop`` warnings in its log.
  The node logs them at most once a second, so this counts the seconds with at least one failed
  QP (a lower bound on the failures);
- ``reinitializations``: the estimator's re-initialisations (its diagnostics, in the bag);
- ``latency_ms``: sensor packet -> estimate -> command packet read by the car, median and p95
  (``sensor_to_command_read``, :mod:`launch_scripts.car_stack`);
- ``outages`` (every preset with outage windows): per window of the link (the union of both
  directions' windows, on the packet clock; :func:`outage_recovery`) whether the motors were cut
  during it, and the time from the link's return to **racing again**, defined as the first
  instant after the return at which (1) the car has read a reference sent after the return's
  first driving command (one that is not the supervisor's stop command, straight wheels and zero
  torque) and (2) its true speed is above :data:`RACING_SPEED` (0.5 m/s) and stays so for
  :data:`RACING_HOLD_S` (1 s: a car still coasting after the cut-off, which then stops, is not
  racing again; without it the first runs counted 0.04 s for a car that stood for 2 s). A
  window is evaluated only when the car was racing at its start (true speed above 0.5 m/s and a
  reference read in the 200 ms before) and the run lasted 1 s past its end (or the car recovered
  before that).

And per run the CPU (% of one core) of every process once running. The summary compares each run
with the clean run of the same load and number of cars (``lap_time_ratio``), and :func:`targets`
evaluates the issue's targets per run (booleans; None when they cannot be evaluated).
"""

from __future__ import annotations

import contextlib
import json
import signal
import socket
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.stack import busy_loops
from chronos_bridge.impairment import PRESET_NAMES
from crs_core.track import Track, load_demo_track
from launch_scripts.car_stack import EMULATOR_PORT, HOST_PORT, EmulatedLink, run_car_stack
from launch_scripts.sim_stack import StackOptions
from sim.closed_loop import off_track

#: True speed above which a car counts as racing, m/s.
RACING_SPEED = 0.5
#: The emulator's loop period, s (a cut-off is logged at the tick that finds the gap).
TICK_S = 0.004
#: How long before an outage a reference must have been read for the car to count as racing, s.
RACING_REFERENCE_S = 0.2
#: Targets of the issue: mean flying lap within this fraction of the clean run's.
LAP_TIME_TOLERANCE = 0.05
#: Targets: laps a car must complete in a ``bad`` race (40 s: about 5 laps when clean).
MIN_LAPS_BAD = 3
#: A car races again once its true speed stays above RACING_SPEED this long, s.
RACING_HOLD_S = 1.0
#: Targets: the longest time from the link's return to racing again, s.
MAX_RECOVERY_S = 1.0
#: The controller's log lines of a failed QP (the MPCC's fallback or stop).
QP_FAILURE_MARKERS = ("MPCC fallback", "MPCC stop")


def parse_counts(name: str, low: int, high: int):
    """A parser of ``N[,N...]`` (distinct integers in ``[low, high]``, kept in order) whose
    ``ValueError`` names ``--name``."""

    def parse(text: str) -> tuple[int, ...]:
        values = []
        for part in text.split(","):
            try:
                value = int(part.strip())
            except ValueError:
                raise ValueError(f"--{name}: {part.strip()!r} is not an integer") from None
            if not low <= value <= high:
                raise ValueError(f"--{name}: {value} must be within [{low}, {high}]")
            values.append(value)
        if len(set(values)) != len(values):
            raise ValueError(f"--{name}: {text!r} names a value twice")
        return tuple(values)

    parse.__name__ = name
    return parse


def parse_presets(text: str) -> tuple[str, ...]:
    """``PRESET[,PRESET...]`` -> the link presets (``ValueError`` naming ``--presets``)."""
    names = tuple(part.strip() for part in text.split(","))
    for name in names:
        if name not in PRESET_NAMES:
            raise ValueError(f"--presets: {name!r} is not a preset ({', '.join(PRESET_NAMES)})")
    if len(set(names)) != len(names):
        raise ValueError(f"--presets: {text!r} names a preset twice")
    return names


def free_ports(cars: int, attempts: int = 50) -> tuple[int, int]:
    """The bridge's and the emulator's UDP port of car 1 (car N: + N - 1) such that all are
    free on 127.0.0.1 now: the defaults (:data:`~launch_scripts.car_stack.HOST_PORT`,
    :data:`~launch_scripts.car_stack.EMULATOR_PORT`) if free, else 200, 400, ... above them
    (another stack on this machine keeps its ports). ``RuntimeError`` if none is."""

    def free(port: int) -> bool:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            try:
                probe.bind(("127.0.0.1", port))
            except OSError:
                return False
        return True

    for k in range(attempts):
        ports = (HOST_PORT + 200 * k, EMULATOR_PORT + 200 * k)
        if all(free(base + i) for base in ports for i in range(cars)):
            return ports
    raise RuntimeError(f"no free UDP ports for {cars} car(s) from {HOST_PORT} on")


@contextlib.contextmanager
def interrupt_flag() -> Iterator[list[bool]]:
    """SIGINT and SIGTERM during the block set ``flag[0]`` and raise ``KeyboardInterrupt``
    (the launcher takes it as its Ctrl-C and stops the race's nodes cleanly; the caller checks
    the flag after each race, since the launcher does not re-raise it)."""
    flag = [False]

    def handler(signum: int, frame: object) -> None:
        flag[0] = True
        raise KeyboardInterrupt

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def outage_windows(log: Any) -> np.ndarray:
    """The link's outage windows ``(k, 2)`` ``[start, end)`` (s, packet clock) from an emulator's
    ``--truth-out`` log: both directions' windows merged where they overlap."""
    windows = []
    for direction in ("up", "down"):
        start, end = f"link_{direction}_outage_start_t", f"link_{direction}_outage_end_t"
        if start in log and end in log:
            windows += list(zip(np.atleast_1d(log[start]), np.atleast_1d(log[end]), strict=True))
    merged: list[list[float]] = []
    for start, end in sorted((float(a), float(b)) for a, b in windows):
        if merged and start <= merged[-1][1]:
            merged[-1][1] = max(merged[-1][1], end)
        else:
            merged.append([start, end])
    return np.array(merged, dtype=float).reshape(-1, 2)


def driving_references(
    command_host_t: np.ndarray, input_t: np.ndarray, input_u: np.ndarray
) -> np.ndarray:
    """Per reference the car read: True when it carries a driving command, i.e. the newest
    host ``input`` stamped at or before its send stamp is not the stop command (``u == 0``);
    True when that input is unknown (no inputs recorded, or an unstamped reference)."""
    sent = np.asarray(command_host_t, dtype=float)
    input_t = np.asarray(input_t, dtype=float)
    driving = np.ones(sent.size, dtype=bool)
    if input_t.size == 0:
        return driving
    stop = np.all(np.asarray(input_u, dtype=float).reshape(-1, 2) == 0.0, axis=1)
    k = np.searchsorted(input_t, sent, side="right") - 1
    known = np.isfinite(sent) & (k >= 0)
    driving[known] = ~stop[k[known]]
    return driving


def outage_recovery(
    windows: np.ndarray,
    t: np.ndarray,
    speed: np.ndarray,
    pause_t: np.ndarray,
    read_t: np.ndarray,
    read_driving: np.ndarray | None = None,
) -> list[dict[str, Any]]:
    """Per outage window: was the car racing, were the motors cut, how long to race again.

    Parameters
    ----------
    windows : numpy.ndarray
        (k, 2) outage windows ``[start, end)``, s (:func:`outage_windows`).
    t, speed : numpy.ndarray
        (n,) the truth's stamps, s, and true speed ``hypot(v_x, v_y)``, m/s.
    pause_t : numpy.ndarray
        The emulator's motor cut-offs, s.
    read_t : numpy.ndarray
        When the car read each reference, s (increasing).
    read_driving : numpy.ndarray, optional
        Per reference read, whether it is a driving command (:func:`driving_references`);
        default all.

    Returns
    -------
    list of dict
        Per window: ``start``, ``end`` (s), ``racing_before`` (true speed above
        :data:`RACING_SPEED` at the start and a reference read in the
        :data:`RACING_REFERENCE_S` before), ``motors_cut`` (a cut-off in ``[start, end]``, one
        loop tick of slack), ``recovery_s`` (time from ``end`` to racing again, see the module
        docstring; None if not within the truth) and ``evaluated`` (racing before, and either
        recovered or the truth lasts :data:`MAX_RECOVERY_S` past ``end``).
    """
    t, speed = np.asarray(t, dtype=float), np.asarray(speed, dtype=float)
    pause_t, read_t = np.asarray(pause_t, dtype=float), np.asarray(read_t, dtype=float)
    driving = np.ones(read_t.size, bool) if read_driving is None else np.asarray(read_driving)
    out = []
    for start, end in np.asarray(windows, dtype=float).reshape(-1, 2):
        at_start = np.searchsorted(t, start)
        fast = at_start < t.size and speed[at_start] > RACING_SPEED
        fed = bool(np.any((read_t >= start - RACING_REFERENCE_S) & (read_t < start)))
        cut = bool(np.any((pause_t >= start) & (pause_t <= end + TICK_S)))
        recovery = None
        after = np.flatnonzero((read_t >= end) & driving)
        if after.size:
            since = _racing_from(t, speed, read_t[after[0]])
            if since is not None:
                recovery = round(since - end, 3)
        racing = bool(fast and fed)
        complete = recovery is not None or bool(t.size > 0 and t[-1] >= end + MAX_RECOVERY_S)
        out.append(
            {
                "start": round(float(start), 3),
                "end": round(float(end), 3),
                "racing_before": racing,
                "motors_cut": cut,
                "recovery_s": recovery,
                "evaluated": racing and complete,
            }
        )
    return out


def _racing_from(t: np.ndarray, speed: np.ndarray, start: float) -> float | None:
    """The first instant from ``start`` on after which the true speed stays above
    :data:`RACING_SPEED` for :data:`RACING_HOLD_S` (or to the end of the truth): a car still
    coasting after a cut-off is not racing, however fast it rolls for a moment."""
    above = speed > RACING_SPEED
    for i in np.flatnonzero((t >= start) & above):
        if i > 0 and above[i - 1] and t[i - 1] >= start:
            continue  # inside a run already checked
        stays = (t >= t[i]) & (t <= t[i] + RACING_HOLD_S)
        if np.all(above[stays]):
            return float(t[i])
    return None


def qp_failure_seconds(log_path: Path) -> int:
    """The controller log's lines reporting a failed QP (:data:`QP_FAILURE_MARKERS`; logged
    at most once a second, so: seconds with at least one failed QP)."""
    if not log_path.is_file():
        return 0
    text = log_path.read_text(errors="replace")
    return sum(any(m in line for m in QP_FAILURE_MARKERS) for line in text.splitlines())


def car_figures(report_car: dict[str, Any], run_dir: Path, car: int, track: Track) -> dict:
    """One car's figures of a finished run (see the module docstring)."""
    from ros4crs.bag_replay import read_car

    laps = report_car.get("lap_times_s", [])
    rmse = report_car.get("estimation_rmse") or {}
    chain = (report_car.get("latency_ms") or {}).get("sensor_to_command_read") or {}
    figures: dict[str, Any] = {
        "laps": report_car.get("laps_completed", 0),
        "lap_times_s": laps,
        "mean_lap_s": round(float(np.mean(laps[1:])), 3) if len(laps) >= 2 else None,
        "off_track": None,
        "motor_cutoffs": (report_car.get("motor_cutoffs") or {}).get("count"),
        "rmse": {k: rmse.get(k) for k in ("x", "y", "yaw")} if rmse else None,
        "qp_failure_seconds": qp_failure_seconds(run_dir / "logs" / f"car{car}_controller.log"),
        "reinitializations": report_car.get("estimator_reinitializations"),
        "latency_ms": {k: chain.get(k) for k in ("median", "p95")} if chain else None,
        "outages": [],
    }
    path = run_dir / f"truth_car{car}.npz"
    if not path.is_file():
        return figures
    with np.load(path) as log:
        t, x = log["t"], log["x"]
        figures["off_track"] = off_track(t, x, track)
        windows = outage_windows(log)
        if windows.size:
            contents = read_car(run_dir / "bag", f"/car{car}")
            input_t = np.array([s.stamp for s in contents.inputs])
            input_u = np.array([s.u for s in contents.inputs]).reshape(-1, 2)
            driving = driving_references(log["command_host_t"], input_t, input_u)
            speed = np.hypot(x[:, 3], x[:, 4]) if x.size else np.zeros(0)
            figures["outages"] = outage_recovery(
                windows, t, speed, log["pause_t"], log["command_read_t"], driving
            )
    return figures


def _run_row(preset: str, load: int, cars: int, report: dict[str, Any], run_dir: Path) -> dict:
    track = load_demo_track()
    per_car = {
        name: car_figures(report["cars"][name], run_dir, int(name[3:]), track)
        for name in sorted(report["cars"])
    }
    return {
        "preset": preset,
        "load": load,
        "cars": cars,
        "folder": str(run_dir),
        "per_car": per_car,
        "cpu_percent_running": report.get("cpu_percent_running") or report.get("cpu_percent"),
        "node_deaths": report.get("node_deaths", []),
    }


def mean_lap(row: dict[str, Any]) -> float | None:
    """The mean flying lap over the run's cars, s (None without one)."""
    laps = [lap for car in row["per_car"].values() for lap in car["lap_times_s"][1:]]
    return round(float(np.mean(laps)), 3) if laps else None


def targets(row: dict[str, Any], clean: dict[str, Any] | None) -> dict[str, bool | None]:
    """The issue's targets for one run (booleans; None: cannot be evaluated, e.g. no clean run
    of the same load and cars or no outage while racing). ``clean``: that clean run's row.

    typical: mean flying lap within 5 % of clean, 0 s off the track, 0 motor cut-offs; bad:
    every car >= :data:`MIN_LAPS_BAD` laps, 0 s off; outages: every evaluated outage cut the
    motors and the car raced again within :data:`MAX_RECOVERY_S` of the link's return, 0 s off.
    ``all``: False when a target is missed, else None when one cannot be evaluated, else True.
    Clean runs have none.
    """
    cars = list(row["per_car"].values())
    off = [c["off_track"]["seconds"] if c["off_track"] else None for c in cars]
    never_off = None if None in off else all(s == 0 for s in off)
    out: dict[str, bool | None] = {}
    if row["preset"] == "typical":
        mine, theirs = mean_lap(row), mean_lap(clean) if clean else None
        out["lap_within_5pct_of_clean"] = (
            None if mine is None or theirs is None else mine <= (1 + LAP_TIME_TOLERANCE) * theirs
        )
        out["never_off_track"] = never_off
        cutoffs = [c["motor_cutoffs"] for c in cars]
        out["no_motor_cutoffs"] = None if None in cutoffs else sum(cutoffs) == 0
    elif row["preset"] == "bad":
        out[f"at_least_{MIN_LAPS_BAD}_laps"] = all(c["laps"] >= MIN_LAPS_BAD for c in cars)
        out["never_off_track"] = never_off
    elif row["preset"] == "outages":
        evaluated = [w for c in cars for w in c["outages"] if w["evaluated"]]
        out["motors_cut_at_each_outage"] = (
            all(w["motors_cut"] for w in evaluated) if evaluated else None
        )
        out["racing_within_1s"] = (
            all(
                w["recovery_s"] is not None and w["recovery_s"] <= MAX_RECOVERY_S for w in evaluated
            )
            if evaluated
            else None
        )
        out["never_off_track"] = never_off
    if out:
        values = list(out.values())
        out["all"] = False if False in values else None if None in values else True
    return out


def summarise(rows: list[dict[str, Any]]) -> None:
    """Add ``mean_lap_s``, ``lap_time_ratio`` (to the clean run of the same load and cars),
    ``targets`` and ``issue_target`` (the rows the issue sets targets for: typical with one busy
    loop, bad and outages at every load) to every row, in place."""
    clean = {(r["load"], r["cars"]): r for r in rows if r["preset"] == "clean"}
    for row in rows:
        reference = clean.get((row["load"], row["cars"]))
        row["mean_lap_s"] = mean_lap(row)
        base = reference and mean_lap(reference)
        row["lap_time_ratio"] = (
            round(row["mean_lap_s"] / base, 3) if base and row["mean_lap_s"] else None
        )
        row["targets"] = targets(row, reference)
        row["issue_target"] = row["preset"] in ("bad", "outages") or (
            row["preset"] == "typical" and row["load"] == 1
        )


def link_benchmark(
    work_dir: Path,
    presets: Sequence[str] = PRESET_NAMES,
    loads: Sequence[int] = (0, 1, 2),
    car_counts: Sequence[int] = (1, 2),
    duration: float = 40.0,
    seed: int = 0,
    domain_id: int | None = None,
) -> dict[str, Any]:
    """Every preset x load x cars race (``work_dir/PRESET_loadL_carsN``); a JSON-ready dict
    with the settings, ``runs`` (one row each, :func:`summarise`) and ``interrupted`` (True
    when Ctrl-C or SIGTERM ended it early: the rows so far)."""
    matrix = [(p, load, c) for load in loads for c in car_counts for p in presets]
    rows: list[dict[str, Any]] = []
    interrupted = False
    try:
        with interrupt_flag() as flag:
            for k, (preset, load, cars) in enumerate(matrix, start=1):
                run_dir = work_dir / f"{preset}_load{load}_cars{cars}"
                ports = free_ports(cars)
                with busy_loops(load):
                    report = run_car_stack(
                        cars,
                        StackOptions("mhe", seed=seed),
                        duration,
                        run_dir,
                        True,
                        domain_id=domain_id,
                        link=EmulatedLink(both=preset, seed=seed),
                        ports=ports,
                    )
                if flag[0]:
                    raise KeyboardInterrupt
                rows.append(_run_row(preset, load, cars, report, run_dir))
                rows[-1]["ports"] = list(ports)
                summarise(rows)
                print(f"[bench link] {k}/{len(matrix)} {progress_line(rows[-1])}", flush=True)
    except KeyboardInterrupt:
        interrupted = True
        print("[bench link] interrupted: keeping the runs finished so far", flush=True)
    return {
        "estimator": "mhe",
        "controller": "mpcc",
        "duration_s": duration,
        "seed": seed,
        "presets": list(presets),
        "loads": list(loads),
        "cars": list(car_counts),
        "definitions": __doc__,
        "interrupted": interrupted,
        "runs": rows,
    }


def _cells(row: dict[str, Any]) -> list[str]:
    cars = list(row["per_car"].values())

    def worst(get, fmt: str) -> str:
        values = [get(c) for c in cars]
        values = [v for v in values if v is not None]
        return format(max(values), fmt) if values else "-"

    laps = "/".join(str(c["laps"]) for c in cars)
    lap = f"{row['mean_lap_s']:.2f}" if row.get("mean_lap_s") else "-"
    ratio = f"{row['lap_time_ratio']:.3f}" if row.get("lap_time_ratio") else "-"
    off = worst(lambda c: c["off_track"] and c["off_track"]["seconds"], ".2f")
    cut = worst(lambda c: c["motor_cutoffs"], "d")
    rmse = "/".join(
        worst(lambda c, k=k: c["rmse"] and 1e3 * c["rmse"][k], ".0f") for k in ("x", "y", "yaw")
    )
    qp = worst(lambda c: c["qp_failure_seconds"], "d")
    reinit = worst(lambda c: c["reinitializations"], "d")
    latency = "/".join(
        worst(lambda c, k=k: c["latency_ms"] and c["latency_ms"][k], ".0f")
        for k in ("median", "p95")
    )
    windows = [w for c in cars for w in c["outages"] if w["evaluated"]]
    if windows:
        recoveries = [w["recovery_s"] for w in windows if w["recovery_s"] is not None]
        slowest = f"{max(recoveries):.2f} s" if recoveries else "-"
        outages = f"{sum(w['motors_cut'] for w in windows)}/{len(windows)} cut, max {slowest}"
    else:
        outages = "-"
    met = row["targets"].get("all") if row.get("targets") else None
    verdict = "-" if not row.get("targets") else {True: "met", False: "MISSED", None: "?"}[met]
    return [
        row["preset"],
        str(row["load"]),
        str(row["cars"]),
        laps,
        lap,
        ratio,
        off,
        cut,
        rmse,
        qp,
        reinit,
        latency,
        outages,
        verdict
        + ("" if row.get("issue_target") or verdict == "-" else " (not a target)")
        + (f" ({len(row['node_deaths'])} node(s) died)" if row.get("node_deaths") else ""),
    ]


#: The columns of :func:`format_table`.
COLUMNS = (
    "preset",
    "busy loops",
    "cars",
    "laps",
    "mean flying lap [s]",
    "lap / clean",
    "off track [s]",
    "motor cut-offs",
    "RMSE x/y [mm] / yaw [mrad]",
    "QP failures [s]",
    "re-inits",
    "sensor→command med/p95 [ms]",
    "outages: cut, max return→racing",
    "targets",
)


def progress_line(row: dict[str, Any]) -> str:
    """One line per finished run."""
    return ", ".join(f"{name} {cell}" for name, cell in zip(COLUMNS, _cells(row), strict=True))


def format_table(result: dict[str, Any]) -> str:
    """A Markdown table, one row per run (several cars: laps per car, the worst car's other
    figures), then the settings and the CPU per process of each run."""
    lines = [
        "| " + " | ".join(COLUMNS) + " |",
        "|" + "|".join("---" for _ in COLUMNS) + "|",
    ]
    lines += ["| " + " | ".join(_cells(row)) + " |" for row in result["runs"]]
    lines.append("")
    lines.append(
        f"{result['duration_s']:g} s races, {result['estimator'].upper()} + "
        f"{result['controller'].upper()}, seed {result['seed']}"
        + (" (interrupted)" if result.get("interrupted") else "")
    )
    for row in result["runs"]:
        cpu = row.get("cpu_percent_running") or {}
        text = ", ".join(f"{name} {value:g}" for name, value in cpu.items())
        lines.append(
            f"CPU % once running, {row['preset']}, {row['load']} busy loop(s), "
            f"{row['cars']} car(s): {text}"
        )
    return "\n".join(lines)


def reanalysed(result: dict[str, Any]) -> dict[str, Any]:
    """``result`` with every run's figures computed again from its folder (its
    ``report.json``, truth and bag) by the current metric functions, and summarised again."""
    rows = []
    for old in result["runs"]:
        run_dir = Path(old["folder"])
        report = json.loads((run_dir / "report.json").read_text())
        row = _run_row(old["preset"], old["load"], old["cars"], report, run_dir)
        row["ports"] = old.get("ports")
        rows.append(row)
    summarise(rows)
    return {**result, "definitions": __doc__, "runs": rows}


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m benchmarks.link table FILE`` prints the Markdown table of a
    saved ``crs bench link`` JSON (the docs' table); ``reanalyse FILE`` computes its runs'
    figures again from their folders and rewrites FILE."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m benchmarks.link")
    parser.add_argument("action", choices=("table", "reanalyse"))
    parser.add_argument("file", type=Path)
    args = parser.parse_args(argv)
    result = json.loads(args.file.read_text())
    if args.action == "reanalyse":
        result = reanalysed(result)
        args.file.write_text(json.dumps(result, indent=2))
    print(format_table(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
