"""The whole stack against cars over UDP: emulated ones on loopback, or real ones over Wi-Fi.

``crs launch car --emulate`` runs, per car ``/carN``, the car emulator (``crs car-emulator``, a
plain process) and the same nodes as against a real car (``crs launch car --car-ip IP``):

- ``emulator`` (``--emulate`` only): binds 127.0.0.1:``EMULATOR_PORT + N - 1`` and sends to the
  bridge's port, seed ``SEED + N``, ``--truth-out OUT/truth_carN.npz`` (its ground truth and the
  link's timing log on the clock of its packet stamps); with an :class:`EmulatedLink`, its
  ``--link``/``--link-up``/``--link-down`` (a Wi-Fi-like link, :mod:`chronos_bridge.impairment`)
  and ``--link-seed LINK_SEED + N`` (default: derived from its own seed, so each car's link
  draws differ);
- ``bridge`` (:mod:`ros4crs.bridge_node`): port ``HOST_PORT + N - 1``; emulated: bound to
  127.0.0.1 and paired only with its emulator's address and port; a real car: bound to
  0.0.0.0 and paired only with that car's IP (any port);
- ``estimator`` (EKF or MHE, ``inputs: auto``: the controller's commands on ``input`` when they
  are torques), ``controller`` (MPCC on ``input``, torque or velocity references);
- one ``recorder`` (OUT/bag): as ``crs launch sim --record`` plus ``bridge/diagnostics``.

Then :func:`analyse_car_run` writes ``OUT/report.json`` per car: laps and lap times (from the
emulator's truth; from the estimates for a real car, marked ``laps_from``), estimation RMSE
against the emulator's truth, estimator deadline misses, latencies, the bridge's last
diagnostics and its final log line, the emulator's summary and motor cut-offs; and per process
CPU (% of one core) and peak memory. ``OUT/path.png`` as for ``crs launch sim`` (emulated cars).

Latencies (ms, median and p95; the packet stamps are the emulator's wall clock, which is the
host's, and the recorder's receive times the host's wall clock):

- ``sensor_to_estimate``, ``sensor_to_input``: as in ``crs launch sim``
  (:func:`crs_core.analysis.latency.latencies`; the sensor stamp is the car's packet stamp);
- ``sensor_to_command_read`` (**sensor packet → estimate → command packet**): for every
  reference the emulated car read, its read time (the emulator's wall clock at ``recvfrom``;
  it reads once per 4 ms tick, as the firmware's loop) minus the stamp of the newest sensor
  packet behind the estimate it was computed from. The chain is followed back through the
  stamps: the command packet's ``Packet.timestamp`` (the bridge's send time) → the newest
  ``input`` message stamped at or before it (the controller stamps its tick's start, right
  after taking the estimates that had arrived) → the newest estimate the recorder had received
  by that stamp (≈ the controller's receipt, both on loopback DDS) → the newest sensor packet
  stamped at or before that estimate's stamp (the estimator queries 20 ms in the past, so this
  includes its deliberate lag, as in ``crs launch sim``);
- ``sensor_to_command_sent``: the same chain ending at the bridge's send stamp, and
  ``command_sent_to_read``: bridge send → emulator read (UDP on loopback plus the wait for the
  emulator's next tick, 0–4 ms).
"""

from __future__ import annotations

import ipaddress
import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from chronos_bridge.impairment import parse_link
from chronos_bridge.link import CarLinkSettings
from crs_core.analysis.latency import LATENCY_DEFINITIONS, command_latencies, input_chain_latency
from crs_core.analysis.metrics import lap_statistics
from crs_core.track import load_demo_track
from launch_scripts.launcher import NodeSpec
from launch_scripts.sim_stack import (
    PIPELINE_PROCESS,
    RECORD_SETS,
    StackOptions,
    analyse,
    car_control_nodes,
    check_cars,
    controller_hold_safe,
    launch_and_report,
    read_cars,
    recorder_node,
    run_folder,
    write_online_parameters,
)
from launch_scripts.warm_cache import warm_compile_cache

if TYPE_CHECKING:
    from ros4crs.bag_replay import BagContents

#: The bridge of car N listens on ``HOST_PORT + N - 1`` (the bridge's default port first, the
#: firmware's default host port).
HOST_PORT = CarLinkSettings.port
#: The emulator of car N binds ``EMULATOR_PORT + N - 1`` (127.0.0.1).
EMULATOR_PORT = 20311
#: The bridge's own topic the recorder adds to the car's record set.
DIAGNOSTICS_TOPIC = "bridge/diagnostics"


@dataclass(frozen=True)
class EmulatedLink:
    """The emulated cars' link impairment: ``crs car-emulator``'s ``--link`` (both ways),
    ``--link-up`` (car -> host), ``--link-down`` (host -> car) specs (None: not given; all
    None: a clean link) and ``seed`` (car N gets ``--link-seed seed + N``; None: each
    emulator derives it from its own ``--seed``)."""

    both: str | None = None
    up: str | None = None
    down: str | None = None
    seed: int | None = None

    @property
    def given(self) -> bool:
        """True when any option is set."""
        return any(value is not None for value in asdict(self).values())

    def arguments(self, car: int) -> list[str]:
        """Car ``car``'s emulator options (checked: ``ValueError`` naming the option)."""
        parse_link(self.both, self.up, self.down)
        if self.seed is not None and self.seed < 0:
            raise ValueError(f"--link-seed: {self.seed} must be >= 0")
        arguments = []
        specs = (("--link", self.both), ("--link-up", self.up), ("--link-down", self.down))
        for option, value in specs:
            if value is not None:
                arguments += [option, value]
        if self.seed is not None:
            arguments += ["--link-seed", str(self.seed + car)]
        return arguments


def parse_car_ips(text: str) -> list[str]:
    """``IP[,IP...]`` -> the cars' IPv4 addresses (``ValueError`` naming ``--car-ip``)."""
    ips = [part.strip() for part in text.split(",")]
    for ip in ips:
        try:
            address = ipaddress.IPv4Address(ip)
        except ValueError:
            raise ValueError(f"--car-ip: {ip!r} is not an IPv4 address") from None
        if address.is_unspecified or address.is_multicast:
            raise ValueError(f"--car-ip: {ip} is not one car's address")
    if len(set(ips)) != len(ips):
        raise ValueError(f"--car-ip: {text!r} names a car twice")
    return ips


def car_nodes(
    cars: int,
    options: StackOptions,
    bag: Path,
    out: Path,
    emulate: bool,
    car_ips: list[str] | None = None,
    ports: tuple[int, int] = (HOST_PORT, EMULATOR_PORT),
    link: EmulatedLink = EmulatedLink(),
) -> list[NodeSpec]:
    """Process specs: per car (``/car1``...) bridge, estimator, controller as ``options`` say
    (:class:`StackOptions`; ``hold_safe`` by default
    :data:`~launch_scripts.sim_stack.HOLD_SAFE_OVER_A_LINK`, as over every link; the emulated
    cars' truth ``options.car``; a ``track_file`` refused: the cars race DEMO_TRACK, where the
    emulator starts), the emulator when ``emulate`` (started last: its car waits for
    references anyway; its truth log in ``out``), and one recorder into the bag ``bag``.
    ``car_ips``: one real car per address (not with ``emulate``). ``ports``: the bridge's and
    the emulator's port of car 1 (car N: + N - 1). ``link``: the emulators' link impairment.
    The visualizer with ``options.viz``.
    Only the nodes of ``options.part`` (an emulator with its bridge), and its Zenoh link."""
    if emulate == bool(car_ips):
        raise ValueError("car: either emulate or car_ips (one real car per address)")
    if link.given and not emulate:
        raise ValueError("--link: only for emulated cars (a real car's link is the real one)")
    car = options.car
    if (car.params_file or car.effects or car.model) and not emulate:
        raise ValueError("--car-params: only for emulated cars (a real car is what it is)")
    if car_ips and len(car_ips) != cars:
        raise ValueError(f"cars: {cars} cars need {cars} addresses, got {len(car_ips)}")
    if options.track_file is not None:
        raise ValueError("track_file: the car stack races DEMO_TRACK (where the emulator starts)")
    check_cars(cars)
    per_car, global_topics = RECORD_SETS[options.record]
    files = options.files()
    # the emulated cars' own model and parameters (the stack's file only if it is of their model)
    truth = options.truth() if emulate else car
    nodes, emulators, topics = [], [], list(global_topics)
    for i in range(1, cars + 1):
        ns, host_port = f"/car{i}", ports[0] + i - 1
        if emulate:
            car_port = ports[1] + i - 1
            bridge = {"port": host_port, "car_ip": "127.0.0.1", "car_port": car_port}
            arguments = ["--host", "127.0.0.1", "--host-port", str(host_port)]
            arguments += ["--port", str(car_port), "--seed", str(options.seed + i)]
            arguments += ["--truth-out", str(Path(out).resolve() / f"truth_car{i}.npz")]
            arguments += link.arguments(i)
            arguments += truth.emulator_arguments()
            emulators.append(
                NodeSpec(
                    "emulator",
                    "chronos_bridge.emulator_process",
                    ns,
                    arguments=arguments,
                    stops_first=True,
                )
            )
        else:
            bridge = {"port": host_port, "bind": "0.0.0.0", "car_ip": car_ips[i - 1]}
        nodes += [
            NodeSpec(
                "bridge", "ros4crs.bridge_node", ns, bridge, process=options.pipeline_process()
            ),
            # what the car applied, not what was sent (late, lost or cut over Wi-Fi)
            *car_control_nodes(ns, options, files, over_udp=True, input_topic="input/applied"),
        ]
        topics += [f"{ns}/{topic}" for topic in (*per_car, DIAGNOSTICS_TOPIC)]
    nodes += [recorder_node(bag, topics), *options.visualizer(cars)]
    return options.part.launched([*nodes, *emulators], "car")


def run_car_stack(
    cars: int,
    options: StackOptions,
    duration: float,
    out: Path,
    emulate: bool,
    car_ips: list[str] | None = None,
    domain_id: int | None = None,
    ports: tuple[int, int] = (HOST_PORT, EMULATOR_PORT),
    link: EmulatedLink = EmulatedLink(),
) -> dict[str, Any]:
    """Run the stack against the cars (:func:`car_nodes`) for ``duration`` s in ROS domain
    ``domain_id`` (:func:`launch_scripts.sim_stack.run_folder`), then write ``out/report.json``
    (``link``: the emulators' link impairment, recorded in it; a part without the recorder:
    no bag analysis, :func:`launch_scripts.sim_stack.launch_and_report`)."""
    out, bag, domain = run_folder(out, domain_id)
    nodes = car_nodes(cars, options, bag, out, emulate, car_ips, ports, link)
    estimator = options.estimator
    model = options.model_spec()
    car_model = options.truth().model if emulate else None  # a real car is what it is
    warm_compile_cache(
        estimator,
        options.controller,
        options.output,
        options.params_file,
        car_effects=options.car.effects,
        model=model,
        car_model=car_model,
    )
    recorded = options.part.runs("recorder")
    what = "emulated car(s) on loopback UDP" if emulate else f"car(s) at {', '.join(car_ips)}"
    contents_of: dict[str, BagContents] = {}  # the bag read once, for the report and the figure

    def analyse_run() -> dict[str, Any]:
        contents_of.update(read_cars(bag, cars))
        write_online_parameters(contents_of, out, options.params_file, model)
        return analyse_car_run(contents_of, bag, cars, out, emulate)

    report = launch_and_report(
        nodes,
        domain,
        out,
        duration,
        f"{len(nodes)} processes, {cars} {what}",
        options.after_start_up,
        analyse_run if recorded else None,
        {
            "mode": "emulated" if emulate else "real",
            "car_ips": car_ips or [],
            "estimator": estimator,
            "controller": options.controller,
            "output": options.output,
            "model": model,
            "hold_safe": controller_hold_safe(options, over_udp=True),
            "duration_s": duration,
            "recorded": options.record,
            "seed": options.seed,
            "link": asdict(link),
            "car_truth": replace(options.car, model=car_model).described(),
            "part": options.part.described(),
        },
    )
    if emulate and recorded:
        from launch_scripts.stack_plot import StateTrack, plot

        truths = {}
        for i in range(1, cars + 1):
            t, x = _truth(out, i)
            if t.size:
                truths[i] = StateTrack(t, x, np.full_like(x, np.nan))
        if truths:
            title = f"ROS 2 stack against {cars} emulated car(s) over UDP: {estimator.upper()} "
            title += "vs the emulator's truth"
            plot(contents_of, cars, out, estimator, None, truths, title)
    return report


def _truth(out: Path, car: int) -> tuple[np.ndarray, np.ndarray]:
    path = Path(out) / f"truth_car{car}.npz"
    if not path.is_file():
        return np.zeros(0), np.zeros((0, 6))
    with np.load(path) as log:
        return log["t"], log["x"]


def analyse_car_run(
    contents_of: dict[str, BagContents], bag: Path, cars: int, out: Path, emulate: bool
) -> dict[str, Any]:
    """``report.json``'s per-car part (see the module docstring) from ``contents_of``, what the
    bag holds of each car (:func:`~launch_scripts.sim_stack.read_cars`)."""
    track = load_demo_track()
    truths = {}
    if emulate:
        for i in range(1, cars + 1):
            t, x = _truth(out, i)
            if t.size >= 2:
                truths[f"car{i}"] = (t, x)
    report = analyse(contents_of, cars, track, truths)
    diagnostics = last_diagnostics(bag, cars)
    for i in range(1, cars + 1):
        name = f"car{i}"
        car = report["cars"][name]
        car["bridge_diagnostics"] = diagnostics.get(name)
        # the bridge's own log, or its car's shared pipeline process's (its logger's lines)
        logs = [out / "logs" / f"car{i}_{stem}.log" for stem in ("bridge", PIPELINE_PROCESS)]
        marker = f"[car{i}.bridge]: stopping: "
        car["bridge_final_log"] = next(
            (line for log in logs if (line := _last_line(log, marker)) is not None), None
        )
        if emulate:
            car["laps_from"] = "emulator truth"
            car["emulator_summary"] = _last_line(
                out / "logs" / f"car{i}_emulator.log", "crs car-emulator: stopped"
            )
            log_path = out / f"truth_car{i}.npz"
            if log_path.is_file():
                with np.load(log_path) as log:
                    car["motor_cutoffs"] = cutoffs(log)
                    times = contents_of[name].receive_times
                    car["latency_ms"].update(command_latencies(times, log))
                    car["latency_ms"]["sensor_to_input_chain"] = input_chain_latency(times)
        else:
            car["laps_from"] = "estimates (no truth from a real car)"
            estimates = contents_of[name].estimates
            if len(estimates) >= 2:
                stamps = np.array([t for t, _ in estimates])
                states = np.array([x for _, x in estimates])
                moving = np.flatnonzero(states[:, 3] > 0.05)
                start = int(moving[0]) if moving.size else 0
                laps = lap_statistics(stamps[start:], states[start:], track, line_tolerance=0.05)
                car["laps_completed"] = laps["laps_completed"]
                car["lap_times_s"] = laps["lap_times_s"]
    report["latency_definitions"] = LATENCY_DEFINITIONS
    return report


def cutoffs(log: Any) -> dict[str, Any]:
    """The emulator's motor cut-offs: how many, the time from the last reference (ms) and how
    many times references came back."""
    gaps = (np.asarray(log["pause_t"]) - np.asarray(log["pause_last_command_t"])) * 1e3
    return {
        "count": int(gaps.size),
        "after_last_reference_ms": [round(float(g), 1) for g in gaps],
        "resumed": int(np.asarray(log["resume_t"]).size),
    }


def last_diagnostics(bag: Path, cars: int) -> dict[str, Any]:
    """Per car, the bridge's last ``bridge/diagnostics`` JSON in the bag."""
    from ros4crs.bag_repair import open_bag
    from ros4crs.interfaces import typestore

    store = typestore()
    wanted = {f"/car{i}/{DIAGNOSTICS_TOPIC}": f"car{i}" for i in range(1, cars + 1)}
    out: dict[str, Any] = {}
    with open_bag(bag) as reader:
        connections = [c for c in reader.connections if c.topic in wanted]
        for connection, _, data in reader.messages(connections) if connections else ():
            msg = store.deserialize_cdr(bytes(data), connection.msgtype)
            try:
                out[wanted[connection.topic]] = json.loads(msg.data)
            except ValueError:
                continue
    return out


def _last_line(path: Path, marker: str) -> str | None:
    if not path.is_file():
        return None
    lines = [ln for ln in path.read_text(errors="replace").splitlines() if marker in ln]
    return lines[-1].strip() if lines else None


def summary(report: dict[str, Any], out: Path) -> str:
    """A few lines for a person (as ``crs launch sim``'s, plus latencies and the link)."""
    from launch_scripts.sim_stack import summary as sim_summary

    lines = sim_summary(report, out).splitlines()
    extra = []
    for name, car in report["cars"].items():
        latency = car.get("latency_ms", {})
        chain = latency.get("sensor_to_command_read") or {}
        diag = car.get("bridge_diagnostics") or {}
        cut = car.get("motor_cutoffs") or {}
        extra.append(
            f"{name}: sensor packet -> command packet median {chain.get('median', '-')} ms, "
            f"p95 {chain.get('p95', '-')} ms; bridge received {diag.get('received', '-')}, "
            f"sent {diag.get('sent', '-')}; motor cut-offs {cut.get('count', '-')}"
        )
    return "\n".join(lines[: len(report["cars"])] + extra + lines[len(report["cars"]) :])
