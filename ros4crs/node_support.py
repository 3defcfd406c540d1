"""What every node process shares: start-up, parameter helpers, clean shutdown, QoS."""

from __future__ import annotations

import math
import os
import signal
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import rclpy
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

from crs_core.errors import FieldError
from ros4crs.discovery import STATS_DIR_VARIABLE, set_discovery_environment

if TYPE_CHECKING:
    from crs_core.model import CarModel
    from crs_core.track import Track

#: Sensor and command streams: reliable with a queue deep enough for 250 Hz bursts.
STREAM_QOS = QoSProfile(
    depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST
)
#: The publishers of the sensor and command streams: :data:`STREAM_QOS`, transient-local. A
#: recorder finds topics by polling the graph (every 0.2 s), so it may subscribe after the
#: estimator has had a stream's first messages (the controller sends commands from its start);
#: with these it still gets the last ``depth`` of them, and a bag holds what the estimator had.
#: Volatile subscribers (every node's :data:`STREAM_QOS`) match and get only new messages.
STREAM_OUT_QOS = QoSProfile(
    depth=STREAM_QOS.depth,
    reliability=ReliabilityPolicy.RELIABLE,
    history=HistoryPolicy.KEEP_LAST,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
#: Estimates and the estimator's query log: reliable and transient-local, the last
#: ``LOG_DEPTH`` messages kept for a subscriber that joins late (a recorder discovering the topic
#: after the first estimates were published gets them; volatile subscribers, like the
#: controller, still match and get only new messages).
LOG_DEPTH = 1000
LOG_QOS = QoSProfile(
    depth=LOG_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    history=HistoryPolicy.KEEP_LAST,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


class ParameterError(FieldError):
    """A node parameter with a bad value; ``field`` is the parameter's name."""


def declare(
    node: Node,
    name: str,
    default: Any,
    description: str = "",
    check: Callable[[Any], str | None] | None = None,
    constraints: str = "",
) -> Any:
    """Declare a parameter with a default and return its value, of the default's type.

    An integer is accepted for a float parameter (``rate_hz: 60``) and integers for a list of
    floats; any other type than the default's is refused. ``check(value)`` returns what is
    wrong (``None``: nothing). Raises :class:`ParameterError` naming the parameter.
    ``constraints`` tells ``ros2 param describe`` what a value must be (the descriptor's
    ``additional_constraints``: text, which ROS does not enforce; the checks do).
    """
    from rcl_interfaces.msg import ParameterDescriptor

    descriptor = ParameterDescriptor(
        description=description, additional_constraints=constraints, dynamic_typing=True
    )
    value = _of_type(name, node.declare_parameter(name, default, descriptor).value, default)
    problem = check(value) if check is not None else None
    if problem:
        raise ParameterError(name, f"{problem.removeprefix(f'{name}: ')}, got {value!r}")
    return value


def _of_type(name: str, value: Any, default: Any) -> Any:
    """``value`` as the type of ``default`` (int -> float allowed), else ParameterError."""

    def number(v: Any) -> bool:
        return isinstance(v, int | float) and not isinstance(v, bool)

    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok, value = number(value), float(value) if number(value) else value
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:  # a list of numbers
        ok = isinstance(value, list | tuple) and all(number(v) for v in value)
        value = [float(v) for v in value] if ok else value
    if not ok:
        kind = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}
        wanted = kind.get(type(default), "a list of numbers")
        raise ParameterError(name, f"expected {wanted}, got {value!r}")
    return value


def positive(value: float) -> str | None:
    """A :func:`declare` check: a finite number > 0."""
    return None if math.isfinite(value) and value > 0 else "must be a finite number > 0"


def non_negative(value: float) -> str | None:
    """A :func:`declare` check: a finite number >= 0."""
    return None if math.isfinite(value) and value >= 0 else "must be a finite number >= 0"


def one_of(*choices: str) -> Callable[[str], str | None]:
    """A :func:`declare` check: one of ``choices``."""
    return lambda value: None if value in choices else f"must be one of {', '.join(choices)}"


def in_range(low: int, high: int) -> Callable[[int], str | None]:
    """A :func:`declare` check: ``low <= value <= high``."""
    return lambda value: None if low <= value <= high else f"must be in {low}..{high}"


def finite_vector(size: int) -> Callable[[list[float]], str | None]:
    """A :func:`declare` check: ``size`` finite numbers."""

    def check(value: list[float]) -> str | None:
        if len(value) != size or not all(math.isfinite(v) for v in value):
            return f"must be {size} finite numbers"
        return None

    return check


def file_or_empty(value: str) -> str | None:
    """A :func:`declare` check: empty (not given) or an existing file."""
    if not value or os.path.isfile(value):
        return None
    return "is a folder, not a file" if os.path.isdir(value) else "no such file"


def parsed_with(parse: Callable[[str], Any]) -> Callable[[str], str | None]:
    """A :func:`declare` check: ``parse(value)`` raises no ``ValueError`` (its message is
    the problem)."""

    def check(value: str) -> str | None:
        try:
            parse(value)
        except ValueError as error:
            return str(error)
        return None

    return check


def declare_track(node: Node) -> Track:
    """The ``track_file`` parameter: a CRS track YAML, empty for the DEMO_TRACK."""
    from crs_core.track import load_demo_track, read_track

    path = declare(
        node, "track_file", "", "track YAML (CRS format); empty: DEMO_TRACK", file_or_empty
    )
    try:
        return read_track(path) if path else load_demo_track()
    except (ValueError, KeyError, OSError) as error:
        message = error.args[0] if isinstance(error, KeyError) else error
        raise ParameterError("track_file", str(message)) from None


def declare_initial_state(node: Node, description: str) -> list[float]:
    """The ``initial_state`` parameter: ``x, y, yaw, vx, vy, omega`` (m, rad, m/s, rad/s), by
    default the start of the ``track_file`` parameter's track (:func:`declare_track`), at rest."""
    track = declare_track(node)
    start = track.start_state().tolist()
    return declare(node, "initial_state", start, description, finite_vector(6))


def declare_model(node: Node, effects: Any = (), n_base_stations: int = 1) -> CarModel:
    """The car model: the ``model`` parameter (a spec, :func:`~crs_core.model.plants.load_plant`:
    ``dynamic``, ``kinematic``, ``FILE.py:CLASS`` or ``MODULE:CLASS``; empty: the one the
    ``params_file`` names under ``model:``, else the dynamic bicycle) with the ``params_file``
    parameter (a parameter YAML, empty for the model's defaults) applied. A model that does not
    load, or that contradicts the file's ``model:``, is refused naming ``model``."""
    from crs_core.model import CarModel
    from crs_core.model.plants import load_plant, model_in_file, resolve_model

    spec = declare(
        node,
        "model",
        "",
        "the model: dynamic, kinematic or FILE.py:CLASS; empty: the params_file's model:, "
        "else dynamic",
    ).strip()
    try:
        plant = load_plant(spec, "model") if spec else None
    except FieldError as error:
        raise ParameterError("model", error.reason) from None
    path = declare(node, "params_file", "", "model parameter YAML; empty: defaults", file_or_empty)
    if path:
        try:
            model_in_file(path)
        except FieldError as error:  # the file's own model: is malformed
            raise ParameterError("params_file", f"{error.field}: {error.reason}") from None
        try:
            plant = load_plant(resolve_model(plant, path), "model")
        except FieldError as error:
            raise ParameterError("model", error.reason) from None
    try:
        return CarModel.from_file(path or None, effects, n_base_stations, plant)
    except FieldError as error:
        if error.field != "model":
            raise ParameterError("params_file", str(error)) from None
        raise ParameterError("model", error.reason) from None  # e.g. other inputs than ours
    except (ValueError, KeyError, OSError) as error:
        message = error.args[0] if isinstance(error, KeyError) else error
        raise ParameterError("params_file", str(message)) from None


#: Topics every node has, which describe one machine's processes: never recorded, carried to
#: another machine or passed to a viewer.
INTERNAL_TOPICS = ("/rosout", "/parameter_events")


def topic_selected(topic: str, prefixes: Sequence[str]) -> bool:
    """Whether ``topic`` is one of the suite's (not :data:`INTERNAL_TOPICS`) and starts with one
    of ``prefixes`` (empty: every topic)."""
    if topic in INTERNAL_TOPICS:
        return False
    return not prefixes or any(topic.startswith(p) for p in prefixes)


def message_class(msgtype: str) -> type:
    """The rclpy message class of ``"pkg/msg/Type"``."""
    import importlib

    package, kind, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def throttled_warning(node: Node, period: float = 1.0) -> Callable[[str], None]:
    """A function logging ``node``'s warnings at most once per ``period`` s (per function).

    rclpy's own ``throttle_duration_sec`` is throttled per call site (so one line of code shared
    by several topics lets only the first topic's warning through) and inspects the caller's
    frame and source on every call, ~1 ms even when it suppresses the message: on a 250 Hz
    stream of bad or late data that is enough to make a node fall behind.
    """
    last = [-math.inf]

    def warn(message: str) -> None:
        now = time.monotonic()
        if now - last[0] >= period:
            last[0] = now
            node.get_logger().warning(message)

    return warn


class CheckedSubscription:
    """A raw subscription whose messages are validated before ``handle`` sees them.

    The CDR bytes are deserialized here (a message that does not deserialize, e.g. of another
    type or truncated, is dropped instead of raising inside the executor), then ``parse``
    converts and validates it (``ValueError`` drops it). Each drop logs a warning naming the
    problem, throttled to one a second per topic; :attr:`dropped` counts them.

    :meth:`take_pending` handles every message already waiting in the queue. rclpy's executor
    runs a due timer before the messages queued behind it and takes one message per
    subscription per wake-up, so a node that fell behind would otherwise compute at its timer
    without data that are already in the process.
    """

    def __init__(
        self,
        node: Node,
        msg_type: type,
        topic: str,
        parse: Callable[[Any], Any],
        handle: Callable[[Any], None],
        what: str,
    ) -> None:
        self.dropped = 0
        self._msg_type, self._topic, self._what = msg_type, topic, what
        self._parse, self._handle = parse, handle
        self._warn = throttled_warning(node)
        self.subscription = node.create_subscription(
            msg_type, topic, self._on_message, STREAM_QOS, raw=True
        )

    def _on_message(self, data: bytes) -> None:
        from rclpy.serialization import deserialize_message

        try:
            value = self._parse(deserialize_message(bytes(data), self._msg_type))
        except Exception as error:
            self.dropped += 1
            self._warn(f"dropped malformed {self._what} on {self._topic}: {error}")
            return
        self._handle(value)

    def take_pending(self) -> int:
        """Handle every message waiting in the queue, in arrival order; how many there were."""
        taken = 0
        with self.subscription.handle:
            while True:
                message = self.subscription.handle.take_message(self._msg_type, True)
                if message is None:
                    return taken
                self._on_message(message[0])
                taken += 1


def input_subscription(
    node: Node, handle: Callable[[Any], None], topic: str | None = None
) -> CheckedSubscription:
    """The car's commanded inputs as the simulator, the bridge and the estimator take them:
    ``chronos_msgs/CarInput`` on ``topic`` (default ``input``), checked by
    ``conversions.input_from_msg``."""
    from chronos_msgs.msg import CarInput
    from ros4crs import conversions

    topic = conversions.TOPICS["input"] if topic is None else topic
    return CheckedSubscription(node, CarInput, topic, conversions.input_from_msg, handle, "input")


def run(make_node: Callable[[], Node], argv: Sequence[str] | None = None) -> int:
    """Initialise rclpy, spin the node until Ctrl-C / SIGTERM / shutdown, clean up.

    A node that cannot start (a bad parameter, an unreadable file, a broken ``--params-file``)
    prints one line, ``<node>: error: <parameter or file>: <reason>``, on stderr and exits with
    code 2 (no traceback). Discovery stays on this machine and uses the suite's Fast DDS profile
    unless the environment says otherwise (:mod:`ros4crs.discovery`). With ``CRS_PROFILE=DIR``
    in the environment the node runs under :mod:`cProfile` and writes
    ``DIR/<ns>_<node>_<pid>.prof`` when it stops (``python -m pstats FILE``).
    """
    args = list(argv) if argv is not None else sys.argv
    return run_nodes([(_node_name(args, make_node), make_node)], args)


def run_nodes(
    makers: Sequence[tuple[str, Callable[[], Node]]], argv: Sequence[str] | None = None
) -> int:
    """:func:`run` for several nodes in one process: ``makers`` are ``(full name, factory)``
    pairs, made in order and spun in one executor (:mod:`ros4crs.composed`). A node that
    cannot start stops the process with its one line, as :func:`run` says."""
    args = list(argv) if argv is not None else sys.argv
    folder = os.environ.get("CRS_PROFILE")
    if folder:
        import cProfile

        profiler = cProfile.Profile()
        profiler.enable()
        try:
            return _run(makers, args)
        finally:
            profiler.disable()
            Path(folder).mkdir(parents=True, exist_ok=True)
            stem = "+".join(name.strip("/").replace("/", "_") for name, _ in makers) or "node"
            profiler.dump_stats(str(Path(folder) / f"{stem}_{os.getpid()}.prof"))
    return _run(makers, args)


def _run(makers: Sequence[tuple[str, Callable[[], Node]]], args: list[str]) -> int:
    from rclpy._rclpy_pybind11 import RCLError

    set_discovery_environment()
    first = makers[0][0]
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RCLError as error:  # e.g. a --params-file that is not valid YAML
        reason = " ".join(str(error).split()).split(", at /")[0]
        return _start_failure(first, f"cannot start ROS: {reason}")
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # as Ctrl-C while starting
    nodes: list[Node] = []
    try:
        try:
            executor = make_executor()  # a bad CRS_EXECUTOR is a start-up error too
        except (ValueError, KeyError, OSError) as error:
            return _start_failure(first, _reason(error))
        for name, make_node in makers:
            try:
                nodes.append(make_node())
            except (ValueError, KeyError, OSError) as error:  # what a user can give wrong
                return _start_failure(name, _reason(error))
        for node in nodes:
            # rclpy finds a log call's caller with inspect, whose first use scans the file of
            # every loaded module: 50 ms on an idle machine, 200 ms and more on a loaded one.
            # Paid here, not in the first callback that logs (it held a controller's commands
            # back past the car's 200 ms motor cut-off).
            node.get_logger().info(f"running (pid {os.getpid()})")
            executor.add_node(node)
        # from now on Ctrl-C / SIGTERM end the loop between callbacks: a signal that shut the
        # context down (rclpy's own handlers) or raised inside a callback stopped it mid-publish
        stop: list[int] = []
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda number, _frame: stop.append(number))
        while rclpy.ok() and not stop:
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok():
            raise  # a real failure while running
        # the context was shut down (Ctrl-C, SIGTERM) under a running callback, e.g. mid-publish
    finally:
        _write_timing_stats(makers, nodes)
        for node in reversed(nodes):
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _write_timing_stats(
    makers: Sequence[tuple[str, Callable[[], Node]]], nodes: list[Node]
) -> None:
    """``<dir>/<ns>_<node>.stats.json`` of each node with a ``timing_stats()`` (the CPU of its
    solver), when ``$CRS_NODE_STATS`` names a folder; a failure to write is logged, never
    raised (the node is stopping)."""
    folder = os.environ.get(STATS_DIR_VARIABLE)
    if not folder:
        return
    import json

    for (name, _), node in zip(makers, nodes, strict=False):
        stats = getattr(node, "timing_stats", None)
        if stats is None:
            continue
        path = Path(folder) / f"{name.strip('/').replace('/', '_')}.stats.json"
        try:
            path.write_text(json.dumps({"node": name, **stats()}))
        except OSError as error:
            print(f"{name}: could not write {path}: {error}", file=sys.stderr)


def _reason(error: Exception) -> str:
    """A start-up error's message on one line (a ``KeyError``'s without its quotes)."""
    message = error.args[0] if isinstance(error, KeyError) and error.args else str(error)
    return " ".join(str(message).split())


#: Executors a node can spin in (``CRS_EXECUTOR``; default ``events``).
EXECUTORS = ("events", "single")


def make_executor() -> Executor:
    """The executor every node of the suite spins in: rclpy's events executor (callbacks
    dispatched from C++ as messages and timers become ready, instead of a wait set rebuilt in
    Python at every wake-up), or with ``CRS_EXECUTOR=single`` the single-threaded one.

    Measured with ``crs launch sim --cars 1 --estimator mhe`` (30 s, the same loaded machine,
    back to back): simulator + estimator + controller 53.7 % of one core with the events
    executor, 75.4 % with the single-threaded one; the recorder 10.5 % against 32.3 %. Nodes
    call ``spin_once`` in a loop: this rclpy's ``EventsExecutor.spin()`` dispatched nothing in
    a test here and never returned."""
    kind = os.environ.get("CRS_EXECUTOR", "events")
    if kind not in EXECUTORS:
        raise FieldError("CRS_EXECUTOR", f"one of {', '.join(EXECUTORS)}, got {kind!r}")
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    return SingleThreadedExecutor()


def _node_name(args: Sequence[str], make_node: Callable[[], Node]) -> str:
    """``/ns/name`` from the ``__ns:=`` / ``__node:=`` remaps, else the node class's name."""
    remaps = dict(a.split(":=", 1) for a in args if a.startswith(("__ns:=", "__node:=")))
    default = getattr(make_node, "__name__", "node").removesuffix("Node").lower()
    namespace = remaps.get("__ns", "").rstrip("/")
    return f"{namespace}/{remaps.get('__node', default)}"


def _start_failure(name: str, message: str) -> int:
    print(f"{name}: error: {message}", file=sys.stderr, flush=True)
    return 2
