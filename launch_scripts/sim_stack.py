"""The whole stack in simulation: simulator, estimator and controller per car, plus a recorder.

``crs launch sim`` runs it for a duration and writes ``report.json`` (per car: laps, lap times,
estimation RMSE against the simulator's ground truth, estimator deadline misses, end-to-end
latencies) and plots, from the recorded bag.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from crs_core.analysis.latency import latencies
from crs_core.analysis.metrics import interpolate_pose, lap_statistics, state_rmse
from crs_core.control.overload import OverloadSettings
from crs_core.model.effects import effect_text
from crs_core.track import Track, load_demo_track, read_track
from launch_scripts.launcher import Launcher, NodeSpec
from launch_scripts.stack_models import car_model_and_parameters, model_spec
from launch_scripts.stack_part import StackPart
from launch_scripts.stack_plot import plot
from launch_scripts.visualizer import VizSettings, visualizer_node
from launch_scripts.warm_cache import warm_compile_cache
from sim.closed_loop import off_track

if TYPE_CHECKING:
    from ros4crs.bag_replay import BagContents

#: What ``crs launch --record`` records, per car (relative topics) and globally. ``all``:
#: everything, so the bag replays the estimator offline to its estimates exactly
#: (:mod:`ros4crs.bag_replay`) and Foxglove / PlotJuggler show the run (IMU, Odometry, TF).
#: ``estimates``: what the report and the plots need (truth, estimates, inputs, TF), without the
#: 250 Hz sensor streams. ``sensors``: the sensor streams and inputs (an estimator's input) with
#: the truth, without the estimates.
RECORD_SETS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "all": (("sensors/", "input", "ground_truth", "estimate/"), ("/tf",)),
    "estimates": (("input", "ground_truth", "estimate/"), ("/tf",)),
    "sensors": (("sensors/", "input", "ground_truth"), ()),
}
#: The controllers' ``hold_safe`` where their commands may cross a link (UDP to the car, Zenoh
#: to another machine) unless :attr:`StackOptions.hold_safe` gives one: the first outage can
#: come at any time (:mod:`crs_core.control.contingency`; a cable pulled as the simulated car
#: entered a bend at 1.6 m/s let it coast off the track and out of the Lighthouse's view).
HOLD_SAFE_OVER_A_LINK = "always"
#: The CPU of the running stack (``cpu_percent_running``) is counted from this long after the
#: run's duration began to count (the launch, or with ``after_start_up`` the moment every process
#: had started; at most a quarter of the run), s: before, the nodes import, discover each other
#: and wait for the simulator's clock, which makes a short run's average look cheaper.
SETTLE_S = 10.0
#: With :attr:`StackOptions.after_start_up` a run's duration counts from the moment all its
#: processes have started, or from this long after the launch, s (their start-up took 3-5 s on
#: an idle machine, 15 s beside two busy loops, and ate a short run's racing).
STARTUP_LIMIT_S = 60.0
#: ``report.json``'s ``bag_analysis`` of a part of a stack without the recorder.
NO_BAG = "none on this machine: the recorder runs on another one (its report analyses the run)"
#: The process a car's simulator or bridge, estimator and controller share (``/car1/pipeline``)
#: unless :attr:`StackOptions.process_per_node`.
PIPELINE_PROCESS = "pipeline"
#: The nodes of a car's pipeline (the simulator or, on a car, the bridge).
PIPELINE_NODES = ("simulator", "bridge", "estimator", "controller")
#: What the controllers command: ``torque`` (``[delta, T]``) or ``velocity`` (``[delta, v_x]``
#: references for the car's onboard velocity PID; MPCC only).
OUTPUTS = ("torque", "velocity")


@dataclass(frozen=True)
class CarTruth:
    """The simulated or emulated cars' own truth, where it differs from the stack's model.

    Attributes
    ----------
    params_file : Path or None
        Their parameter YAML (None: the stack's ``params_file`` when it is a file of their
        model, else their model's defaults: :mod:`launch_scripts.stack_models`).
    effects : tuple
        Their hidden effects, parsed (:func:`crs_core.model.effects.parse_effect`).
    drift_file : Path or None
        A schedule of changes to their truth while they race (:mod:`sim.drift`; None: none).
    model : str or None
        Their model, a spec (:func:`~crs_core.model.plants.load_plant`; None: the one their
        ``params_file`` names, else the dynamic bicycle; never the stack's model).
    """

    params_file: Path | None = None
    effects: tuple[tuple[str, str | None, float | None], ...] = ()
    drift_file: Path | None = None
    model: str | None = None

    def resolved(self, stack_params: Path | None) -> CarTruth:
        """This truth with its model (a canonical spec) and its parameter file (its own, else
        ``stack_params`` when that is a file of its model, else None) decided
        (:func:`~launch_scripts.stack_models.car_model_and_parameters`)."""
        model, params = car_model_and_parameters(self.model, self.params_file, stack_params)
        return replace(self, model=model, params_file=params)

    def simulator_parameters(self) -> dict[str, str]:
        """The simulator node's ``model``, ``params_file``, ``effects`` and ``drift_file`` for
        this truth (none: its defaults)."""
        out = {"model": self.model} if self.model else {}
        if self.params_file:
            out["params_file"] = str(Path(self.params_file).resolve())
        if self.effects:
            out["effects"] = ",".join(effect_text(e) for e in self.effects)
        if self.drift_file:
            out["drift_file"] = str(Path(self.drift_file).resolve())
        return out

    def described(self) -> dict[str, Any]:
        """For a report: the model, the parameter file, the effects and the drift schedule
        (None / None / [] / None: the defaults, unchanging)."""
        return {
            "model": self.model,
            "params_file": str(self.params_file) if self.params_file else None,
            "effects": [effect_text(e) for e in self.effects],
            "drift_file": str(self.drift_file) if self.drift_file else None,
        }

    def emulator_arguments(self) -> list[str]:
        """``crs car-emulator``'s ``--model``, ``--params``, ``--effect`` and ``--drift`` for
        this truth."""
        out = ["--model", self.model] if self.model else []
        if self.params_file:
            out += ["--params", str(Path(self.params_file).resolve())]
        for effect in self.effects:
            out += ["--effect", effect_text(effect)]
        if self.drift_file:
            out += ["--drift", str(Path(self.drift_file).resolve())]
        return out


@dataclass(frozen=True)
class StackOptions:
    """What a stack runs on every car, the same for simulated, emulated and real cars: the
    options :func:`stack_nodes`, :func:`run_stack`, :func:`launch_scripts.car_stack.car_nodes`
    and :func:`launch_scripts.car_stack.run_car_stack` share (``crs launch``'s). The number of
    cars, the bag, the output folder, the duration, the ROS domain and the car stack's
    addresses, ports and link are each run's own arguments.

    Made checked (``ValueError`` naming the field): ``estimator``, ``output``, ``record``.

    Attributes
    ----------
    estimator : {"ekf", "mhe"}
        Each car's estimator node.
    controller : {"mpcc", "path"}
        ``mpcc``: racing, 30 Hz; ``path``: the centreline follower at 1 m/s, 50 Hz.
    output : {"torque", "velocity"}
        What the controllers command (:data:`OUTPUTS`): ``torque`` (``[delta, T]``; the
        default stack passes the controller no ``output``, the node's default) or ``velocity``
        (``[delta, v_x]``: a steering angle and a velocity reference, m/s, for the car's onboard
        velocity PID, which the simulators then run, ``onboard: true``; the estimators ignore
        such commands and estimate the inputs). The simulated stack refuses it with the path
        controller (which commands torque).
    record : {"all", "estimates", "sensors"}
        What the bag records, a key of :data:`RECORD_SETS`.
    blind_start : bool
        The estimators ignore the known start pose and initialise themselves from the
        Lighthouse (the car waits, its controller seeing no estimate, until they have).
    params_file : Path or None
        The cars' parameter YAML, for every car's nodes: the model of the estimator and the
        controller, and the simulated or emulated truth unless ``car`` has its own or is of
        another model (None: the model's defaults).
    model : str or None
        The estimators' and controllers' model, a spec
        (:func:`~crs_core.model.plants.load_plant`; None: the one ``params_file`` names under
        ``model:``, else the dynamic bicycle). The simulated or emulated cars' is ``car.model``.
    track_file : Path or None
        Track YAML (CRS format) for every car's nodes (None: DEMO_TRACK). Simulated cars only:
        the car stack races DEMO_TRACK (where the emulator starts) and refuses it.
    hold_safe : {"after_outage", "always", "never"} or None
        The controllers' ``hold_safe`` (:data:`crs_core.control.supervisor.HOLD_SAFE_MODES`).
        None: the stack's default, :data:`HOLD_SAFE_OVER_A_LINK` where the commands may cross
        a link (over UDP, or a part of the stack with a Zenoh link: the first outage can come
        at any time there), else the node's own (``after_outage``).
    onboard : bool
        Simulated cars only: the simulators run the car's onboard loop also for torque commands
        (its steering servo then moves the wheels, as on the emulator and a real car, which
        always run it: the car stack ignores the option).
    car : CarTruth
        The simulated or emulated cars' own truth where it is not ``params_file`` (a real car
        takes none: the car stack refuses it without ``emulate``).
    seed : int
        Noise seed: car N's simulator or emulator uses ``seed + N``.
    part : StackPart
        The nodes that run on this machine and its Zenoh link (default: all, no link).
    viz : VizSettings or None
        Add the ``visualizer`` node serving as these settings say (None: no visualizer).
    process_per_node : bool
        Every node in a process of its own (for debugging: a node's own log, profile and CPU
        figure); by default a car's simulator or bridge, estimator and controller share one
        (:data:`PIPELINE_PROCESS`, :mod:`ros4crs.composed`), the topics on the wire the same.
    after_start_up : bool
        A run's duration counts from the moment every process has started (at most
        :data:`STARTUP_LIMIT_S` after the launch), not from the launch: a loaded machine's
        start-up does not eat a short run (the tests' way; ``crs launch --after-start-up``).
    online_parameters : tuple of str
        Parameters every car's estimator estimates online (:mod:`crs_core.model.online`;
        published on ``estimate/parameters``, written to ``online_parameters_carN.csv``).
    drive_file : Path, optional
        A ``drive.yaml`` of ``crs plan-drive`` every car's controller drives (the path
        follower plus its command offsets; the ``path`` controller's ``drive_file``).
    drive_after : float
        With ``drive_file``: the follower alone drives this long first, s (``drive_after``).
    """

    estimator: str
    controller: str = "mpcc"
    output: str = "torque"
    record: str = "all"
    blind_start: bool = False
    params_file: Path | None = None
    track_file: Path | None = None
    hold_safe: str | None = None
    onboard: bool = False
    car: CarTruth = CarTruth()
    seed: int = 0
    part: StackPart = field(default_factory=StackPart)
    viz: VizSettings | None = None
    process_per_node: bool = False
    after_start_up: bool = False
    online_parameters: tuple[str, ...] = ()
    drive_file: Path | None = None
    drive_after: float = 0.0
    model: str | None = None

    def model_spec(self) -> str:
        """The estimators' and controllers' model, a canonical spec (errors name
        ``--model``: :func:`~launch_scripts.stack_models.model_spec`)."""
        return model_spec(self.model, self.params_file)

    def truth(self) -> CarTruth:
        """The simulated or emulated cars' truth, its model and parameter file decided
        (:meth:`CarTruth.resolved`)."""
        return self.car.resolved(self.params_file)

    def pipeline_process(self) -> str:
        """The process a car's pipeline nodes share (``""``: each its own)."""
        return "" if self.process_per_node else PIPELINE_PROCESS

    def __post_init__(self) -> None:
        if self.estimator not in ("ekf", "mhe"):
            raise ValueError(f"estimator: must be ekf or mhe, got {self.estimator!r}")
        if self.output not in OUTPUTS:
            raise ValueError(f"output: must be one of {', '.join(OUTPUTS)}, got {self.output!r}")
        if self.record not in RECORD_SETS:
            raise ValueError(
                f"record: must be one of {', '.join(RECORD_SETS)}, got {self.record!r}"
            )

    def visualizer(self, cars: int) -> list[NodeSpec]:
        """The stack's visualizer node (none without ``viz``)."""
        return [] if self.viz is None else [visualizer_node(self.viz, cars, self.files())]

    def files(self) -> dict[str, str]:
        """The ``track_file`` and ``params_file`` parameters of every car's nodes (absolute;
        none given: the nodes' defaults)."""
        return {
            name: str(Path(path).resolve())
            for name, path in (("track_file", self.track_file), ("params_file", self.params_file))
            if path is not None
        }


def stack_nodes(cars: int, options: StackOptions, bag: Path) -> list[NodeSpec]:
    """Node specs for ``cars`` cars in namespaces ``/car1``..., each a simulator, an estimator
    and a controller as ``options`` say (:class:`StackOptions`), one recorder into the bag
    ``bag`` and the visualizer with ``options.viz``: those of ``options.part``
    (:meth:`StackPart.launched`)."""
    check_cars(cars)
    if options.output == "velocity" and options.controller != "mpcc":
        raise ValueError(
            f"output: velocity needs the mpcc controller (the {options.controller} controller "
            "commands torque)"
        )
    per_car, global_topics = RECORD_SETS[options.record]
    nodes, topics = [], list(global_topics)
    files = options.files()
    # the simulated cars' own model and parameters (the stack's file only if it is of their model)
    truth = options.truth()
    track = {name: path for name, path in files.items() if name == "track_file"}
    # the default torque stack passes no extra parameters (the nodes' defaults)
    onboard_loop = {"onboard": True} if options.onboard or options.output == "velocity" else {}
    for i in range(1, cars + 1):
        ns = f"/car{i}"
        nodes += [
            # waits for the estimator, the recorder and the controller before its clock starts
            # (far ones: through the Zenoh link; StackPart.sensor_subscribers)
            NodeSpec(
                "simulator",
                "ros4crs.simulator_node",
                ns,
                {
                    "seed": options.seed + i,
                    "wait_for_subscribers": options.part.sensor_subscribers(),
                    "wait_for_commands": True,
                    **onboard_loop,
                    **track,
                    **truth.simulator_parameters(),
                },
                process=options.pipeline_process(),
            ),
            *car_control_nodes(ns, options, files),
        ]
        topics += [f"{ns}/{topic}" for topic in per_car]
    return options.part.launched(
        [*nodes, recorder_node(bag, topics), *options.visualizer(cars)], "sim"
    )


def check_cars(cars: int) -> None:
    """Every stack's check of its number of cars."""
    if cars < 1:
        raise ValueError("cars: must be >= 1")


def controller_hold_safe(options: StackOptions, over_udp: bool = False) -> str | None:
    """The controllers' ``hold_safe``: the ``options``' own, else :data:`HOLD_SAFE_OVER_A_LINK`
    where their commands cross a link (``over_udp`` to a car, or the part's Zenoh link), else
    None (the node's default, ``after_outage``)."""
    if options.hold_safe is not None:
        return options.hold_safe
    if over_udp or options.part.zenoh is not None:
        return HOLD_SAFE_OVER_A_LINK
    return None


def car_control_nodes(
    ns: str,
    options: StackOptions,
    files: dict[str, str],
    *,
    over_udp: bool = False,
    **estimator_parameters: Any,
) -> list[NodeSpec]:
    """A car's estimator (with ``estimator_parameters``) and controller, in every stack, with
    the parameter ``files`` and the stack's ``model`` (:meth:`StackOptions.model_spec`); the
    default torque stack passes the controller no ``output`` (the
    node's default), and ``hold_safe`` as :func:`controller_hold_safe` says (``over_udp``: the
    commands go to a car over UDP)."""
    commands: dict[str, Any] = {"output": options.output} if options.output == "velocity" else {}
    hold_safe = controller_hold_safe(options, over_udp)
    if hold_safe is not None:
        commands["hold_safe"] = hold_safe
    if options.drive_file is not None:
        commands["drive_file"] = str(Path(options.drive_file).resolve())
        commands["drive_after"] = float(options.drive_after)
    estimator: dict[str, Any] = {
        "estimator": options.estimator,
        "blind_start": options.blind_start,
    }
    model = {"model": options.model_spec()}
    if options.online_parameters:
        estimator["online_parameters"] = ",".join(options.online_parameters)
    return [
        NodeSpec(
            "estimator",
            "ros4crs.estimator_node",
            ns,
            {**estimator, **estimator_parameters, **files, **model},
            process=options.pipeline_process(),
        ),
        NodeSpec(
            "controller",
            "ros4crs.controller_node",
            ns,
            {"controller": options.controller, **commands, **files, **model},
            process=options.pipeline_process(),
        ),
    ]


def recorder_node(bag: Path, topics: list[str]) -> NodeSpec:
    """The one recorder of a stack: ``topics`` into the MCAP bag ``bag``."""
    return NodeSpec(
        "recorder", "ros4crs.recorder_node", "", {"output": str(bag), "topics": ",".join(topics)}
    )


def run_stack(
    cars: int,
    options: StackOptions,
    duration: float,
    out: Path,
    domain_id: int | None = None,
) -> dict[str, Any]:
    """Run the stack (:func:`stack_nodes`) for ``duration`` s in ROS domain ``domain_id``
    (:func:`run_folder`), then analyse its bag into ``out/report.json``."""
    out, bag, domain = run_folder(out, domain_id)
    nodes = stack_nodes(cars, options, bag)
    track = read_track(options.track_file) if options.track_file else load_demo_track()
    model, truth = options.model_spec(), options.truth()
    warm_compile_cache(
        options.estimator,
        options.controller,
        options.output,
        options.params_file,
        car_effects=options.car.effects,
        model=model,
        car_model=truth.model,
    )
    recorded = options.part.runs("recorder")
    contents_of: dict[str, BagContents] = {}  # the bag read once, for the report and the figure

    def analyse_run() -> dict[str, Any]:
        contents_of.update(read_cars(bag, cars))
        write_online_parameters(contents_of, out, options.params_file, model)
        write_drift_truth(contents_of, out)
        return analyse(contents_of, cars, track)

    report = launch_and_report(
        nodes,
        domain,
        out,
        duration,
        f"{len(nodes)} nodes, {cars} car(s)",
        options.after_start_up,
        analyse_run if recorded else None,
        {
            "estimator": options.estimator,
            "controller": options.controller,
            "output": options.output,
            "model": model,
            "duration_s": duration,
            "recorded": options.record,
            "car_truth": replace(options.car, model=truth.model).described(),
            "part": options.part.described(),
        },
    )
    if recorded:
        plot(contents_of, cars, out, options.estimator, track)
    return report


def launch_and_report(
    nodes: list[NodeSpec],
    domain: int,
    out: Path,
    duration: float,
    what: str,
    after_start_up: bool,
    analyse_run: Callable[[], dict[str, Any]] | None,
    settings: dict[str, Any],
) -> dict[str, Any]:
    """Launch ``nodes`` (ROS domain ``domain``, logs in OUT/logs) for ``duration`` s (from the
    moment every process has started with ``after_start_up``, :func:`run_watched`), announced
    as ``what`` and the ``settings`` estimator, controller and output; then OUT/report.json:
    ``analyse_run()`` (None: a part of the stack without the recorder, no bag here: no cars,
    and ``bag_analysis`` :data:`NO_BAG`), the ``settings``, the nodes that died and CPU and
    memory per process (the launched runs of ``crs launch sim`` and ``crs launch car``) and
    ``nodes``, the full names of the processes launched. Returns the report."""
    launcher = Launcher(nodes, domain, out / "logs")
    print(
        f"[launch] {what}, {settings['estimator']}, {settings['controller']} "
        f"({settings['output']} commands) for {duration:g} s",
        flush=True,
    )
    deaths = run_watched(launcher, duration, after_start_up)
    if analyse_run is None:
        report: dict[str, Any] = {"cars": {}, "bag_analysis": NO_BAG}
    else:
        print("[launch] analysing the bag", flush=True)
        report = analyse_run()
    report.update(settings)
    report["nodes"] = [spec.full_name for spec in nodes]
    report["node_deaths"] = [{"node": d.node, "returncode": d.returncode} for d in deaths]
    report.update(process_figures(launcher))
    (out / "report.json").write_text(json.dumps(report, indent=2))
    return report


def solver_cpu_percent(log_dir: Path, wall_s: float) -> dict[str, float]:
    """Per car, the CPU of its solvers over the run (% of one core): the estimator's updates
    and the controller's decisions, from the ``*.stats.json`` the nodes write when they stop
    (:data:`~ros4crs.discovery.STATS_DIR_VARIABLE`); the whole run's wall time ``wall_s``,
    like ``cpu_percent``. A car whose nodes wrote none is left out."""
    totals: dict[str, float] = {}
    for path in sorted(Path(log_dir).glob("*.stats.json")):
        try:
            stats = json.loads(path.read_text())
            car = stats["node"].strip("/").split("/")[0]
            totals[car] = totals.get(car, 0.0) + float(stats["solver_cpu_s"])
        except (OSError, ValueError, KeyError, AttributeError):
            continue  # a node killed while writing: no figure rather than a wrong one
    if wall_s <= 0:
        return {}
    return {car: round(100 * seconds / wall_s, 1) for car, seconds in totals.items()}


def run_folder(out: Path, domain_id: int | None) -> tuple[Path, Path, int]:
    """``out`` created, the bag folder in it (refused if it exists) and the ROS domain
    (``domain_id``, else ``$ROS_DOMAIN_ID``, else 42) of a launched run."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    bag = out / "bag"
    if bag.exists():
        raise FileExistsError(f"{bag} exists; choose an empty --out")
    domain = domain_id if domain_id is not None else int(os.environ.get("ROS_DOMAIN_ID", "42"))
    return out, bag, domain


def run_watched(launcher: Launcher, duration: float, after_start_up: bool = False) -> list:
    """Run the launcher for ``duration`` s (from the moment its processes have started with
    ``after_start_up``, :data:`STARTUP_LIMIT_S`) with a line when they have and a progress line
    every 5 s, reporting any process that dies, the CPU counted from :data:`SETTLE_S` (at most
    a quarter of the run) on; the processes that died."""

    def report_death(exited) -> None:
        print(
            f"[launch] {exited.node} exited with code {exited.returncode}:\n{exited.log_tail}",
            flush=True,
        )

    deaths = launcher.run(
        duration,
        on_exit=report_death,
        until=_progress(launcher, duration),
        settle_s=min(SETTLE_S, duration / 4),
        startup_limit=STARTUP_LIMIT_S if after_start_up else None,
    )
    print("[launch] stopped", flush=True)
    return deaths


def process_figures(launcher: Launcher) -> dict[str, Any]:
    """``startup_s`` (until every process had started), ``cpu_percent`` (whole run),
    ``cpu_percent_running`` (from the settle time on) and ``peak_memory_mib`` per process of a
    finished :meth:`Launcher.run`, and ``solver_cpu_percent`` per car
    (:func:`solver_cpu_percent`)."""
    wall = max(launcher.wall_at_stop, 1e-9)
    figures: dict[str, Any] = {
        "startup_s": None if launcher.startup_s is None else round(launcher.startup_s, 2),
        "cpu_percent": {n: round(100 * s / wall, 1) for n, s in launcher.cpu_at_stop.items()},
    }
    if launcher.cpu_at_settle is not None and launcher.wall_at_stop > launcher.wall_at_settle:
        running = launcher.wall_at_stop - launcher.wall_at_settle
        figures["cpu_percent_running"] = {
            n: round(100 * (s - launcher.cpu_at_settle.get(n, 0.0)) / running, 1)
            for n, s in launcher.cpu_at_stop.items()
        }
    figures["peak_memory_mib"] = {n: round(m, 1) for n, m in launcher.memory_at_stop.items()}
    figures["solver_cpu_percent"] = solver_cpu_percent(launcher.log_dir, launcher.wall_at_stop)
    return figures


def _progress(launcher: Launcher, duration: float, every: float = 5.0):
    """An ``until`` callback for :meth:`Launcher.run` that says when every process has started
    and prints a progress line every ``every`` s of the run (and never stops it)."""
    said, due = [False], [every]

    def tick() -> bool:
        total = len(launcher.processes)
        if not said[0] and launcher.startup_s is not None:
            print(f"[launch] {total} processes started in {launcher.startup_s:.1f} s", flush=True)
            said[0] = True
        since = launcher.counting_since
        if since is None:
            return False
        elapsed = time.monotonic() - since
        if elapsed >= due[0]:
            running = sum(p.poll() is None for p in launcher.processes.values())
            print(
                f"[launch] {elapsed:3.0f} / {duration:g} s: {running} of {total} processes running",
                flush=True,
            )
            due[0] += every
        return False

    return tick


def rmse_text(rmse: dict[str, float] | None) -> str:
    """``RMSE x 0.8 mm, y 1.0 mm, yaw 7.1 mrad`` from a report's ``estimation_rmse``."""
    if not rmse:
        return "no estimates"
    return (
        f"RMSE x {1e3 * rmse['x']:.1f} mm, y {1e3 * rmse['y']:.1f} mm, "
        f"yaw {1e3 * rmse['yaw']:.1f} mrad"
    )


def summary(report: dict[str, Any], out: Path) -> str:
    """A few lines for a person: laps, errors, deadline misses, deaths, where the report is
    (a part without the recorder: that it analysed no bag, and the processes it ran)."""
    unanalysed = report.get("bag_analysis")
    if unanalysed:
        lines = [f"no bag analysis: {unanalysed}; ran {', '.join(report['nodes'])}"]
    else:
        lines = []
    for car, c in report["cars"].items():
        times = ", ".join(f"{t:.1f}" for t in c.get("lap_times_s", []))
        laps = f"{c.get('laps_completed', 0)} laps" + (f" ({times} s)" if times else "")
        line = (
            f"{car}: {laps}; {rmse_text(c.get('estimation_rmse'))}; "
            f"{c.get('estimator_deadline_misses', 0)} deadline misses in "
            f"{c.get('estimator_updates', 0)} updates"
        )
        overload, outside = c.get("overload"), c.get("off_track")
        if overload and overload["starved"]:
            line += f"; starved ({overload['late_commands']} late commands)"
        if outside and outside["episodes"]:
            line += f"; LEFT THE TRACK ({outside['seconds']:.1f} s outside)"
        lines.append(line)
        online = c.get("online_parameters")
        if online:
            lines.append(
                "  online at the end: "
                + ", ".join(f"{n} {p['value']:.4g} ± {p['std']:.2g}" for n, p in online.items())
            )
    deaths = report.get("node_deaths") or []
    lines.append(
        "node deaths: " + (", ".join(f"{d['node']} ({d['returncode']})" for d in deaths) or "none")
    )
    cpu = report.get("cpu_percent", {})
    lines.append("CPU % of one core: " + ", ".join(f"{n} {v:g}" for n, v in cpu.items()))
    running = report.get("cpu_percent_running")
    if running:
        lines.append("  after the start-up: " + ", ".join(f"{n} {v:g}" for n, v in running.items()))
    if unanalysed:
        lines.append(f"report: {out / 'report.json'}")
    else:
        lines.append(f"report: {out / 'report.json'}, {out / 'path.png'}, bag {out / 'bag'}")
    return "\n".join(lines)


def read_cars(bag: Path, cars: int) -> dict[str, BagContents]:
    """What the bag holds of each of ``cars`` (``car1``, ...), one pass of the bag per car."""
    from ros4crs.bag_replay import read_car

    return {f"car{i}": read_car(bag, f"/car{i}") for i in range(1, cars + 1)}


def write_online_parameters(
    contents_of: dict[str, BagContents],
    out: Path,
    params_file: Path | None,
    model: str | None = None,
) -> list[Path]:
    """``out/online_parameters_carN.csv`` (``t, name, value, std``) of each car whose
    estimator published online parameters: ``t`` in s since the car's first command, each
    parameter's prior first (of the model ``model``, a spec, with ``params_file``'s values;
    None: the file's model, else the dynamic one)."""
    from crs_core.estimation.online_track import OnlineTrack
    from crs_core.model import CarModel
    from crs_core.model.online import DEFAULT_REVERSION_S

    written = []
    for car, contents in contents_of.items():
        messages = contents.online_parameters
        if not messages or not contents.inputs:
            continue
        names = tuple(messages[0][1])
        track = OnlineTrack.empty(len(messages), names)
        for k, (_, parameters) in enumerate(messages):
            track.set(k, parameters)
        base = CarModel.from_file(params_file, model=model)
        online_model = base.with_online(names, DEFAULT_REVERSION_S)
        origin = contents.inputs[0].stamp
        stamps = np.array([stamp for stamp, _ in messages]) - origin
        path = out / f"online_parameters_{car}.csv"
        prior_t = min(0.0, float(stamps[0]))  # estimates before the first command: earlier
        written.append(track.write_csv(path, stamps, online_model.online.priors, prior_t))
    return written


def write_drift_truth(contents_of: dict[str, BagContents], out: Path) -> list[Path]:
    """``out/truth_carN.npz`` of each car whose simulator drifted (``ground_truth/parameters``
    in the bag): ``t`` (s, the ground truth's stamps), ``x`` (its states, ``(N, 6)``) and
    ``drift_<name>`` (each drifted parameter at ``t``), as an emulated car's truth log."""
    written = []
    for car, contents in contents_of.items():
        if not contents.truth_parameters or not contents.truth:
            continue
        t = np.array([stamp for stamp, _ in contents.truth])
        stamps = np.array([stamp for stamp, _ in contents.truth_parameters])
        drifted = {
            f"drift_{name}": np.interp(
                t, stamps, [values[name] for _, values in contents.truth_parameters]
            )
            for name in contents.truth_parameters[0][1]
        }
        path = out / f"truth_{car}.npz"
        np.savez(path, t=t, x=np.array([x for _, x in contents.truth]), **drifted)
        written.append(path)
    return written


def analyse(
    contents_of: dict[str, BagContents],
    cars: int,
    track: Track | None = None,
    truths: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
) -> dict[str, Any]:
    """Per car: laps, lap times, estimation RMSE, deadline misses, latencies, from
    ``contents_of``, what the bag holds of each car (:func:`read_cars`).

    The truth is the bag's ``ground_truth`` (the simulator's), unless ``truths`` gives it per
    car (``{"car1": (stamps (n,), states (n, 6))}``, e.g. a car emulator's log; a car missing
    from it has no truth)."""
    track = track or load_demo_track()
    report: dict[str, Any] = {"cars": {}}
    for i in range(1, cars + 1):
        ns = f"/car{i}"
        contents = contents_of[ns.strip("/")]
        car: dict[str, Any] = {"laps_completed": 0, "lap_times_s": []}
        if truths is not None:
            truth = truths.get(ns.strip("/"))
        elif contents.truth:
            truth = (
                np.array([t for t, _ in contents.truth]),
                np.array([x for _, x in contents.truth]),
            )
        else:
            truth = None
        if truth is not None and len(truth[0]) >= 2:
            stamps, states = np.asarray(truth[0], dtype=float), np.asarray(truth[1], dtype=float)
            # laps are timed from when the car starts moving (it waits on the start line until
            # the estimator is up), a start within 5 cm of the line counting as on it
            moving = int(np.argmax(states[:, 3] > 0.05)) if np.any(states[:, 3] > 0.05) else 0
            laps = lap_statistics(stamps[moving:], states[moving:], track, line_tolerance=0.05)
            car["laps_completed"] = laps["laps_completed"]
            car["lap_times_s"] = laps["lap_times_s"]
            rmse = estimation_rmse(contents.estimates, stamps, states)
            if rmse is not None:
                car["estimation_rmse"] = rmse
            car["off_track"] = off_track(stamps[moving:], states[moving:], track)
        car["estimator_deadline_misses"] = contents.deadline_misses
        car["estimator_updates"] = contents.updates
        car["overload"] = overload_figures(
            [sample.stamp for sample in contents.inputs], contents.deadline_misses, contents.updates
        )
        car["outcome"] = outcome(car)
        car["estimator_reinitializations"] = contents.reinitializations
        car["malformed_messages"] = contents.malformed
        car["latency_ms"] = latencies(contents.receive_times)
        if contents.online_parameters:  # the last estimate's
            car["online_parameters"] = {
                name: {"value": p.value, "std": p.std, "informed": p.informed}
                for name, p in contents.online_parameters[-1][1].items()
            }
        report["cars"][ns.strip("/")] = car
    return report


def pipeline_cpu(cpu: dict[str, float], car: str) -> float:
    """A car's pipeline CPU (% of one core) from a report's ``cpu_percent`` (or
    ``cpu_percent_running``): its shared process (``/car1/pipeline``) or, with
    ``process_per_node``, its simulator or bridge, estimator and controller summed."""
    shared = cpu.get(f"/{car}/{PIPELINE_PROCESS}")
    if shared is not None:
        return shared
    return sum(cpu.get(f"/{car}/{node}", 0.0) for node in PIPELINE_NODES)


def overload_figures(
    command_stamps: list[float], misses: int, updates: int, late: float | None = None
) -> dict[str, Any]:
    """How starved a car's loop was, from what it sent: the gaps between its commands (stamps,
    s) longer than ``late`` (default: the supervisor's late tick,
    :class:`~crs_core.control.overload.OverloadSettings`), the longest gap, and the share of
    the estimator's updates that missed their deadline; ``starved`` when a command came late or
    more than 1 % of the updates missed."""
    late = OverloadSettings().late_tick if late is None else late
    gaps = np.diff(np.sort(np.asarray(command_stamps, dtype=float)))
    fraction = misses / updates if updates else 0.0
    late_commands = int(np.sum(gaps > late))
    return {
        "late_commands": late_commands,
        "longest_command_gap_s": round(float(gaps.max()), 3) if gaps.size else None,
        "estimator_miss_fraction": round(fraction, 4),
        "starved": bool(late_commands or fraction > 0.01),
    }


def outcome(car: dict[str, Any]) -> str:
    """``"left the track"`` (its footprint was outside the border), ``"raced"`` (a lap or
    more, always inside) or ``"stayed on the track"`` (no lap); ``"unknown"`` without its
    truth."""
    outside = car.get("off_track")
    if outside is None:
        return "unknown"
    if outside["episodes"]:
        return "left the track"
    return "raced" if car.get("laps_completed", 0) else "stayed on the track"


def estimation_rmse(
    estimates: list[tuple[float, np.ndarray]],
    stamps: np.ndarray,
    states: np.ndarray,
    until: float = math.inf,
) -> dict[str, float] | None:
    """RMSE of a car's ``estimates`` (``(stamp, state)``, the first left out) against its truth
    (``stamps`` (n,), ``states`` (n, 6)), from 2 s after the truth's start to its end or
    ``until`` (s, the same clock), rounded to 0.01 mm / 0.01 mrad; None without estimates there.
    Keys ``x``, ``y``, ``yaw``, ``vx``, ``vy``."""
    if len(estimates) < 2:
        return None
    est_t = np.array([t for t, _ in estimates[1:]])
    est_x = np.array([x for _, x in estimates[1:]])
    truth = np.column_stack(
        [
            interpolate_pose(est_t, stamps, states),
            *(np.interp(est_t, stamps, states[:, k]) for k in range(3, 6)),
        ]
    )
    inside = (est_t >= stamps[0] + 2.0) & (est_t <= min(stamps[-1], until))
    rmse = state_rmse(est_x, truth, inside)
    if rmse is None:
        return None
    return {name: round(rmse[name], 5) for name in ("x", "y", "yaw", "vx", "vy")}
