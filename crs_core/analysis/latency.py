"""End-to-end latencies of the stack from recorded stamps: sensor -> estimate -> input -> command.

Every function takes ``times``: per topic kind (``"sensor"``, ``"estimate"``, ``"input"``) a
list of ``(stamp, receive time)`` pairs, s (the message's header stamp and the recorder's
receive time, as :attr:`ros4crs.bag_replay.BagContents.receive_times` holds them), and
matches each message to the newest one upstream of it with :func:`numpy.searchsorted`. Each
latency is reported in ms as the median and p95 (:func:`crs_core.analysis.statistics.summary`,
2 decimals), or ``{}`` when nothing matched. :data:`LATENCY_DEFINITIONS` says in words what
each one measures (``crs launch car`` copies it into ``report.json``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from crs_core.analysis.statistics import summary

__all__ = ["LATENCY_DEFINITIONS", "command_latencies", "input_chain_latency", "latencies"]

#: Stamp and receive time pairs per topic kind, s.
StampTimes = Mapping[str, list[tuple[float, float]]]

#: What each latency measures.
LATENCY_DEFINITIONS = {
    "sensor_to_estimate": "recorder receive time of each estimate minus the stamp of the newest "
    "sensor packet stamped at or before the estimate's stamp (includes the estimator's 20 ms lag)",
    "sensor_to_input": "recorder receive time of each input message minus the stamp of the newest "
    "sensor packet behind the newest estimate received before it",
    "sensor_to_command_read": "sensor packet -> estimate -> command packet: the emulator's read "
    "time of each reference minus the stamp of the newest sensor packet behind the estimate it was "
    "computed from (reference host stamp -> newest input stamped at or before it -> newest "
    "estimate received by that input's stamp -> newest sensor stamped at or before the estimate)",
    "sensor_to_input_chain": "the same chain ending at the recorder's receive time of the "
    "input message (defined alike for the direct simulator)",
    "sensor_to_command_sent": "the same chain ending at the bridge's send stamp of the reference",
    "command_sent_to_read": "bridge send stamp -> emulator read (loopback UDP + up to one "
    "4 ms tick)",
}


def _ms_summary(values: np.ndarray) -> dict[str, float]:
    """Median and p95, 2 decimals; ``{}`` for no values."""
    if values.size == 0:
        return {}
    return summary(values, ("median", "p95"), digits=2)


def latencies(times: StampTimes) -> dict[str, Any]:
    """End-to-end latencies from (stamp, receive time) pairs per topic kind, ms.

    ``sensor_to_estimate``: receive time of each estimate minus the stamp of the newest sensor
    sample it could include (stamp <= estimate stamp). ``sensor_to_input``: receive time of each
    car input minus the stamp of the newest sensor sample behind the estimate it used.
    """
    sensors = np.sort(np.array([s for s, _ in times.get("sensor", [])]))
    estimates = sorted(times.get("estimate", []), key=lambda p: p[1])
    inputs = sorted(times.get("input", []), key=lambda p: p[1])
    if sensors.size == 0 or not estimates:
        return {}
    est_stamp = np.array([s for s, _ in estimates])
    est_recv = np.array([r for _, r in estimates])
    newest = sensors[np.clip(np.searchsorted(sensors, est_stamp, side="right") - 1, 0, None)]
    to_estimate = (est_recv - newest) * 1e3
    out = {"sensor_to_estimate": _ms_summary(to_estimate)}
    if inputs:
        in_recv = np.array([r for _, r in inputs])
        used = np.searchsorted(est_recv, in_recv, side="right") - 1
        valid = used >= 0
        to_input = (in_recv[valid] - newest[used[valid]]) * 1e3
        out["sensor_to_input"] = _ms_summary(to_input)
    return out


def command_latencies(
    times: StampTimes, log: Mapping[str, ArrayLike]
) -> dict[str, dict[str, float] | int]:
    """The command-packet latencies (ms; see :data:`LATENCY_DEFINITIONS`), and the number of
    commands they were measured on (``commands_matched``), from the bag's
    ``(stamp, receive time)`` pairs and the car emulator's log (``command_host_t``: the bridge's
    send stamp of each reference it sent, ``command_read_t``: the emulator's read time of it)."""
    sensors = np.sort(np.array([s for s, _ in times.get("sensor", [])]))
    estimates = sorted(times.get("estimate", []), key=lambda p: p[1])
    input_stamps = np.sort(np.array([s for s, _ in times.get("input", [])]))
    sent = np.asarray(log["command_host_t"], dtype=float)
    read = np.asarray(log["command_read_t"], dtype=float)
    if sensors.size == 0 or not estimates or input_stamps.size == 0 or sent.size == 0:
        return {}
    est_stamp = np.array([s for s, _ in estimates])
    est_recv = np.array([r for _, r in estimates])
    keep = np.isfinite(sent)
    sent, read = sent[keep], read[keep]
    # a reference the bridge repeated (the same stamp) counts once, at its first read
    order = np.argsort(read, kind="stable")
    _, first = np.unique(sent[order], return_index=True)
    sent, read = sent[order][first], read[order][first]
    # the input each command was sent for: the newest stamped at or before its send stamp,
    # within one controller period (a command with no recorded input is left out)
    k = np.searchsorted(input_stamps, sent, side="right") - 1
    ok = (k >= 0) & (sent - input_stamps[np.clip(k, 0, None)] < 0.1)
    tick = input_stamps[k[ok]]
    sent, read = sent[ok], read[ok]
    e = np.searchsorted(est_recv, tick, side="right") - 1
    ok = e >= 0
    sent, read, e = sent[ok], read[ok], e[ok]
    s = np.searchsorted(sensors, est_stamp[e], side="right") - 1
    ok = s >= 0
    newest = sensors[s[ok]]
    sent, read = sent[ok], read[ok]
    return {
        "sensor_to_command_read": _ms_summary((read - newest) * 1e3),
        "sensor_to_command_sent": _ms_summary((sent - newest) * 1e3),
        "command_sent_to_read": _ms_summary((read - sent) * 1e3),
        "commands_matched": int(sent.size),
    }


def input_chain_latency(times: StampTimes) -> dict[str, float]:
    """``sensor_to_input_chain`` (ms): the recorder's receive time of each ``input`` minus the
    stamp of the newest sensor sample behind the newest estimate received by the input's stamp
    (the controller's tick): the chain of ``sensor_to_command_*`` ending at the input message,
    defined alike for the direct simulator (no packets there)."""
    sensors = np.sort(np.array([s for s, _ in times.get("sensor", [])]))
    estimates = sorted(times.get("estimate", []), key=lambda p: p[1])
    inputs = times.get("input", [])
    if sensors.size == 0 or not estimates or not inputs:
        return {}
    est_stamp = np.array([s for s, _ in estimates])
    est_recv = np.array([r for _, r in estimates])
    tick = np.array([s for s, _ in inputs])
    received = np.array([r for _, r in inputs])
    e = np.searchsorted(est_recv, tick, side="right") - 1
    ok = e >= 0
    s = np.searchsorted(sensors, est_stamp[e[ok]], side="right") - 1
    good = s >= 0
    return _ms_summary((received[ok][good] - sensors[s[good]]) * 1e3)
