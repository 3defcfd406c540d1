r"""A car's ``CarState`` <-> the suite's measurement stream (ROS-free).

Host side: :class:`CarStateConverter` (one per car) turns decoded packets into
:class:`crs_core.measurements.Measurement` objects and a :class:`Telemetry` record:

- ``imu`` = ``[a_x, a_y, ω]`` in the body frame (m/s², rad/s): the board's x and y axes point the
  other way, so x and y of both vectors are negated and z kept; ω is the gyro's z. With
  ``imu_sensor="gyro"`` the converter publishes ``gyro`` = ``[ω]`` instead (as the real
  recordings hold it). Never both: they would count the yaw rate twice.
- ``wheel_encoders`` = ``[fl, fr, rl, rr]`` rad/s (the wire order is fr, fl, rr, rl), when the
  packet carries wheel speeds.
- ``lighthouse/<station>/<plane>`` = the 4 sweep angles (rad) in the sensor model's convention
  (:mod:`crs_core.model.lighthouse`): station = ``polynomial >> 1``; plane from the pairing rule
  of the spec, made independent of the arrival order (:meth:`CarStateConverter.convert`: the
  sweeps of one rotation share ``sync_timestamp``, plane 1 has the earlier deck ticks); angle
  offset ``-π + π/3`` (plane 1) or ``-π - π/3`` (plane 2); a sweep whose corrected angle_0 is
  outside [-1.5, 1.5] rad is out of view and dropped (the pairing sees it; only its publication
  is dropped).

Stamps: every measurement of a packet gets the packet's stamp, ``Packet.timestamp`` (µs since
the Unix epoch, converted to s) when present, else the ``receipt_stamp`` the caller passes (s,
the host clock at reception); a Lighthouse sweep its measurement time from the deck's ticks
(:class:`DeckClock`), also when it is published later, by its partner. Packets may arrive in any
order; a duplicate packet must be dropped before (:class:`chronos_bridge.link.DatagramFilter`).

Car side (the emulator): :func:`board_imu`, :func:`wire_wheel_speeds`, :func:`raw_sweep_angles`
map the suite's values to the firmware's raw values; :class:`SweepClock` makes 24-bit deck
timestamps that the host pairs; :class:`CarStateAssembler` collects one 250 Hz step of
measurements into a ``CarState`` datagram.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from chronos_bridge.codec import encode_car_state_fitting
from chronos_bridge.packets import (
    MAX_SWEEPS,
    STEER_LIMIT,
    TICKS_24BIT,
    Battery,
    CarState,
    ControlInput,
    FieldError,
    Imu,
    LighthouseSweep,
    Packet,
    Steering,
    WheelSpeeds,
)
from crs_core.measurements import Measurement, lighthouse_sensor, parse_lighthouse

#: Angle added to a raw sweep angle of plane 1 and plane 2 (rad) to reach the model convention.
PLANE_OFFSETS = {1: -math.pi + math.pi / 3, 2: -math.pi - math.pi / 3}
#: A sweep whose ``sync_timestamp`` is within this many ticks of the held first plane's is its
#: second plane (24-bit wrap-around difference).
PAIRING_TICKS = 100
#: A sweep whose raw angle_0 is within this of the held first plane's is the next first plane, rad.
NEW_FIRST_PLANE_RAD = 0.1
#: How long the pairing remembers a station's sweeps, s (measurement time): longer than the
#: reordering of a Wi-Fi link (tens of ms) and than a rotation (20 ms), well inside the 0.35 s
#: over which 24-bit tick differences are unambiguous.
MEMORY_S = 0.1
#: Corrected angle_0 outside ±this is out of view, rad.
IN_VIEW_RAD = 1.5
#: Standard gravity, m/s² (the accelerometer's z at rest).
GRAVITY = 9.80665
#: Lighthouse deck tick rate assumed by the emulator, Hz (24-bit counter: wraps every ~0.7 s).
DECK_TICK_HZ = 24_000_000
#: The sensors' true ranges (the emulator saturates there, as the BMI088 does).
GYRO_RANGE = math.radians(250.0)
ACCEL_RANGE = 3.0 * GRAVITY


def tick_difference(a: int, b: int) -> int:
    """Signed 24-bit difference ``a - b`` in ``[-2**23, 2**23)`` (wrap-around aware)."""
    d = (a - b) % TICKS_24BIT
    return d - TICKS_24BIT if d >= TICKS_24BIT // 2 else d


@dataclass(frozen=True, slots=True)
class Telemetry:
    """What a car state says besides measurements, at ``stamp`` (s, as the measurements).

    ``battery_voltage`` V and ``battery_current`` A (negative when discharging; ``None`` when not
    sent), ``steer_angle`` rad and ``steer_adc`` counts (``steer_adc_range`` the potentiometer's
    (low, high) when sent), ``longitudinal_velocity`` the car's own v_x estimate (m/s, or
    ``None``), ``drive_power`` / ``steer_power`` the motor powers in [-1, 1], ``reference`` the
    command the car is executing.
    """

    stamp: float
    battery_voltage: float | None
    battery_current: float | None
    steer_angle: float
    steer_adc: int
    steer_adc_range: tuple[int, int] | None
    longitudinal_velocity: float | None
    drive_power: float
    steer_power: float
    reference: ControlInput


@dataclass(frozen=True, slots=True)
class Converted:
    """The measurements (in publication order) and the telemetry of one car state."""

    measurements: tuple[Measurement, ...]
    telemetry: Telemetry


class DeckClock:
    """The Lighthouse deck's 24-bit tick counter mapped onto the packet clock.

    A sweep is carried by the first ``CarState`` after it was measured, so ``packet stamp -
    deck time`` (deck time: the sweep's ``first_timestamp`` unwrapped, over
    :data:`DECK_TICK_HZ`) is the clocks' offset plus a delay of 0 to 4 ms (one 250 Hz step; more
    when the sweep waited for room in a later packet). The smallest difference over the last
    ``window`` sweeps (10: about 0.1 s) estimates the offset, following a drifting deck clock
    and re-anchoring within a window after a jump of the car's clock (an emulator on a loaded
    host falls behind the wall clock and re-anchors its ticks); a sweep is
    stamped at its deck time plus that offset (never after its packet). Unwrapping needs a sweep
    at least every 0.35 s (half the counter's 0.699 s period): after a longer gap (a Lighthouse
    blackout) the clock starts afresh. A stamp more than ``max_age`` s before its packet (deck
    ticks that do not follow the packet clock) falls back to the packet's stamp, counted in
    ``fallbacks``.

    Out-of-order packets: ticks unwrap relative to the newest sweep seen (an older sweep, within
    0.35 s, gets an older deck time and does not move the reference), and the gap that restarts
    the clock is measured from the newest packet stamp, so a late packet never restarts it. With
    ``Packet.timestamp`` the packet stamp is the car's send time and a late arrival changes no
    offset; stamped on receipt, a late packet's offset is too large and the minimum ignores it.
    """

    def __init__(self, window: int = 10, max_age: float = 0.05) -> None:
        self.window, self.max_age = int(window), float(max_age)
        self.fallbacks = 0
        self.restart()

    def restart(self) -> None:
        """Forget the offset and the unwrapping."""
        self._ticks: int | None = None
        self._unwrapped = 0
        self._packet = -math.inf
        self._offsets: deque[float] = deque(maxlen=self.window)

    def stamp(self, ticks: int, packet_stamp: float) -> float:
        """Measurement time (s, the packet clock) of a sweep with ``first_timestamp`` ticks
        carried by a packet stamped ``packet_stamp``."""
        ticks = int(ticks)
        if self._ticks is None or packet_stamp - self._packet > 0.5 * TICKS_24BIT / DECK_TICK_HZ:
            self.restart()
            unwrapped = ticks
        else:
            unwrapped = self._unwrapped + tick_difference(ticks, self._ticks)
        if self._ticks is None or unwrapped > self._unwrapped:
            self._ticks, self._unwrapped = ticks, unwrapped
        self._packet = max(self._packet, packet_stamp)
        deck_time = unwrapped / DECK_TICK_HZ
        self._offsets.append(packet_stamp - deck_time)
        stamp = min(deck_time + min(self._offsets), packet_stamp)
        if packet_stamp - stamp > self.max_age:
            self.fallbacks += 1
            return packet_stamp
        return stamp


@dataclass(slots=True)
class _Sweep:
    """A sweep the pairing remembers without a partner: its measurement time (s), whether it was
    published (as plane 1, by the angle rule) and whether that was against a known first plane."""

    sweep: LighthouseSweep
    stamp: float
    published: bool
    known: bool


@dataclass(slots=True)
class _Station:
    """The pairing's memory of one base station (entries newest last)."""

    #: Sweeps without a partner yet.
    unpaired: list[_Sweep]
    #: The two sweeps of recent pairs (a sweep of a rotation already paired is a duplicate).
    pairs: deque[tuple[LighthouseSweep, LighthouseSweep, float]]
    #: Recent sweeps known to be plane 1 (paired, or by the angle rule) and their stamps.
    firsts: deque[tuple[LighthouseSweep, float]]
    #: The spec's held first plane (the last sweep that was not a second plane).
    held: LighthouseSweep | None = None


class CarStateConverter:
    """Host side: validated ``CarState`` packets of one car -> measurements + telemetry.

    Stateful (the Lighthouse pairing remembers each station's recent sweeps; the
    :class:`DeckClock` stamps sweeps at their measurement time from the deck's ticks): use one
    per car. Packets may come in any order (UDP over Wi-Fi reorders), but each once: drop
    duplicates before (:class:`chronos_bridge.link.DatagramFilter`). Counters: ``states``,
    ``sweeps_out_of_view``, ``sweeps_held`` (sweeps held without a plane when they came),
    ``sweeps_unpaired`` (held sweeps forgotten without a plane, never published),
    ``sweeps_out_of_order`` (pairs whose second plane came first), ``sweeps_duplicate``
    (dropped), ``sweeps_wrong_plane`` (published as plane 1, found a plane 2 by its partner:
    see :meth:`convert`); ``deck_clock.fallbacks``.
    """

    def __init__(self, imu_sensor: Literal["imu", "gyro"] = "imu") -> None:
        if imu_sensor not in ("imu", "gyro"):
            raise FieldError("imu_sensor", f"'imu' or 'gyro', got {imu_sensor!r}")
        self.imu_sensor = imu_sensor
        self._stations: dict[int, _Station] = {}
        self.deck_clock = DeckClock()
        self.states = 0
        self.sweeps_out_of_view = 0
        self.sweeps_held = 0
        self.sweeps_unpaired = 0
        self.sweeps_out_of_order = 0
        self.sweeps_duplicate = 0
        self.sweeps_wrong_plane = 0

    def reset(self) -> None:
        """Forget the remembered sweeps and the deck clock (e.g. when the car reconnects)."""
        self._stations.clear()
        self.deck_clock.restart()

    def convert(self, packet: Packet, receipt_stamp: float) -> Converted:
        """Measurements and telemetry of a ``Packet{car_state}`` from :func:`decode_from_car`.

        ``receipt_stamp``: host time of reception, s since the Unix epoch; used when the packet
        has no timestamp. IMU, wheel speeds and telemetry carry the packet's stamp (sampled in
        the step that sends them); a Lighthouse sweep its own measurement time from the deck's
        ticks (:class:`DeckClock`: a sweep waits up to a 4 ms step, more for room in a packet,
        which at 1.6 m/s is millimetres).

        Lighthouse pairing, per sweep, for its station; the spec's rule made independent of the
        arrival order. Both planes of one rotation carry the same ``sync_timestamp`` and plane 1
        is swept first (its raw angle, the rotor's angle since the sync, is 2π/3 below plane 2's),
        so among the station's sweeps remembered without a partner (those of the last
        :data:`MEMORY_S`):

        1. one whose ``sync_timestamp`` is within ±100 ticks (24-bit difference) is the partner:
           the earlier ``first_timestamp`` is plane 1, the other plane 2 (on equal ticks the one
           that came first; a partner published as plane 1 by rule 2 against a known first plane
           stays plane 1); the pair's unpublished sweeps are published, plane 1 first;
        2. otherwise, if its raw angle_0 is within 0.1 rad of plane 1's, it is a new first plane
           (published, remembered: its plane 2 may still come). Plane 1 is the known first
           plane (paired, or by this rule) nearest in deck ticks within :data:`MEMORY_S`, else
           the spec's held first plane (the last sweep that was not a second plane);
        3. otherwise it is held, unpublished, and becomes the held first plane if it is the
           newest; forgotten after :data:`MEMORY_S` if no partner came (``sweeps_unpaired``).

        For packets in order this is the spec's rule, except that a first plane that passes
        rule 2 against a known first plane is published even when a lone plane 2 (its plane 1
        lost) came in between. A sweep of a rotation already paired, or one equal to a
        remembered sweep, is a duplicate and dropped (``sweeps_duplicate``). Left as in the spec:
        with no known first plane (the start, after a blackout of the station) rule 2 compares
        with the held sweep, which may be a plane 2 whose plane 1 is late or lost; a sweep it
        then publishes as plane 1 is not taken for a known first plane (the error does not
        spread), and when its partner shows it was a plane 2 it is counted in
        ``sweeps_wrong_plane`` (published already; the partner is published as plane 1).
        """
        state = packet.contents
        if not isinstance(state, CarState):
            raise TypeError(f"convert: needs a car_state packet, got {type(state).__name__}")
        stamp = packet.stamp_s if packet.timestamp_us is not None else float(receipt_stamp)
        self.states += 1
        out: list[Measurement] = []
        acc, gyro = state.imu.linear_acceleration, state.imu.angular_velocity
        if self.imu_sensor == "imu":
            out.append(Measurement(stamp, "imu", np.array([-acc[0], -acc[1], gyro[2]])))
        else:
            out.append(Measurement(stamp, "gyro", np.array([gyro[2]])))
        w = state.wheel_speeds
        if w is not None:
            values = np.array([w.front_left, w.front_right, w.rear_left, w.rear_right])
            out.append(Measurement(stamp, "wheel_encoders", values))
        for sweep in state.sweeps:
            self._pair(sweep, self.deck_clock.stamp(sweep.first_timestamp, stamp), out)
        s = state.steering
        battery = state.battery
        telemetry = Telemetry(
            stamp=stamp,
            battery_voltage=None if battery is None else battery.voltage,
            battery_current=None if battery is None else battery.current,
            steer_angle=s.steer_rad,
            steer_adc=s.adc_meas,
            steer_adc_range=s.adc_range,
            longitudinal_velocity=state.longitudinal_velocity,
            drive_power=state.drive_power,
            steer_power=state.steer_power,
            reference=state.current_reference,
        )
        return Converted(tuple(out), telemetry)

    def _station(self, station: int, stamp: float) -> _Station:
        """The station's memory with what is older than :data:`MEMORY_S` before ``stamp``
        forgotten (so that 24-bit tick differences within it are unambiguous)."""
        memory = self._stations.get(station)
        if memory is None:
            memory = self._stations[station] = _Station([], deque(maxlen=8), deque(maxlen=8))
            return memory
        oldest = stamp - MEMORY_S
        kept = [entry for entry in memory.unpaired if entry.stamp >= oldest]
        self.sweeps_unpaired += sum(
            not entry.published for entry in memory.unpaired if entry.stamp < oldest
        )
        memory.unpaired = kept
        while memory.pairs and memory.pairs[0][2] < oldest:
            memory.pairs.popleft()
        while memory.firsts and memory.firsts[0][1] < oldest:
            memory.firsts.popleft()
        return memory

    def _pair(self, sweep: LighthouseSweep, stamp: float, out: list[Measurement]) -> None:
        memory = self._station(sweep.station, stamp)

        def same_rotation(other: LighthouseSweep) -> bool:
            return abs(tick_difference(sweep.sync_timestamp, other.sync_timestamp)) <= PAIRING_TICKS

        if any(same_rotation(first) for first, _, _ in memory.pairs) or any(
            entry.sweep == sweep for entry in memory.unpaired
        ):
            self.sweeps_duplicate += 1
            return
        partner = next((e for e in memory.unpaired if same_rotation(e.sweep)), None)
        if partner is not None:
            memory.unpaired.remove(partner)
            new = _Sweep(sweep, stamp, published=False, known=False)
            earlier = tick_difference(sweep.first_timestamp, partner.sweep.first_timestamp) < 0
            first, second = (new, partner) if earlier and not partner.known else (partner, new)
            if first is new:
                self.sweeps_out_of_order += 1
                self.sweeps_wrong_plane += partner.published
            if not first.published:
                self._publish(first.sweep, 1, first.stamp, out)
            if not second.published:  # else published as plane 1 by the held-plane rule: wrong
                self._publish(second.sweep, 2, second.stamp, out)
            memory.pairs.append((first.sweep, second.sweep, min(first.stamp, second.stamp)))
            self._first_plane(memory, first.sweep, first.stamp, known=True)
            return
        known = bool(memory.firsts)
        reference = (
            min(
                (first for first, _ in memory.firsts),
                key=lambda f: abs(tick_difference(sweep.first_timestamp, f.first_timestamp)),
            )
            if known
            else memory.held
        )
        if (
            reference is not None
            and abs(sweep.angles[0] - reference.angles[0]) <= NEW_FIRST_PLANE_RAD
        ):
            memory.unpaired.append(_Sweep(sweep, stamp, published=True, known=known))
            self._publish(sweep, 1, stamp, out)
            self._first_plane(memory, sweep, stamp, known)
            return
        memory.unpaired.append(_Sweep(sweep, stamp, published=False, known=False))
        self.sweeps_held += 1
        self._first_plane(memory, sweep, stamp, known=False)

    @staticmethod
    def _first_plane(memory: _Station, sweep: LighthouseSweep, stamp: float, known: bool) -> None:
        """``sweep`` is (``known``) or may be the station's first plane: remember it."""
        if known:
            memory.firsts.append((sweep, stamp))
        if memory.held is None or not _newer(memory.held, sweep):
            memory.held = sweep

    def _publish(
        self, sweep: LighthouseSweep, plane: int, stamp: float, out: list[Measurement]
    ) -> None:
        angles = np.array(sweep.angles) + PLANE_OFFSETS[plane]
        if not -IN_VIEW_RAD <= angles[0] <= IN_VIEW_RAD:
            self.sweeps_out_of_view += 1
            return
        out.append(Measurement(stamp, lighthouse_sensor(sweep.station, plane), angles))


def _newer(a: LighthouseSweep, b: LighthouseSweep) -> bool:
    """Whether sweep ``a`` was measured after ``b`` (deck ticks, within half a wrap)."""
    return tick_difference(a.first_timestamp, b.first_timestamp) > 0


# --------------------------------------------------------------------------- car side


def board_imu(
    imu: Sequence[float],
    vertical_acceleration: float = GRAVITY,
    roll_pitch_rates: tuple[float, float] = (0.0, 0.0),
) -> Imu:
    """The suite's ``imu`` = ``[a_x, a_y, ω]`` (body) -> the board-axes reading.

    Body x and y are negated, z kept; the accelerometer's z is ``vertical_acceleration`` (m/s²,
    +g at rest on a level track), the gyro's x and y are body ``roll_pitch_rates`` (rad/s).
    Each axis saturates at the sensor's range (±3 g, ±250 °/s) as the BMI088 does.
    """
    ax, ay, omega = (float(v) for v in imu)
    wx, wy = roll_pitch_rates

    def clip(value: float, limit: float) -> float:
        return min(max(value, -limit), limit)

    return Imu(
        tuple(clip(v, ACCEL_RANGE) for v in (-ax, -ay, vertical_acceleration)),
        tuple(clip(v, GYRO_RANGE) for v in (-wx, -wy, omega)),
    )


def wire_wheel_speeds(wheel_encoders: Sequence[float]) -> WheelSpeeds:
    """The suite's ``wheel_encoders`` ``[fl, fr, rl, rr]`` (rad/s) -> the wire's fr, fl, rr, rl."""
    fl, fr, rl, rr = (float(v) for v in wheel_encoders)
    return WheelSpeeds(front_right=fr, front_left=fl, rear_right=rr, rear_left=rl)


def raw_sweep_angles(plane: int, angles: Iterable[float]) -> tuple[float, float, float, float]:
    """Model-convention sweep angles of ``plane`` (1 or 2) -> the firmware's raw angles (the
    host's plane offset subtracted)."""
    if plane not in PLANE_OFFSETS:
        raise FieldError("plane", f"1 or 2, got {plane!r}")
    raw = tuple(float(a) - PLANE_OFFSETS[plane] for a in angles)
    if len(raw) != 4:
        raise FieldError("angles", f"needs 4, got {len(raw)}")
    return raw  # type: ignore[return-value]


def steering_from_angle(
    steer: float, adc_per_rad: float = 1500.0, adc_center: int = 2048
) -> Steering:
    """A plausible ``SteeringPositionMeasurement`` for a steering angle (rad): a 12-bit ADC
    reading linear in the angle (``adc_center + adc_per_rad·δ``)."""
    steer = min(max(float(steer), -STEER_LIMIT), STEER_LIMIT)
    return Steering(steer, round(adc_center + adc_per_rad * steer))


class SweepClock:
    """24-bit Lighthouse deck timestamps for emulated sweeps that the host pairs correctly.

    A plane-1 sweep at time ``t`` (s) gets ``sync_timestamp = first_timestamp = ticks(t)``. A
    plane-2 sweep within ``pair_window_s`` after the last plane 1 of its station gets that
    plane's ``sync_timestamp`` (difference 0, within the host's ±100 ticks) and its own
    ``first_timestamp = ticks(t)``; a plane 2 without a recent plane 1 (it was lost) gets
    ``sync = ticks(t)``, which does not pair, as on the real deck. ``ticks(t) =
    round(t · tick_hz) mod 2**24``.
    """

    def __init__(self, tick_hz: float = DECK_TICK_HZ, pair_window_s: float = 0.015) -> None:
        self.tick_hz = float(tick_hz)
        self.pair_window_s = float(pair_window_s)
        self._first: dict[int, tuple[float, int]] = {}

    def ticks(self, t: float) -> int:
        return round(t * self.tick_hz) % TICKS_24BIT

    def timestamps(self, station: int, plane: int, t: float) -> tuple[int, int]:
        """``(first_timestamp, sync_timestamp)`` of a sweep of ``station``/``plane`` at ``t``."""
        now = self.ticks(t)
        if plane == 1:
            self._first[station] = (t, now)
            return now, now
        first = self._first.get(station)
        if first is not None and 0.0 <= t - first[0] <= self.pair_window_s:
            return now, first[1]
        return now, now


def raw_sweep(
    measurement: Measurement, clock: SweepClock, t: float | None = None
) -> LighthouseSweep:
    """A ``lighthouse/<station>/<plane>`` measurement -> the firmware's sweep.

    Raw angles (:func:`raw_sweep_angles`), ``polynomial = station << 1`` (the low bit, which
    the host ignores, is 0: the first of the station's two LFSR polynomials), deck timestamps
    from ``clock`` at ``t`` (default the measurement's stamp, s).
    """
    parsed = parse_lighthouse(measurement.sensor)
    if parsed is None:
        raise FieldError("sensor", f"not a lighthouse sensor: {measurement.sensor!r}")
    station, plane = parsed
    first, sync = clock.timestamps(station, plane, measurement.stamp if t is None else t)
    return LighthouseSweep(raw_sweep_angles(plane, measurement.values), station << 1, first, sync)


class CarStateAssembler:
    """Car side: the suite's measurements of one 250 Hz step -> the ``CarState`` the firmware
    sends.

    :meth:`add` measurements (``imu``, ``wheel_encoders``, ``lighthouse/<s>/<p>``; others are
    ignored) as they come, then :meth:`encode_step` once per step. The IMU is sampled every step
    (the last reading is repeated if none arrived; zero motion with +g before the first);
    wheel speeds are sent only in a step that has a new reading. Sweeps queue (oldest dropped
    beyond 5, counted in ``sweeps_dropped``; one
    whose raw angle is beyond ±2π is counted in ``sweeps_unseen``) and go out as many as fit
    in 255 bytes.
    """

    def __init__(self, clock: SweepClock | None = None) -> None:
        self.clock = clock or SweepClock()
        self._imu = board_imu((0.0, 0.0, 0.0))
        self._wheels: WheelSpeeds | None = None
        self._sweeps: deque[LighthouseSweep] = deque()
        self.sweeps_dropped = 0
        self.sweeps_unseen = 0

    def add(self, measurement: Measurement) -> None:
        if measurement.sensor == "imu":
            self._imu = board_imu(measurement.values)
        elif measurement.sensor == "wheel_encoders":
            self._wheels = wire_wheel_speeds(measurement.values)
        elif parse_lighthouse(measurement.sensor) is not None:
            try:
                sweep = raw_sweep(measurement, self.clock)
            except FieldError:  # a raw angle beyond one turn: the deck cannot have seen it
                self.sweeps_unseen += 1
                return
            self._sweeps.append(sweep)
            while len(self._sweeps) > MAX_SWEEPS:
                self._sweeps.popleft()
                self.sweeps_dropped += 1

    def build(
        self,
        reference: ControlInput,
        steering: Steering,
        drive_power: float = 0.0,
        steer_power: float = 0.0,
        battery: Battery | None = None,
        longitudinal_velocity: float | None = None,
    ) -> CarState:
        """The step's ``CarState`` with every queued sweep (the queue is not consumed)."""
        return CarState(
            current_reference=reference,
            drive_power=drive_power,
            steer_power=steer_power,
            imu=self._imu,
            steering=steering,
            wheel_speeds=self._wheels,
            battery=battery,
            sweeps=tuple(self._sweeps),
            longitudinal_velocity=longitudinal_velocity,
        )

    def encode_step(self, timestamp_us: int | None, **telemetry: object) -> bytes:
        """Build (``telemetry``: the keyword arguments of :meth:`build`) and encode the step's
        datagram; sweeps that do not fit stay queued for the next step."""
        state = self.build(**telemetry)  # type: ignore[arg-type]
        data, left = encode_car_state_fitting(state, timestamp_us)
        self._sweeps = deque(left)
        self._wheels = None
        return data
