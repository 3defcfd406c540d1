"""One car's UDP link (host side, ROS-free): receive, validate, pair, answer pings, command.

:class:`CarLink` owns a non-blocking UDP socket bound to ``(bind, port)`` (default
``127.0.0.1:20211``: loopback only unless told otherwise; a real car needs ``bind="0.0.0.0"`` or
the host's Wi-Fi address). One link per car; several cars use several ports.

Pairing. The car's endpoint (IP, port) is either configured (``car_ip`` and ``car_port``: paired
from the start) or learned from the **first valid datagram** (a car state or a ping that
decodes): with ``car_ip`` alone only that IP can pair (its port is learned), with neither any
sender can. Once paired the endpoint is pinned for the life of the link; a datagram from any
other (IP, port) is ignored unread and counted as ``foreign``. (Learning trusts the first valid
sender: on a shared network configure ``car_ip``.)

Every received datagram lands in exactly one bucket of :attr:`CarLink.counts`:

============  ==================================================================================
bucket        meaning
============  ==================================================================================
car_state     a valid car state, converted (returned by :meth:`CarLink.poll`)
duplicate     a valid car state already received (:class:`DatagramFilter`), not converted again
ping          a valid discovery ping (answered with ``should_bounce=false`` when it asked to be)
foreign       from another endpoint than the paired car's (or another IP than ``car_ip``)
oversize      more than 255 bytes (the firmware's buffer), not decoded
undecodable   not a protobuf ``Packet`` at all (field ``datagram``)
invalid       a ``Packet`` with a bad field: missing, unknown (or wrong wire type, or an unknown
              oneof tag), NaN/inf, out of range, too many repeated entries, a host-only content,
              a ``timestamp`` after 2038-01-19 (:data:`STAMP_MAX_US`)
error         a valid packet whose conversion failed or produced a non-finite value (never
              expected; kept so that nothing escapes the count)
============  ==================================================================================

:attr:`CarLink.rejected_fields` counts ``undecodable`` and ``invalid`` by the field the codec
named (indices and unknown field numbers folded, e.g. ``car_state.lighthouse_sweeps[].angle_0``,
``<unknown field>``, so the table stays small whatever arrives). Each reject calls ``warn``
with the field and reason, throttled to one call per ``warn_period`` s (the message says how
many were suppressed). Outgoing datagrams are counted in :attr:`CarLink.sent`.

Commands are repeated: the newest reference is sent again every ``repeat_period`` s (by
:meth:`CarLink.repeat`, called as often as the caller polls) for ``repeat_for`` s after it was
first sent, the same bytes (its stamp is the time it was first sent). The car cuts its motors
after 200 ms without a reference, so at the controller's 30 Hz six datagrams lost in a row
stopped it; bad Wi-Fi loses them in bursts (6 cut-offs in a 40 s race with the ``bad`` link
preset). A controller that stops sending still stops the car: at most ``repeat_for`` later.
Every 20 ms (the default) a command goes out once more between two of the controller's: every
10 ms, the emulated car's own process took 5 % more of a core reading them, which two
emulated cars on two cores could not spare.

Stamps: measurements carry the packet's ``timestamp`` when the car sent one (its clock is
SNTP-synchronised), else the receipt time ``now`` given to :meth:`CarLink.poll`
(:class:`~chronos_bridge.car_state.CarStateConverter`).

Wi-Fi loses, delays, duplicates and reorders datagrams. A car state is converted at most once
(:class:`DatagramFilter`: by its ``timestamp``, or by its bytes when it has none) and in the order
it arrives: the converter pairs the Lighthouse planes whatever the order, every measurement keeps
its measurement time, and the estimator orders measurements by stamp.
:attr:`CarLink.arrival` counts what came out of order (``reordered`` datagrams, Lighthouse
``sweeps_out_of_order``, ``sweeps_duplicate``); :meth:`CarLink.summary` reports it.
"""

from __future__ import annotations

import errno
import ipaddress
import logging
import math
import re
import socket
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from chronos_bridge import DEFAULT_PORT
from chronos_bridge.car_state import CarStateConverter, Converted
from chronos_bridge.codec import (
    CAR_DATAGRAM_MAX,
    DecodeError,
    decode_from_car,
    encode_ping_reply,
    encode_torque_command,
    encode_velocity_command,
    now_us,
)
from chronos_bridge.packets import CarState, Packet, Ping
from crs_core.errors import FieldError
from crs_core.settings import Settings, non_negative

#: The buckets of :attr:`CarLink.counts`, in report order.
BUCKETS = (
    "car_state",
    "duplicate",
    "ping",
    "foreign",
    "oversize",
    "undecodable",
    "invalid",
    "error",
)
#: Largest UDP payload; the receive buffer takes any datagram whole (an oversize one is counted,
#: not cut to look valid).
_RECV_SIZE = 65_536
#: Receive buffer asked of the kernel, bytes (capped by ``net.core.rmem_max``): a few thousand
#: car-sized datagrams, so a host that stalls for a moment does not drop the car's packets.
RECEIVE_BUFFER = 1 << 21

#: Latest packet timestamp accepted, µs since the Unix epoch: 2038-01-19T03:14:07Z, the last
#: second a ROS ``builtin_interfaces/Time`` (int32 ``sec``) holds. The codec accepts up to the
#: year 2100; a later stamp would wrap to a negative ROS time, so the link refuses it.
STAMP_MAX_US = (2**31 - 1) * 1_000_000
#: How long :class:`DatagramFilter` remembers a car state, s (the car's clock with a timestamp, the
#: receipt time without): far longer than a datagram stays in a Wi-Fi router's queues.
DUPLICATE_MEMORY_S = 2.0

_log = logging.getLogger(__name__)
_INDEX = re.compile(r"\[\d+\]")
_UNKNOWN = re.compile(r"<field \d+>")

Endpoint = tuple[str, int]


def field_key(field: str) -> str:
    """A codec field path folded for counting: ``a[3].b`` -> ``a[].b``, ``<field 7>`` ->
    ``<unknown field>``."""
    return _UNKNOWN.sub("<unknown field>", _INDEX.sub("[]", field))


def _ipv4(name: str, value: str) -> str:
    try:
        return str(ipaddress.IPv4Address(value))
    except ValueError:
        raise FieldError(name, f"not an IPv4 address, got {value!r}") from None


#: What :attr:`CarLinkSettings.imu_sensor` may be.
IMU_SENSORS = ("imu", "gyro")


@dataclass(frozen=True)
class CarLinkSettings(Settings):
    """Where a :class:`CarLink` listens, which car it pairs with, how it repeats commands.

    Attributes
    ----------
    port : int
        Local UDP port, 0..65535 (0: any free one, see :attr:`CarLink.address`; not for the
        bridge node, whose car must know the port).
    bind : str
        Local IPv4 address to bind; ``0.0.0.0`` for every interface (a real car).
    car_ip : str
        The car's IPv4 address; empty: learn it from the first valid datagram.
    car_port : int
        The car's UDP port, 0..65535; 0: learn it (a port needs ``car_ip``).
    imu_sensor : {"imu", "gyro"}
        The IMU's readings as ``imu`` (accelerations and yaw rate) or ``gyro`` (yaw rate).
    repeat_period : float
        The newest command is sent again this often, s (0: never).
    repeat_for : float
        ... for this long after it was first sent, s.
    """

    port: int = DEFAULT_PORT
    bind: str = "127.0.0.1"
    car_ip: str = ""
    car_port: int = 0
    imu_sensor: Literal["imu", "gyro"] = "imu"
    repeat_period: float = non_negative(0.02)
    repeat_for: float = non_negative(0.1)

    def _check_relations(self) -> None:
        for name in ("port", "car_port"):
            value = getattr(self, name)
            if not 0 <= int(value) <= 65535:
                raise FieldError(name, f"must be in 0..65535, got {value!r}")
        _ipv4("bind", self.bind)
        if self.car_ip:
            _ipv4("car_ip", self.car_ip)
        if self.car_port and not self.car_ip:
            raise FieldError(
                "car_port", f"needs car_ip (the port alone cannot pair), got {self.car_port}"
            )
        if self.imu_sensor not in IMU_SENSORS:
            raise FieldError(
                "imu_sensor", f"must be one of {', '.join(IMU_SENSORS)}, got {self.imu_sensor!r}"
            )


class DatagramFilter:
    """Recognises the car states already received (UDP may deliver a datagram twice).

    A car state with a ``timestamp`` (µs, the car's clock; one per 250 Hz step) is a duplicate
    when a car state with the same timestamp was accepted within the last ``memory_s`` s of the
    car's clock; without a timestamp (an unsynchronised car), when the same bytes were accepted
    within the last ``memory_s`` s of receipt time (two different steps of a real car never
    give the same bytes: the IMU is noisy). A timestamp more than ``memory_s`` before the
    newest is taken for a step back of the car's clock (SNTP) and starts the memory afresh.

    Counters: ``duplicates`` (rejected), ``reordered`` (accepted with a timestamp older than
    the newest accepted: overtaken on the way).
    """

    def __init__(self, memory_s: float = DUPLICATE_MEMORY_S) -> None:
        if not memory_s > 0.0:
            raise FieldError("memory_s", f"must be > 0, got {memory_s!r}")
        self.memory_us = round(memory_s * 1e6)
        self.memory_s = float(memory_s)
        self.duplicates = 0
        self.reordered = 0
        self._newest: int | None = None
        self._stamps: set[int] = set()
        self._stamp_order: deque[int] = deque()
        self._payloads: dict[bytes, float] = {}  # receipt order

    def accept(self, packet: Packet, data: bytes, now: float) -> bool:
        """True for a car state not received before (remembered from now on); False for a
        duplicate. ``data``: the datagram's bytes; ``now``: receipt time, s."""
        stamp = packet.timestamp_us
        if stamp is None:
            return self._accept_payload(data, now)
        if self._newest is not None and stamp < self._newest - self.memory_us:
            self._newest = None
            self._stamps.clear()
            self._stamp_order.clear()
        if stamp in self._stamps:
            self.duplicates += 1
            return False
        if self._newest is not None and stamp < self._newest:
            self.reordered += 1
        self._newest = stamp if self._newest is None else max(self._newest, stamp)
        self._stamps.add(stamp)
        self._stamp_order.append(stamp)
        while self._stamp_order[0] < self._newest - self.memory_us:
            self._stamps.discard(self._stamp_order.popleft())
        return True

    def _accept_payload(self, data: bytes, now: float) -> bool:
        while self._payloads:
            oldest = next(iter(self._payloads))
            if self._payloads[oldest] >= now - self.memory_s:
                break
            del self._payloads[oldest]
        if data in self._payloads:
            self.duplicates += 1
            return False
        self._payloads[data] = now
        return True


class CarLink:
    """The UDP link to one car; see the module docstring.

    Parameters
    ----------
    port, bind, car_ip, car_port, imu_sensor, repeat_period, repeat_for
        The fields of :class:`CarLinkSettings` (its defaults, checked there; ``port`` 0 picks a
        free one, see :attr:`address`), kept as :attr:`settings`.
    warn : callable
        Called with a one-line warning for rejects, refused commands and send failures (each
        kind throttled to one per ``warn_period`` s); default the module's logger.
    warn_period : float
        At most one reject warning per this many seconds (of the ``now`` given to poll).
    max_per_poll : int
        At most this many datagrams per :meth:`poll` (a flood cannot starve the caller; the rest
        wait in the socket for the next poll).
    """

    def __init__(
        self,
        port: int = CarLinkSettings.port,
        bind: str = CarLinkSettings.bind,
        car_ip: str = CarLinkSettings.car_ip,
        car_port: int = CarLinkSettings.car_port,
        imu_sensor: Literal["imu", "gyro"] = CarLinkSettings.imu_sensor,
        warn: Callable[[str], None] | None = None,
        warn_period: float = 1.0,
        max_per_poll: int = 2000,
        repeat_period: float = CarLinkSettings.repeat_period,
        repeat_for: float = CarLinkSettings.repeat_for,
    ) -> None:
        #: The link's settings (checked).
        self.settings = CarLinkSettings(
            port, bind, car_ip, car_port, imu_sensor, repeat_period, repeat_for
        )
        if max_per_poll < 1:
            raise FieldError("max_per_poll", f"must be >= 1, got {max_per_poll}")
        bind = _ipv4("bind", bind)
        self.car_ip = _ipv4("car_ip", car_ip) if car_ip else ""
        self.car_port = int(car_port)
        self.converter = CarStateConverter(imu_sensor)
        self.filter = DatagramFilter()
        self._warn = warn or _log.warning
        self.warn_period = float(warn_period)
        self.max_per_poll = int(max_per_poll)
        #: The car's endpoint once paired (configured or learned), else ``None``.
        self.endpoint: Endpoint | None = (self.car_ip, self.car_port) if car_port else None
        self.counts: dict[str, int] = dict.fromkeys(BUCKETS, 0)
        self.rejected_fields: dict[str, int] = {}
        self.sent: dict[str, int] = dict.fromkeys(
            ("commands", "repeats", "ping_replies", "unpaired", "invalid_commands", "send_errors"),
            0,
        )
        self.repeat_period, self.repeat_for = float(repeat_period), float(repeat_for)
        #: the newest reference sent: its bytes, when it was first and last sent (monotonic s)
        self._reference: tuple[bytes, float, float] | None = None
        #: Receipt time (``now`` of poll) of the last valid datagram from the car, or ``None``.
        self.last_valid: float | None = None
        self._last_warning = -math.inf
        self._suppressed = 0
        self._last_kind: dict[str, float] = {}
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._socket.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
            self._socket.bind((bind, int(port)))
        except OSError as error:
            self._socket.close()
            raise OSError(f"port: cannot bind UDP {bind}:{port}: {error.strerror}") from None
        self._socket.setblocking(False)

    # ------------------------------------------------------------------ properties
    @property
    def address(self) -> Endpoint:
        """The local (IP, port) the link listens on."""
        return self._socket.getsockname()

    @property
    def paired(self) -> bool:
        return self.endpoint is not None

    @property
    def received(self) -> int:
        """Datagrams received so far (the sum of :attr:`counts`)."""
        return sum(self.counts.values())

    @property
    def arrival(self) -> dict[str, int]:
        """Car states and sweeps that did not come once and in order: ``reordered`` datagrams
        (overtaken on the way), Lighthouse ``sweeps_out_of_order`` (second plane before the
        first) and ``sweeps_duplicate`` (dropped); duplicate datagrams are in :attr:`counts`."""
        return {
            "reordered": self.filter.reordered,
            "sweeps_out_of_order": self.converter.sweeps_out_of_order,
            "sweeps_duplicate": self.converter.sweeps_duplicate,
        }

    def fileno(self) -> int:
        """The socket's file descriptor (to wait on it with ``select``)."""
        return self._socket.fileno()

    # ------------------------------------------------------------------ receiving
    def poll(self, now: float) -> list[Converted]:
        """Read the pending datagrams (at most ``max_per_poll``); return the converted car states.

        ``now``: the host time of reception, s since the Unix epoch (the stamp of a packet
        without a timestamp). Never raises for anything a sender can put in a datagram.
        """
        out: list[Converted] = []
        for _ in range(self.max_per_poll):
            try:
                data, sender = self._socket.recvfrom(_RECV_SIZE)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as error:  # e.g. ECONNREFUSED queued by an ICMP error: not a datagram
                if error.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                    break
                continue
            self._receive(data, sender[:2], now, out)
        return out

    def _receive(self, data: bytes, sender: Endpoint, now: float, out: list[Converted]) -> None:
        if self.endpoint is not None:
            if sender != self.endpoint:
                self.counts["foreign"] += 1
                return
        elif self.car_ip and sender[0] != self.car_ip:
            self.counts["foreign"] += 1
            return
        if len(data) > CAR_DATAGRAM_MAX:
            self.counts["oversize"] += 1
            self._reject(now, "datagram", f"{len(data)} bytes > {CAR_DATAGRAM_MAX}", sender)
            return
        try:
            packet = decode_from_car(data)
            if packet.timestamp_us is not None and packet.timestamp_us > STAMP_MAX_US:
                raise DecodeError("timestamp", f"{packet.timestamp_us} µs is after 2038-01-19")
        except DecodeError as error:
            bucket = "undecodable" if error.field == "datagram" else "invalid"
            self.counts[bucket] += 1
            key = field_key(error.field)
            self.rejected_fields[key] = self.rejected_fields.get(key, 0) + 1
            self._reject(now, error.field, error.reason, sender)
            return
        except Exception as error:  # a decoder bug must not take the link down
            self.counts["error"] += 1
            self._reject(now, "datagram", f"decoder failed: {error!r}", sender)
            return
        if self.endpoint is None:
            self.endpoint = sender
            _log.info("paired with the car at %s:%d", *sender)
        self.last_valid = now
        contents = packet.contents
        if isinstance(contents, Ping):
            self.counts["ping"] += 1
            if contents.should_bounce:
                self._send(encode_ping_reply(), "ping_replies")
            return
        if not isinstance(contents, CarState):  # decode_from_car returns nothing else
            self.counts["error"] += 1
            return
        if not self.filter.accept(packet, data, now):
            self.counts["duplicate"] += 1
            return
        try:
            converted = self.converter.convert(packet, now)
            _check_finite(converted)
        except Exception as error:
            self.counts["error"] += 1
            self._reject(now, "car_state", f"conversion failed: {error}", sender)
            return
        self.counts["car_state"] += 1
        out.append(converted)

    def _reject(self, now: float, field: str, reason: str, sender: Endpoint) -> None:
        if now - self._last_warning < self.warn_period:
            self._suppressed += 1
            return
        more = f" (+{self._suppressed} rejects since the last warning)" if self._suppressed else ""
        self._last_warning, self._suppressed = now, 0
        self._warn(f"dropped datagram from {sender[0]}:{sender[1]}: {field}: {reason}{more}")

    # ------------------------------------------------------------------ sending
    def send_command(self, u: Sequence[float], mode: str, now: float | None = None) -> bool:
        """Send ``u`` as a ``CarReference`` to the paired car; True when sent.

        ``mode="torque"``: ``u = [steer (rad), torque (-)]`` -> ``{throttle, angle}``;
        ``mode="velocity"``: ``u = [steer (rad), v_x (m/s)]`` -> ``{longitudinal_velocity,
        angle}``. Stamped with ``now`` (s since the Unix epoch; default the host clock). Nothing
        is sent before pairing (``sent["unpaired"]``); a value the codec refuses (NaN/inf, out of
        range) is counted in ``sent["invalid_commands"]`` and warned about, never sent.
        """
        if self.endpoint is None:
            self.sent["unpaired"] += 1
            return False
        stamp = now_us() if now is None else int(now * 1e6)
        try:
            steer, second = float(u[0]), float(u[1])
            if mode == "torque":
                data = encode_torque_command(steer, second, stamp)
            elif mode == "velocity":
                data = encode_velocity_command(steer, second, stamp)
            else:
                raise FieldError("mode", f"must be torque or velocity, got {mode!r}")
        except (ValueError, TypeError, IndexError) as error:
            self.sent["invalid_commands"] += 1
            self._throttled("command", f"command not sent: {error}")
            return False
        sent_at = time.monotonic()
        self._reference = (data, sent_at, sent_at)
        return self._send(data, "commands")

    def repeat(self, now: float | None = None) -> bool:
        """Send the newest reference again when ``repeat_period`` s have passed since it was
        last sent and no more than ``repeat_for`` s since it was first sent; True when sent.
        ``now``: monotonic s (default :func:`time.monotonic`)."""
        if self._reference is None or self.repeat_period <= 0 or self.endpoint is None:
            return False
        now = time.monotonic() if now is None else float(now)
        data, first, last = self._reference
        if now - last < self.repeat_period or now - first > self.repeat_for:
            return False
        self._reference = (data, first, now)
        return self._send(data, "repeats")

    def _send(self, data: bytes, what: str) -> bool:
        try:
            self._socket.sendto(data, self.endpoint)
        except OSError as error:
            self.sent["send_errors"] += 1
            self._throttled("send", f"cannot send to the car at {self.endpoint}: {error}")
            return False
        self.sent[what] += 1
        return True

    def _throttled(self, kind: str, message: str) -> None:
        """``warn`` at most once per ``warn_period`` s (wall clock) per ``kind``."""
        now = time.monotonic()
        if now - self._last_kind.get(kind, -math.inf) >= self.warn_period:
            self._last_kind[kind] = now
            self._warn(message)

    # ------------------------------------------------------------------ reporting, closing
    def summary(self) -> str:
        """One line: the receive buckets, the arrival order, the top rejected fields, what was
        sent."""
        counts = ", ".join(f"{k} {v}" for k, v in self.counts.items())
        arrival = ", ".join(f"{k} {v}" for k, v in self.arrival.items())
        top = sorted(self.rejected_fields.items(), key=lambda kv: -kv[1])[:5]
        fields = ", ".join(f"{k} {v}" for k, v in top)
        sent = ", ".join(f"{k} {v}" for k, v in self.sent.items())
        peer = f"{self.endpoint[0]}:{self.endpoint[1]}" if self.endpoint else "not paired"
        return (
            f"car {peer}; received {self.received}: {counts}; arrival: {arrival}"
            + (f"; top rejected fields: {fields}" if fields else "")
            + f"; sent: {sent}"
        )

    def close(self) -> None:
        self._socket.close()

    def __enter__(self) -> CarLink:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()


def _check_finite(converted: Converted) -> None:
    """Defence in depth: the codec validated every value; a non-finite one after the
    conversion would be a bug, and must not reach a subscriber."""
    for measurement in converted.measurements:
        if not (math.isfinite(measurement.stamp) and np.all(np.isfinite(measurement.values))):
            raise FieldError(measurement.sensor, "non-finite value after conversion")
    t = converted.telemetry
    for value in (t.stamp, t.battery_voltage, t.battery_current, t.longitudinal_velocity):
        if value is not None and not math.isfinite(value):
            raise FieldError("telemetry", "non-finite value after conversion")
