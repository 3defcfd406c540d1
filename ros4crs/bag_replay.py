"""Offline replay of a bag straight into the ``crs_core`` estimators, without ROS.

Reads the sensor and input topics of one car from a bag (rosbags, no rclpy), converts them with
the same :mod:`ros4crs.conversions` the nodes use, and feeds an estimator. An estimator node
logs each of its queries on ``estimate/query`` with the first and the newest message of every
input stream it had received by then; :func:`replay_estimator` gives the estimator exactly those
messages before each query, so it reproduces the node's estimates exactly, whatever the
transport delays were (a message stamped before a query but arriving after it was not used
live, nor here) and whichever of the recorder and the estimator subscribed to a stream first
(a recorder that subscribed first holds messages the estimator never had; one that subscribed
last gets the publishers' recent history, see :data:`~ros4crs.node_support.STREAM_OUT_QOS`, and
where even that began after the estimator's first message the replay warns:
:class:`ReplayIncompleteWarning`).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import Reader

from crs_core.errors import FieldError
from crs_core.estimation.base import Estimate, Estimator, OnlineValue
from crs_core.measurements import InputSample, Measurement, from_start, in_stamp_order
from ros4crs import conversions
from ros4crs.bag_repair import open_bag
from ros4crs.interfaces import typestore

_FAMILY_OF_TOPIC = {topic: family for family, topic in conversions.TOPICS.items()}
#: The kinds of message whose receive times :attr:`BagContents.receive_times` keeps.
_RECEIVE_KINDS = ("sensor", "estimate", "input")


class ReplayIncompleteWarning(UserWarning):
    """The bag lacks messages the estimator node had: its replay is not exact."""


@dataclass(frozen=True)
class Query:
    """One query of an estimator node (``estimate/query``): the time asked for, whether the
    estimator started there, and per input stream the newest stamp it had and the first
    since the (re)start (s)."""

    stamp: float
    start: bool
    newest: dict[str, float]
    oldest: dict[str, float] = field(default_factory=dict)


@dataclass
class BagContents:
    """One car's data from a bag, in stamp order."""

    measurements: list[Measurement]
    inputs: list[InputSample]
    estimates: list[tuple[float, np.ndarray]]
    truth: list[tuple[float, np.ndarray]]
    malformed: int
    deadline_misses: int = 0
    updates: int = 0
    reinitializations: int = 0
    queries: list[Query] = field(default_factory=list)
    #: Velocity-mode commands on ``input``: not in ``inputs`` (they carry no torque; the
    #: estimator node ignores them too, so a replay sees what the node saw).
    velocity_references: int = 0
    #: The topic (relative to the car) the inputs were read from.
    input_topic: str = "input"
    #: The standard deviations (6,) of each of ``estimates``
    #: (:func:`~ros4crs.conversions.state_sigma_from_msg`).
    estimate_sigmas: list[np.ndarray] = field(default_factory=list)
    #: ``(header stamp, recorder receive time)`` in s per kind, ``sensor`` (a
    #: ``sensors/batch`` message: each reading's stamp with the batch's receive time),
    #: ``estimate`` (``estimate/state``) and ``input`` (the commands sent, ``input``).
    receive_times: dict[str, list[tuple[float, float]]] = field(
        default_factory=lambda: {kind: [] for kind in _RECEIVE_KINDS}
    )
    #: ``estimate/parameters``: each message's stamp and its online parameters by name.
    online_parameters: list[tuple[float, dict[str, OnlineValue]]] = field(default_factory=list)
    #: ``ground_truth/parameters``: each message's stamp and the simulated car's drifted
    #: parameters by name (a car with a drift schedule).
    truth_parameters: list[tuple[float, dict[str, float]]] = field(default_factory=list)


def read_car(bag: str | Path, namespace: str = "", input_topic: str = "input") -> BagContents:
    """Sensors, inputs, published estimates, queries and truth of the car in ``namespace``.

    ``input_topic``: where the model inputs are read from, the commands sent (``input``) or
    the inputs the car reported applying (``input/applied``, as the estimator of a real or
    emulated car takes them).

    A cut-off bag is read up to its last complete message, with a
    :class:`~ros4crs.bag_repair.BagDamagedWarning` saying what was lost.
    """
    with open_bag(bag) as reader:
        return read_car_from(reader, namespace, input_topic)


def read_car_from(reader: Reader, namespace: str = "", input_topic: str = "input") -> BagContents:
    """:func:`read_car` on an open reader (:func:`~ros4crs.bag_repair.open_bag`)."""
    store = typestore()
    prefix = namespace.rstrip("/") + "/" if namespace else "/"
    measurements, inputs, estimates, truth, queries = [], [], [], [], []
    online: list[tuple[float, dict[str, OnlineValue]]] = []
    truth_parameters: list[tuple[float, dict[str, float]]] = []
    estimate_sigmas: list[np.ndarray] = []
    receive_times: dict[str, list[tuple[float, float]]] = {k: [] for k in _RECEIVE_KINDS}
    malformed = velocity_references = 0
    diagnostics = None
    wanted = [c for c in reader.connections if c.topic.startswith(prefix)]
    for connection, received, data in reader.messages(wanted) if wanted else ():
        relative = connection.topic[len(prefix) :]
        family = _FAMILY_OF_TOPIC.get(relative)
        sent_command = family == "input"  # its receive time is kept whatever the inputs are
        if family in ("input", "applied_input"):
            family = "input" if relative == input_topic else None
        if family is None and not sent_command:
            continue
        msg = store.deserialize_cdr(bytes(data), connection.msgtype)
        kind = None  # of its receive time
        if sent_command:
            kind = "input"
        elif relative.startswith("sensors/"):
            kind = "sensor"
        elif family == "state":
            kind = "estimate"
        try:
            if kind is not None and family != "batch":
                stamp = conversions.seconds_from_stamp(msg.header.stamp)
                receive_times[kind].append((stamp, received * 1e-9))
            if family in conversions.SENSOR_PARSERS:
                measurements.append(conversions.SENSOR_PARSERS[family](msg))
            elif family == "batch":
                readings = conversions.batch_from_msg(msg)
                measurements.extend(readings.measurements)
                receive_times["sensor"].extend(
                    (m.stamp, received * 1e-9) for m in readings.measurements
                )
                malformed += len(readings.rejected)
            elif family == "input":
                command = conversions.input_from_msg(msg)
                if command.mode == "torque":
                    inputs.append(command.input_sample())
                else:  # a velocity reference is no model input (as in the estimator node)
                    velocity_references += 1
            elif family == "state":
                estimate = conversions.state_from_msg(msg)
                estimate_sigmas.append(conversions.state_sigma_from_msg(msg))
                estimates.append(estimate)
            elif family == "ground_truth":
                truth.append(conversions.state_from_msg(msg))
            elif family == "diagnostics":
                diagnostics = msg
            elif family == "query":
                queries.append(Query(*conversions.query_from_msg(msg)))
            elif family == "parameters":
                online.append(conversions.online_parameters_from_msg(msg))
            elif family == "truth_parameters":
                stamp, values = conversions.online_parameters_from_msg(msg)
                truth_parameters.append((stamp, {k: v.value for k, v in values.items()}))
        except ValueError:
            malformed += 1
    measurements.sort(key=lambda m: (m.stamp, m.sensor))
    inputs.sort(key=lambda s: s.stamp)
    contents = BagContents(
        measurements,
        inputs,
        estimates,
        truth,
        malformed,
        queries=queries,
        velocity_references=velocity_references,
        input_topic=input_topic,
        estimate_sigmas=estimate_sigmas,
        receive_times=receive_times,
        online_parameters=online,
        truth_parameters=truth_parameters,
    )
    if diagnostics is not None:
        contents.deadline_misses = int(diagnostics.deadline_misses)
        contents.updates = int(diagnostics.updates)
        contents.reinitializations = int(diagnostics.reinitializations)
    return contents


def replay_estimator(
    contents: BagContents,
    estimator: Estimator,
    queries: Iterable[Query],
    x0: np.ndarray | None,
) -> list[Estimate | None]:
    """The estimates of ``estimator`` at each query, fed as the node that logged them was.

    At a ``start`` query the estimator is reset there (to ``x0``; ``None``: a blind start) on
    :func:`~crs_core.measurements.from_start` of the data it had; before any other query it
    gets every message up to the query's newest stamp of each stream, then is asked for the
    estimate (``None`` where that fails, as the node logs and skips it; also at a start).
    Messages of a stream older than the first the node had since its (re)start (its ``oldest``
    in the first query that lists the stream, which may come after the start) are left out
    (the recorder subscribed before the estimator); where the bag's stream begins after that
    first message, a :class:`ReplayIncompleteWarning` says so.
    """
    queries = list(queries)
    if not queries or not queries[0].start:
        raise FieldError(
            "queries",
            "the first is not the estimator's start (was the bag recorded from the "
            "start of the estimator node, with estimate/query?)",
        )
    streams: dict[str, list[Measurement | InputSample]] = {}
    for item in in_stamp_order(contents.measurements, contents.inputs):
        streams.setdefault(_stream_of(item, contents.input_topic), []).append(item)
    taken = dict.fromkeys(streams, 0)
    begun: set[str] = set()  # the streams the node has had since its (re)start
    out: list[Estimate | None] = []
    for query in queries:
        if query.start:
            begun.clear()
        for stream, items in streams.items():
            # a stream's first message may reach the node after its start (the controller's
            # first commands came before the estimator subscribed; the recorder has them)
            if stream not in begun and stream in query.oldest:
                taken[stream] = _first_taken(stream, items, taken[stream], query)
                begun.add(stream)
        arrived: list[Measurement | InputSample] = []
        for stream, items in streams.items():
            newest, k = query.newest.get(stream, -np.inf), taken[stream]
            while k < len(items) and items[k].stamp <= newest:
                arrived.append(items[k])
                k += 1
            taken[stream] = k
        if query.start:
            estimator.reset(query.stamp, x0)
            arrived = from_start(
                in_stamp_order(
                    [i for i in arrived if isinstance(i, Measurement)],
                    [i for i in arrived if isinstance(i, InputSample)],
                ),
                query.stamp,
            )
        for item in arrived:
            estimator.add(item)
        if query.start:
            out.append(None)
            continue
        try:
            out.append(estimator.estimate(query.stamp))
        except ValueError:
            out.append(None)
    return out


def _first_taken(
    stream: str, items: list[Measurement | InputSample], taken: int, query: Query
) -> int:
    """Where the (re)started estimator's data of ``stream`` begin in ``items`` (stamp order,
    the first ``taken`` already given): at the first message the node had, as ``query`` logs it
    (also skipping those after the last query that it never had). Warns where the bag has no
    message at that stamp."""
    first = query.oldest[stream]
    k = taken
    while k < len(items) and items[k].stamp < first:
        k += 1
    # stamps went through a ROS Time (whole ns) and back: equal within 1 ns
    if k == len(items) or items[k].stamp > first + 1e-9:
        warnings.warn(
            f"{stream}: the estimator's data began at {first:.6f} s but the bag has no message "
            "then (the recorder joined late): the replay is not exact",
            ReplayIncompleteWarning,
            stacklevel=3,
        )
    return k


def _stream_of(item: Measurement | InputSample, input_topic: str) -> str:
    """The topic (relative to the car) an item came on."""
    if isinstance(item, InputSample):
        return input_topic
    return conversions.TOPICS[conversions.topic_family(item.sensor)]
