"""``crs bench bridge``: the stack against the direct simulator and against the emulated car.

Runs ``crs launch sim`` (:func:`launch_scripts.sim_stack.run_stack`: simulator node, estimator,
controller, recorder) and then ``crs launch car --emulate``
(:func:`launch_scripts.car_stack.run_car_stack`: the car emulator over loopback UDP, bridge,
estimator, controller, recorder), one car each, for the same wall-clock duration and noise seed,
each into a folder of its own, and puts side by side: laps and lap times, estimation RMSE (x, y,
yaw, vx, vy; against the simulator's ``ground_truth`` and the emulator's own truth log),
estimator deadline misses and updates, latencies (median, p95; the car run also sensor packet →
estimate → command packet, see :mod:`launch_scripts.car_stack`), the bridge's counts and the
emulator's summary, CPU per process once running and node deaths.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from crs_core.analysis.latency import input_chain_latency
from launch_scripts.car_stack import run_car_stack
from launch_scripts.sim_stack import StackOptions, run_stack

#: The report keys kept per run.
KEPT = ("cpu_percent", "cpu_percent_running", "peak_memory_mib", "node_deaths")


def bridge_benchmark(
    duration: float,
    work_dir: Path,
    estimator: str = "mhe",
    seed: int = 0,
    domain_id: int | None = None,
) -> dict[str, Any]:
    """Both runs (``work_dir/sim``, ``work_dir/emulated``); a JSON-ready dict."""
    # the same car as the emulator's: the simulator runs the onboard loop (steering servo),
    # which the emulator always runs
    options = StackOptions(estimator, onboard=True, seed=seed)
    print("[bench] direct simulator (crs launch sim)", flush=True)
    sim = run_stack(1, options, duration, work_dir / "sim", domain_id)
    from ros4crs.bag_replay import read_car

    sim["cars"]["car1"].setdefault("latency_ms", {})["sensor_to_input_chain"] = input_chain_latency(
        read_car(work_dir / "sim" / "bag", "/car1").receive_times
    )
    print("[bench] emulated car over UDP (crs launch car --emulate)", flush=True)
    car = run_car_stack(1, options, duration, work_dir / "emulated", True, None, domain_id)
    runs = {}
    for name, report in (("sim", sim), ("emulated", car)):
        runs[name] = {"car": report["cars"]["car1"], **{k: report[k] for k in KEPT if k in report}}
    return {
        "cars": 1,
        "estimator": estimator,
        "duration_s": duration,
        "seed": seed,
        "latency_definitions": car.get("latency_definitions", {}),
        "runs": runs,
    }


def _ms(latency: dict[str, Any], key: str) -> str:
    value = latency.get(key) or {}
    return f"{value['median']:.1f} / {value['p95']:.1f}" if value else "-"


def _pipeline_cpu(run: dict[str, Any]) -> str:
    cpu = run.get("cpu_percent_running") or run.get("cpu_percent") or {}
    return ", ".join(f"{name.rsplit('/', 1)[-1]} {value:g}" for name, value in cpu.items())


def _rows(result: dict[str, Any]) -> list[tuple[str, str, str]]:
    """The compared figures: (label with its unit, direct simulator, emulated car)."""
    sim, emu = result["runs"]["sim"], result["runs"]["emulated"]
    rows = []

    def row(label: str, key) -> None:
        rows.append((label, key(sim), key(emu)))

    def laps(run):
        times = ", ".join(f"{t:.2f}" for t in run["car"].get("lap_times_s", []))
        return f"{run['car'].get('laps_completed', 0)} ({times} s)"

    def rmse(component: str, factor: float):
        return lambda run: (
            f"{factor * run['car']['estimation_rmse'][component]:.1f}"
            if run["car"].get("estimation_rmse")
            else "-"
        )

    row("laps (lap times)", laps)
    row("RMSE x [mm]", rmse("x", 1e3))
    row("RMSE y [mm]", rmse("y", 1e3))
    row("RMSE yaw [mrad]", rmse("yaw", 1e3))
    row("RMSE vx / vy [mm/s]", lambda r: f"{rmse('vx', 1e3)(r)} / {rmse('vy', 1e3)(r)}")
    row(
        "deadline misses / updates",
        lambda r: (
            f"{r['car'].get('estimator_deadline_misses', 0)} / "
            f"{r['car'].get('estimator_updates', 0)}"
        ),
    )
    for key, label in (
        ("sensor_to_estimate", "sensor -> estimate [ms] med / p95"),
        ("sensor_to_input", "sensor -> input msg [ms]"),
        ("sensor_to_input_chain", "sensor -> input msg, via its stamp [ms]"),
        ("sensor_to_command_sent", "sensor pkt -> command sent [ms]"),
        ("sensor_to_command_read", "sensor pkt -> command read by car [ms]"),
        ("command_sent_to_read", "command sent -> read by car [ms]"),
    ):
        row(label, lambda r, key=key: _ms(r["car"].get("latency_ms", {}), key))
    row(
        "bridge received / commands sent",
        lambda r: (
            f"{r['car']['bridge_diagnostics']['received']} / "
            f"{r['car']['bridge_diagnostics']['sent']['commands']}"
            if r["car"].get("bridge_diagnostics")
            else "-"
        ),
    )
    row("node deaths", lambda r: str(len(r.get("node_deaths", []))))
    return rows


def _settings(result: dict[str, Any]) -> str:
    return f"1 car, {result['estimator']}, {result['duration_s']:g} s, seed {result['seed']}"


def format_table(result: dict[str, Any]) -> str:
    """The two runs side by side, for a person."""
    rows = _rows(result)
    width = max(len(label) for label, _, _ in rows)
    lines = [
        _settings(result),
        f"{'':{width}}  {'direct simulator':>36}  {'emulated car over UDP':>36}",
    ]
    lines += [f"{label:{width}}  {a:>36}  {b:>36}" for label, a, b in rows]
    lines.append(f"CPU % once running, sim: {_pipeline_cpu(result['runs']['sim'])}")
    lines.append(f"CPU % once running, emulated: {_pipeline_cpu(result['runs']['emulated'])}")
    return "\n".join(lines)


def format_markdown(result: dict[str, Any]) -> str:
    """The two runs side by side as the docs show them (Markdown): the rows of
    :func:`format_table`, then the CPU per process once running.

    Parameters
    ----------
    result : dict
        The benchmark's JSON (:func:`bridge_benchmark`): RMSE in m, m/s and rad, latencies in
        ms, CPU in % of one core.

    Returns
    -------
    str
        Markdown: a settings line and a table in the units its labels name.
    """
    lines = [
        f"{_settings(result)}.",
        "",
        "| | direct simulator | emulated car over UDP |",
        "|---|---|---|",
    ]
    lines += [f"| {label.replace('->', '→')} | {a} | {b} |" for label, a, b in _rows(result)]
    sim, emu = result["runs"]["sim"], result["runs"]["emulated"]
    lines.append(
        f"| CPU once running (% of one core) | {_pipeline_cpu(sim) or '-'} | "
        f"{_pipeline_cpu(emu) or '-'} |"
    )
    return "\n".join(lines)
