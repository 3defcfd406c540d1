"""Process launcher: node processes with parameters, namespaces and a ROS domain.

Each node runs as ``python -m <module> --ros-args -r __ns:=<ns> -r __node:=<name>
--params-file <yaml>`` with ``ROS_DOMAIN_ID`` set and ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``.
The launcher watches the processes, reports any that dies (name, exit code, the end of its
log), and stops everything cleanly: SIGINT, then SIGTERM, then SIGKILL after timeouts.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ros4crs.discovery import STATS_DIR_VARIABLE, set_discovery_environment

#: The line each ROS node logs once it is made and about to spin
#: (:func:`ros4crs.node_support.run_nodes`).
READY_LINE = "running (pid"
#: How long after the launch :meth:`Launcher.run` looks for every process to have started, s.
READY_WATCH_S = 120.0


@dataclass
class NodeSpec:
    """One node process.

    Attributes
    ----------
    name : str
        Node name (``__node`` remap) and log-file stem.
    module : str
        Python module with a ``main`` (``ros4crs.estimator_node``).
    namespace : str
        ROS namespace, e.g. ``/car1`` (``""`` for the root).
    parameters : dict
        ROS parameters, written to a params file under the node's full name.
    arguments : list of str, optional
        For a plain (non-ROS) process: its command-line arguments. When given, the process
        runs as ``python -m <module> *arguments``; ``namespace`` then only names it (and its
        log) and ``parameters`` must be empty.
    stops_first : bool
        Stopped, and waited for, before the others (an emulated car: stopped while the host
        still sends, it never sees the host go away, which it would count as a motor cut-off).
    process : str
        The name of a process the node shares with the other nodes of its namespace that give
        the same one (:mod:`ros4crs.composed`; the process is ``<namespace>/<process>`` in
        reports); ``""``: a process of its own.
    """

    name: str
    module: str
    namespace: str = ""
    parameters: dict[str, Any] = field(default_factory=dict)
    arguments: list[str] | None = None
    stops_first: bool = False
    process: str = ""

    def __post_init__(self) -> None:
        if self.arguments is not None and self.parameters:
            raise ValueError(f"{self.full_name}: a plain process (arguments) takes no parameters")
        if self.arguments is not None and self.process:
            raise ValueError(f"{self.full_name}: a plain process (arguments) shares no process")

    @property
    def full_name(self) -> str:
        return f"{self.namespace.rstrip('/')}/{self.name}"

    @property
    def process_name(self) -> str:
        """The name of the process that runs the node (its own: its full name)."""
        return f"{self.namespace.rstrip('/')}/{self.process}" if self.process else self.full_name


@dataclass
class Exited:
    """A node process that ended."""

    node: str
    returncode: int
    log_tail: str


class Launcher:
    """Start, watch and stop a set of node processes.

    Parameters
    ----------
    nodes : list of NodeSpec
    domain_id : int
        ``ROS_DOMAIN_ID`` for every process.
    log_dir : Path
        Where the params files and one log per node go.
    """

    def __init__(self, nodes: list[NodeSpec], domain_id: int, log_dir: Path) -> None:
        names = [n.full_name for n in nodes]
        if len(set(names)) != len(names):
            raise ValueError(f"nodes: duplicate full names in {names}")
        if not 0 <= domain_id <= 232:
            raise ValueError(f"domain_id: must be in 0..232, got {domain_id}")
        self.nodes, self.domain_id, self.log_dir = nodes, domain_id, Path(log_dir)
        self.processes: dict[str, subprocess.Popen] = {}
        self._logs: dict[str, Path] = {}
        #: per process, the ROS nodes in it (each logs a :data:`READY_LINE`; 0: a plain process)
        self._ros_nodes: dict[str, int] = {}
        self.exited: list[Exited] = []

    def environment(self) -> dict[str, str]:
        env = dict(os.environ)
        env["ROS_DOMAIN_ID"] = str(self.domain_id)
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        env["PYTHONUNBUFFERED"] = "1"
        env[STATS_DIR_VARIABLE] = str(self.log_dir.resolve())  # the nodes' solver CPU at the end
        set_discovery_environment(env)  # the suite's Fast DDS profile, unless the user has one
        # node logs with local date and time (rcutils' default is raw epoch seconds)
        env.setdefault(
            "RCUTILS_CONSOLE_OUTPUT_FORMAT",
            "[{severity}] [{date_time_with_ms}] [{name}]: {message}",
        )
        return env

    def start(self) -> None:
        """Start every process (in the order of their first node); the nodes that share a
        process (:attr:`NodeSpec.process`) are started together in it."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        env = self.environment()
        groups: dict[str, list[NodeSpec]] = {}
        for spec in self.nodes:
            groups.setdefault(spec.process_name, []).append(spec)
        for process, specs in groups.items():
            log = self.log_dir / f"{_stem(process)}.log"
            spec = specs[0]
            self._ros_nodes[process] = sum(node.arguments is None for node in specs)
            if spec.arguments is not None:
                self._spawn(process, [sys.executable, "-m", spec.module, *spec.arguments], log, env)
                continue
            files = [self._params_file(s) for s in specs]
            if not spec.process:
                command = [sys.executable, "-m", spec.module, "--ros-args"]
                if spec.namespace:
                    command += ["-r", f"__ns:={spec.namespace}"]
                command += ["-r", f"__node:={spec.name}", "--params-file", str(files[0])]
            else:
                command = [sys.executable, "-m", "ros4crs.composed"]
                for node, params in zip(specs, files, strict=True):
                    command += ["--node", f"{node.full_name}={node.module}:{params}"]
            self._spawn(process, command, log, env)

    def _params_file(self, spec: NodeSpec) -> Path:
        """Write the parameter file of node ``spec``; its path."""
        params = self.log_dir / f"{_stem(spec.full_name)}.params.yaml"
        params.write_text(yaml.safe_dump({spec.full_name: {"ros__parameters": spec.parameters}}))
        return params

    def _spawn(self, process: str, command: list[str], log: Path, env: dict[str, str]) -> None:
        with open(log, "w") as handle:
            self.processes[process] = subprocess.Popen(
                command,
                stdout=handle,
                stderr=subprocess.STDOUT,
                env=env,
                start_new_session=True,
            )
        self._logs[process] = log

    def poll(self) -> list[Exited]:
        """Processes that ended since the last poll."""
        new = []
        for name, process in list(self.processes.items()):
            code = process.poll()
            if code is not None and all(e.node != name for e in self.exited):
                tail = "\n".join(self._logs[name].read_text(errors="replace").splitlines()[-8:])
                new.append(Exited(name, code, tail))
        self.exited.extend(new)
        return new

    def cpu_seconds(self) -> dict[str, float]:
        """User + system CPU time (s) used so far by each running process."""
        ticks = os.sysconf("SC_CLK_TCK")
        out = {}
        for name, process in self.processes.items():
            try:
                fields = Path(f"/proc/{process.pid}/stat").read_text().rsplit(")", 1)[1].split()
                out[name] = (int(fields[11]) + int(fields[12])) / ticks
            except (OSError, IndexError, ValueError):
                continue
        return out

    def peak_memory_mib(self) -> dict[str, float]:
        """Peak resident memory (VmHWM, MiB) of each running process."""
        out = {}
        for name, process in self.processes.items():
            try:
                status = Path(f"/proc/{process.pid}/status").read_text()
                line = next(ln for ln in status.splitlines() if ln.startswith("VmHWM:"))
                out[name] = int(line.split()[1]) / 1024
            except (OSError, StopIteration, IndexError, ValueError):
                continue
        return out

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the nodes marked ``stops_first``, then the others: SIGINT, then SIGTERM, then
        SIGKILL whatever is still running."""
        first = {spec.process_name for spec in self.nodes if spec.stops_first}
        for group in (first, set(self.processes) - first):
            self._stop([p for name, p in self.processes.items() if name in group], timeout)

    @staticmethod
    def _stop(processes: list[subprocess.Popen], timeout: float) -> None:
        for sig, wait in ((signal.SIGINT, timeout), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
            running = [p for p in processes if p.poll() is None]
            if not running:
                return
            for process in running:
                try:
                    process.send_signal(sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + wait
            while time.monotonic() < deadline and any(p.poll() is None for p in running):
                time.sleep(0.05)

    def ready(self) -> bool:
        """Whether every process has started: a ROS process's log holds a :data:`READY_LINE`
        for each of its nodes, a plain process's log any output."""
        for name in self.processes:
            try:
                text = self._logs[name].read_text(errors="replace")
            except OSError:
                return False
            if text.count(READY_LINE) < self._ros_nodes[name] or not text:
                return False
        return True

    def run(
        self,
        duration: float | None,
        on_exit=None,
        until=None,
        settle_s: float | None = None,
        startup_limit: float | None = None,
    ) -> list[Exited]:
        """Start, watch until ``duration`` s passed, ``until()`` is true or Ctrl-C, then stop.

        ``on_exit(exited)`` is called for every node that dies while running. The moment every
        process has started (:meth:`ready`) is noted as :attr:`startup_s`, s after the launch
        (None if it never came in :data:`READY_WATCH_S`). ``duration`` counts from the launch,
        or with ``startup_limit`` from that moment, at most ``startup_limit`` s after the
        launch: a loaded machine's slow imports do not eat the run. With ``settle_s`` the CPU
        times are also taken that long after ``duration`` began to count
        (:attr:`cpu_at_settle`), so that the cost of the running stack can be told from its
        start-up. Returns all processes that died before the stop.
        """
        self.start()
        deaths: list[Exited] = []
        launched = time.monotonic()
        self.startup_s: float | None = None
        #: when ``duration`` began to count (:func:`time.monotonic`), None while starting up
        self.counting_since: float | None = None if startup_limit is not None else launched
        self.cpu_at_settle: dict[str, float] | None = None
        self.wall_at_settle = 0.0
        try:
            while True:
                now = time.monotonic()
                elapsed = now - launched
                if self.startup_s is None and elapsed < READY_WATCH_S and self.ready():
                    self.startup_s = elapsed
                if self.counting_since is None and (
                    self.startup_s is not None or elapsed >= (startup_limit or 0.0)
                ):
                    self.counting_since = now
                counted = None if self.counting_since is None else now - self.counting_since
                if counted is not None and duration is not None and counted >= duration:
                    break
                if (
                    counted is not None
                    and settle_s is not None
                    and self.cpu_at_settle is None
                    and counted >= settle_s
                ):
                    self.cpu_at_settle, self.wall_at_settle = self.cpu_seconds(), elapsed
                for exited in self.poll():
                    deaths.append(exited)
                    if on_exit:
                        on_exit(exited)
                if until is not None and until():
                    break
                time.sleep(0.1)
        except KeyboardInterrupt:
            pass
        finally:
            self.cpu_at_stop = self.cpu_seconds()
            self.memory_at_stop = self.peak_memory_mib()
            self.wall_at_stop = time.monotonic() - launched
            self.stop()
        return deaths


def _stem(name: str) -> str:
    """A file-name stem of a node's or process's full name (``/car1/estimator`` ->
    ``car1_estimator``)."""
    return name.strip("/").replace("/", "_")
