"""``crs bench machines``: the stack split across two machines over the Zenoh link, next to the
same stack on one machine.

The one-machine run is :func:`launch_scripts.sim_stack.run_stack` (``crs launch sim``, DDS on
loopback). The split run is two ``crs launch sim`` parts in two network namespaces joined by a
veth pair (:mod:`benchmarks.netns`; needs root): namespace A runs ``--nodes simulator,recorder``
and listens (``--zenoh-open``: the veth reaches nothing but B), namespace B runs ``--nodes
estimator,controller`` and connects, so every sensor reading crosses to B and every estimate and
command back to A. Per run: laps, position RMSE, the sensor -> input latency (median / p95: the
recorder's receive times of a command and of the readings it was computed from; across machines
a round trip over the link) and CPU per node; for the link, its bytes per second each way on the
veth (Ethernet frames, so every header is counted) and the CPU of the ``zenoh_link`` node on each
side. One car: the link figures are per car.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from benchmarks.netns import NetnsPair, netns_pair
from launch_scripts.sim_stack import StackOptions, rmse_text, run_stack

#: The two parts of the split and their nodes.
PARTS = {"A": "simulator,recorder", "B": "estimator,controller"}
#: Zenoh port of part A's listener.
PORT = 7447
ROOT = Path(__file__).resolve().parents[1]


@contextmanager
def split_stack(
    pair: NetnsPair,
    out: Path,
    duration: float,
    domain: int,
    estimator: str = "mhe",
    port: int = PORT,
    after_start_up: bool = False,
) -> Iterator[dict[str, subprocess.Popen]]:
    """The two parts of :data:`PARTS` launched in ``pair``'s namespaces for ``duration`` s
    (from the moment each part's processes have started with ``after_start_up``)
    (``crs launch sim --nodes ... --zenoh-listen/--zenoh-connect``, ROS domain ``domain`` in
    each, reports in ``out/A`` and ``out/B``, their output in ``out/A.txt`` and ``out/B.txt``);
    yields the processes by part, and kills any still running when the block ends. A listens
    unauthenticated (``--zenoh-open``, one warning line in ``out/A.txt``): its veth address
    reaches B only, and the run measures the link, not who may join it."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    endpoint = f"tcp/{pair.address_a}:{port}"
    joins = {"A": ["--zenoh-listen", endpoint, "--zenoh-open"], "B": ["--zenoh-connect", endpoint]}
    processes: dict[str, subprocess.Popen] = {}
    try:
        for part, nodes in PARTS.items():
            argv = [sys.executable, "-m", "launch_scripts.cli", "launch", "sim"]
            argv += ["--estimator", estimator, "--nodes", nodes, *joins[part]]
            argv += ["--duration", f"{duration:g}", "--out", str(out / part)]
            argv += ["--after-start-up"] if after_start_up else []
            with (out / f"{part}.txt").open("w") as log:
                processes[part] = subprocess.Popen(
                    pair.command(pair.a if part == "A" else pair.b, argv),
                    cwd=ROOT,
                    env=env,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                )
        yield processes
    finally:
        for process in processes.values():
            if process.poll() is None:
                process.kill()
            process.wait()


def machines_benchmark(duration: float, work_dir: Path, domain: int = 42) -> dict[str, Any]:
    """Run the one-machine stack, then the split one, each for ``duration`` s (one car, MHE).

    Returns a JSON-ready dict: ``duration_s``; ``one_machine`` and ``two_machines`` (``car``:
    the car's entry of the report, ``cpu_percent_running`` per node; the two machines' nodes
    but their links); ``link``: ``bytes_per_s`` (``a_to_b``, ``b_to_a``) and ``cpu_percent``
    (the ``zenoh_link`` node in ``A`` and ``B``).
    Raises :class:`~benchmarks.netns.NetnsUnavailableError` where namespaces cannot be made.
    """
    print("[bench] one machine", flush=True)
    one = run_stack(1, StackOptions("mhe", seed=1), duration, work_dir / "one", domain)
    print("[bench] two machines", flush=True)
    out = work_dir / "two"
    out.mkdir(parents=True, exist_ok=True)
    with netns_pair() as pair, split_stack(pair, out, duration, domain) as processes:
        sent, received = pair.bytes_from_a()
        started = time.monotonic()
        codes = {part: process.wait(timeout=duration + 300) for part, process in processes.items()}
        elapsed = time.monotonic() - started
        sent_end, received_end = pair.bytes_from_a()
    if any(codes.values()):
        raise RuntimeError(f"a part failed: exit codes {codes}; see {out}/A.txt and B.txt")
    reports = {part: json.loads((out / part / "report.json").read_text()) for part in PARTS}
    cpu = {part: reports[part].get("cpu_percent_running", {}) for part in PARTS}
    return {
        "duration_s": duration,
        "one_machine": _kept(one),
        "two_machines": {
            **_kept(reports["A"]),
            "cpu_percent_running": {
                node: value
                for part in PARTS
                for node, value in cpu[part].items()
                if node != "/zenoh_link"
            },
        },
        "link": {
            "bytes_per_s": {
                "a_to_b": round((sent_end - sent) / elapsed),
                "b_to_a": round((received_end - received) / elapsed),
            },
            "cpu_percent": {part: cpu[part].get("/zenoh_link") for part in PARTS},
        },
    }


def _kept(report: dict[str, Any]) -> dict[str, Any]:
    return {
        "car": report["cars"]["car1"],
        "cpu_percent_running": report.get("cpu_percent_running", {}),
        "node_deaths": report.get("node_deaths", []),
    }


def format_table(result: dict[str, Any]) -> str:
    """A few lines for a person."""
    lines = [f"one car, MHE, {result['duration_s']:g} s per run"]
    for name in ("one_machine", "two_machines"):
        car = result[name]["car"]
        latency = car["latency_ms"]["sensor_to_input"]
        lines.append(
            f"  {name.replace('_', ' ')}: {car['laps_completed']} laps; "
            f"{rmse_text(car.get('estimation_rmse'))}; sensor -> input "
            f"{latency['median']:.1f} / {latency['p95']:.1f} ms (median / p95)"
        )
    link = result["link"]
    lines.append(
        f"  link: {link['bytes_per_s']['a_to_b'] / 1e3:.1f} kB/s A -> B, "
        f"{link['bytes_per_s']['b_to_a'] / 1e3:.1f} kB/s B -> A; zenoh_link CPU "
        f"{link['cpu_percent']['A']} % (A), {link['cpu_percent']['B']} % (B)"
    )
    return "\n".join(lines)


def format_markdown(result: dict[str, Any]) -> str:
    """The docs' table: one row per setting (laps, RMSE x / y, sensor -> input latency, CPU of
    the car's nodes), then the link's bandwidth and CPU."""
    rows = [
        "| where | laps (lap time) | RMSE x / y | sensor → input (median / p95) | CPU of the "
        "car's nodes | CPU of the link |",
        "|---|---|---|---|---|---|",
    ]
    link = result["link"]
    for name, label in (("one_machine", "one machine (DDS)"), ("two_machines", "two (Zenoh)")):
        run = result[name]
        car, cpu = run["car"], run["cpu_percent_running"]
        rmse = car.get("estimation_rmse") or {}
        latency = car["latency_ms"]["sensor_to_input"]
        nodes = sum(v for k, v in cpu.items() if k.startswith("/car1/"))
        link_cpu = (
            f"{link['cpu_percent']['A']:g} + {link['cpu_percent']['B']:g} %"
            if name == "two_machines"
            else "–"
        )
        times = car.get("lap_times_s") or []
        lap_time = f" ({min(times):.2f}–{max(times):.2f} s)" if times else ""
        rows.append(
            f"| {label} | {car['laps_completed']}{lap_time} | "
            f"{1e3 * rmse.get('x', float('nan')):.2f} / {1e3 * rmse.get('y', float('nan')):.2f} mm"
            f" | {latency['median']:.1f} / {latency['p95']:.1f} ms | {nodes:.1f} % | {link_cpu} |"
        )
    rows += [
        "",
        f"{result['duration_s']:g} s per run, one car, MHE. The link carried "
        f"{link['bytes_per_s']['a_to_b'] / 1e3:.1f} kB/s from A (simulator, recorder) to B "
        f"(estimator, controller) and {link['bytes_per_s']['b_to_a'] / 1e3:.1f} kB/s back "
        "(Ethernet frames on the veth, every header counted).",
    ]
    return "\n".join(rows)
