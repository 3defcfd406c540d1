r"""A Chronos car emulator that behaves like the firmware, transport-free and clock-driven.

:class:`CarEmulator` is the car's side of the Wi-Fi link (``shared/specs/chronos-wifi-protocol.md``)
on top of the simulator (:class:`sim.simulator.Simulator` with the onboard 250 Hz loop,
:mod:`sim.onboard`). It owns no socket and never sleeps: the caller hands it the datagrams it
received (:meth:`CarEmulator.receive`) and calls :meth:`CarEmulator.step` once per 4 ms firmware
tick, sending the datagrams it returns. :mod:`chronos_bridge.emulator_process` is the process
around it (UDP, real-time pacing).

What it does like the firmware:

- **250 Hz** ``CarState``, one per step, at most 255 bytes (Lighthouse sweeps that do not fit wait
  for the next step): IMU in the **board's** axes (x, y opposite to the body frame, z up with
  +g), wheel speeds in the wire order, Lighthouse sweeps with the firmware's **raw** angles (the
  host adds the plane offsets) and 24-bit deck timestamps the host pairs, the steering angle
  as the firmware estimates it from the potentiometer (and the ADC reading), the motor powers,
  the reference it executes, the battery, and its own v_x from the rear wheel speeds.
- **Discovery** ``Ping{should_bounce=true}`` every 5 s (the first with the first step); a host
  ``Ping{should_bounce=true}`` is answered with ``should_bounce=false`` in the next step.
- **References**: ``CarReference`` with ``throttle`` (torque mode) or ``longitudinal_velocity``
  (the onboard velocity PID tracks it) and a steering ``angle`` or potentiometer ``voltage``
  (mV; mapped to an angle through the firmware's potentiometer calibration, rejected outside
  its calibrated voltage range; no steering field keeps the current steering reference); the
  older ``SingleControlInput`` (torque mode; steering from ``steer_input`` when present, else
  ``steer_ref``). Malformed datagrams are counted by reason (:attr:`CarEmulator.rejected`) and
  change nothing; :meth:`~CarEmulator.receive` never raises.
- **Timeout**: the firmware's watchdog (:class:`sim.cutoff.MotorCutoff`): when no valid
  reference arrived for 200 ms the car cuts the drive motor (torque 0; the steering keeps its
  last reference, as if the linkage stood still) and pauses (:attr:`~CarEmulator.paused`) until
  the next valid reference. It starts paused (no reference yet).
- **Timestamps**: ``Packet.timestamp`` = ``unix_offset + now`` in µs, as an SNTP-synchronised
  car stamps; ``timestamps=False`` leaves it out (the host then stamps on receipt).

Clocks: ``now`` (s) is the emulator's clock (any origin, never decreasing; the process passes
``time.monotonic()``). Simulation time advances exactly one tick per :meth:`~CarEmulator.step`
(``k · 4 ms`` after the first step); the timeout, the pings and the stamps follow ``now``.

Battery (:class:`BatteryModel`): a 2S LiPo, 7.4 V nominal, as a linear open-circuit voltage
in the state of charge plus an internal resistance. The current is the electronics' idle draw plus
each motor's current, proportional to its |power| (see the class for the figures), so the
voltage sags under drive power and slowly falls as the charge is used.
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from dataclasses import dataclass

import numpy as np

from chronos_bridge.car_state import CarStateAssembler
from chronos_bridge.codec import DecodeError, decode_from_host, encode_discovery_ping, encode_packet
from chronos_bridge.packets import (
    CAR_VELOCITY_LIMIT,
    CURRENT_TORQUE_REF_LIMIT,
    Battery,
    ControlInput,
    FieldError,
    Packet,
    Ping,
    Reference,
    Steering,
)
from crs_core.control.low_level import rear_axle_speed
from crs_core.measurements import Measurement
from crs_core.model import CarModel
from crs_core.settings import Settings, non_negative
from sim.cutoff import MotorCutoff
from sim.drift import DriftSchedule
from sim.onboard import OnboardSettings
from sim.sensors import SensorSuite
from sim.simulator import SimulationSession, Simulator

#: Firmware loop period, s (250 Hz).
TICK_S = 0.004
#: Period of the discovery ping, s.
PING_PERIOD_S = 5.0
#: Unix time (s) of the emulator clock's zero unless given: 2025-06-15T16:53:20Z (reproducible
#: stamps in tests; the process passes the wall clock's offset).
DEFAULT_UNIX_OFFSET = 1_750_006_400.0

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BatteryModel(Settings):
    """A 2S LiPo with internal resistance: ``V = V_oc(soc) - R · I``.

    ``V_oc = empty_voltage + (full_voltage - empty_voltage) · soc`` (linear, 6.8 V .. 8.4 V,
    i.e. 7.6 V at half charge), ``I = idle_current + drive_current · |drive power| +
    steer_current · |steer power|`` (A), and ``soc`` falls by ``I · dt / capacity``. Defaults:
    a 300 mAh pack at 80 % charge, 0.1 Ω, 0.25 A for the ESP32 and the Lighthouse deck, 3 A
    for the drive motor at full power, 0.5 A for the steering motor: 8.05 V idle, about 7.7 V
    at full throttle, dropping by about 0.07 V per minute at full throttle.
    """

    full_voltage: float = non_negative(8.4)
    empty_voltage: float = non_negative(6.8)
    capacity_ah: float = non_negative(0.3)
    initial_charge: float = non_negative(0.8)
    internal_resistance: float = non_negative(0.1)
    idle_current: float = non_negative(0.25)
    drive_current: float = non_negative(3.0)
    steer_current: float = non_negative(0.5)

    def _check_relations(self) -> None:
        if not self.empty_voltage < self.full_voltage:
            raise FieldError("empty_voltage", "must be < full_voltage")
        if self.capacity_ah <= 0:
            raise FieldError("capacity_ah", f"must be > 0, got {self.capacity_ah!r}")
        if self.initial_charge > 1:
            raise FieldError("initial_charge", f"must be <= 1, got {self.initial_charge!r}")


class _Battery:
    def __init__(self, model: BatteryModel) -> None:
        self.model = model
        self.charge = model.initial_charge

    def step(self, dt: float, drive_power: float, steer_power: float) -> Battery:
        m = self.model
        current = m.idle_current + m.drive_current * abs(drive_power)
        current += m.steer_current * abs(steer_power)
        self.charge = max(self.charge - current * dt / 3600.0 / m.capacity_ah, 0.0)
        open_circuit = m.empty_voltage + (m.full_voltage - m.empty_voltage) * self.charge
        voltage = max(open_circuit - m.internal_resistance * current, 0.0)
        return Battery(voltage, -current)


def _clip(value: float, limit: float) -> float:
    return min(max(float(value), -limit), limit)


class CarEmulator:
    """One emulated Chronos car (see the module docstring for what it does).

    Parameters
    ----------
    seed : int
        Seed of every random draw of the simulation (sensor noise, drop-outs).
    x0 : array (6,), optional
        Initial base state ``[x, y, yaw, v_x, v_y, omega]``; default: at rest at DEMO_TRACK's start.
    model : CarModel, optional
        Truth model; default the Chronos model (:class:`~crs_core.model.CarModel`).
    sensors : SensorSuite, optional
        Sensor rates and imperfections; default :class:`~sim.sensors.SensorSuite` (IMU and wheel
        encoders must be at 250 Hz to give one reading per state).
    onboard : OnboardSettings, optional
        The firmware's loop (PIDs, steering actuator, potentiometer); default settings.
    battery : BatteryModel, optional
        The battery (:class:`BatteryModel` defaults).
    unix_offset : float
        Unix time (s) at ``now = 0`` of the emulator's clock, for ``Packet.timestamp``.
    timestamps : bool
        Stamp the car's packets (True, a synchronised car) or leave the stamp out.
    drift : DriftSchedule, optional
        Changes of the car's truth while it races (:mod:`sim.drift`).

    Counters: ``steps``, ``states_sent``, ``pings_sent``, ``ping_replies`` (the host's
    answers), ``commands`` (valid references applied), ``rejected`` (a ``Counter`` by reason:
    the decoder's field, e.g. ``datagram`` or ``reference.throttle``, or ``reference.voltage``
    outside the calibration), ``pauses`` (times the timeout cut the motors).
    """

    def __init__(
        self,
        seed: int = 0,
        x0: np.ndarray | None = None,
        model: CarModel | None = None,
        sensors: SensorSuite | None = None,
        onboard: OnboardSettings | None = None,
        battery: BatteryModel | None = None,
        unix_offset: float = DEFAULT_UNIX_OFFSET,
        timestamps: bool = True,
        drift: DriftSchedule | None = None,
    ) -> None:
        if x0 is None:
            from crs_core.track import load_demo_track

            track = load_demo_track()
            x0 = track.start_state()
        self.model = model or CarModel()
        sensors = sensors or SensorSuite()
        for name in ("imu", "wheel_encoders"):
            rate = sensors.spec(name).rate_hz
            if abs(rate * TICK_S - 1.0) > 1e-9:
                raise FieldError(
                    f"sensors.{name}.rate_hz", f"must be 250 (one per step), got {rate}"
                )
        self.onboard_settings = onboard or OnboardSettings()
        if abs(self.onboard_settings.rate_hz * TICK_S - 1.0) > 1e-9:
            raise FieldError("onboard.rate_hz", f"must be 250, got {self.onboard_settings.rate_hz}")
        if not math.isfinite(unix_offset):
            raise FieldError("unix_offset", f"must be finite, got {unix_offset!r}")
        self.simulator = Simulator(
            self.model, sensors, seed, onboard=self.onboard_settings, drift=drift
        )
        self.session: SimulationSession = self.simulator.session(
            np.asarray(x0, dtype=float), keep_history=False
        )
        self.unix_offset = float(unix_offset)
        self.timestamps = bool(timestamps)
        self._battery = _Battery(battery or BatteryModel())
        self._assembler = CarStateAssembler()
        self._pot = self.onboard_settings.potentiometer
        calibration = self.onboard_settings.steering.potentiometer
        self._voltage_range = (min(calibration.voltages), max(calibration.voltages))
        self._steer_ref = 0.0
        self._throttle_ref = 0.0  # torque (torque mode) or v_x (velocity mode)
        self._mode = "torque"
        self._next_ping: float | None = None
        self._reply_pending = False
        self._now: float | None = None
        self._wheels = np.zeros(4)
        self._cutoff = MotorCutoff()
        self.last_measurements: tuple[Measurement, ...] = ()
        self._later: list[Measurement] = []  # measured after this tick's stamp: the next packet
        self.last_battery: Battery | None = None
        self.steps = 0
        self.states_sent = 0
        self.pings_sent = 0
        self.ping_replies = 0
        self.commands = 0
        self.encode_failures = 0
        self.rejected: Counter[str] = Counter()

    # ----------------------------------------------------------------------------- queries

    def truth(self) -> np.ndarray:
        """True base state ``[x, y, yaw, v_x, v_y, omega]`` now (ground truth, for tests)."""
        return self.session.base_state

    @property
    def sim_time(self) -> float:
        """Simulation time, s (``steps · 4 ms``)."""
        return self.session.time

    @property
    def reference(self) -> tuple[str, float, float]:
        """The reference executed: ``(mode, steer (rad), torque (-) or v_x (m/s))``."""
        return self._mode, self._steer_ref, self._throttle_ref

    @property
    def paused(self) -> bool:
        """The motors are cut: no valid reference yet, or none for 200 ms."""
        return self._cutoff.cut

    @property
    def pauses(self) -> int:
        """Times the timeout cut the motors."""
        return self._cutoff.cuts

    @property
    def drive_power(self) -> float:
        """The drive motor's power now, in [-1, 1] (0 while paused)."""
        return _clip(self.session.applied_command[1], 1.0)

    @property
    def rejected_total(self) -> int:
        return sum(self.rejected.values())

    # ----------------------------------------------------------------------------- input

    def receive(self, datagram: bytes, now: float) -> bool:
        """Handle one datagram from the host at clock ``now`` (s); True if it was valid.

        Never raises on bad input: a malformed datagram is counted in :attr:`rejected` by
        reason and changes nothing.
        """
        self._clock(now)
        try:
            packet = decode_from_host(datagram)
            contents = packet.contents
            if isinstance(contents, Ping):
                if contents.should_bounce:
                    self._reply_pending = True
                else:
                    self.ping_replies += 1
                return True
            mode, steer, value = self._command(contents)
        except FieldError as error:  # DecodeError, or our own check naming the field
            self.rejected[error.field] += 1
            return False
        except Exception:  # never let a datagram take the car down
            _log.exception("unexpected error decoding a host datagram")
            self.rejected["internal"] += 1
            return False
        self._apply(mode, steer, value)
        self._cutoff.commanded(now)
        self.commands += 1
        return True

    def _command(self, contents: object) -> tuple[str, float, float]:
        if isinstance(contents, Reference):
            steer = self._steer(
                self._steer_ref, contents.angle, contents.voltage, "reference.voltage"
            )
            if contents.throttle is not None:
                return "torque", steer, contents.throttle
            return "velocity", steer, contents.longitudinal_velocity  # type: ignore[return-value]
        if isinstance(contents, ControlInput):
            steer = self._steer(
                contents.steer_ref,
                contents.steer_angle,
                contents.steer_voltage,
                "control_input.steer_voltage",
            )
            return "torque", steer, contents.torque_ref
        raise DecodeError("contents", f"{type(contents).__name__} is not a command")

    def _steer(
        self, otherwise: float, angle: float | None, millivolts: int | None, field: str
    ) -> float:
        """The steering reference of a command: its ``angle`` (rad) if it has one, else the angle
        of its potentiometer voltage (mV, ``field`` names it), else ``otherwise``."""
        if angle is not None:
            return angle
        if millivolts is not None:
            return self._voltage_angle(field, millivolts)
        return otherwise

    def _voltage_angle(self, field: str, millivolts: int) -> float:
        volts = millivolts * 1e-3
        low, high = self._voltage_range
        if not low <= volts <= high:
            raise FieldError(field, f"{millivolts} mV outside the calibration {low:g}..{high:g} V")
        return float(self.onboard_settings.steering.potentiometer.angle(volts))

    def _apply(self, mode: str, steer: float, value: float) -> None:
        self._mode, self._steer_ref, self._throttle_ref = mode, float(steer), float(value)
        self.session.command(np.array([self._steer_ref, self._throttle_ref]), mode)

    def _clock(self, now: float) -> None:
        if not math.isfinite(now):
            raise FieldError("now", f"must be finite, got {now!r}")
        if self._now is not None and now < self._now:
            raise FieldError("now", f"the clock went back ({now} < {self._now})")
        self._now = now

    # ----------------------------------------------------------------------------- output

    def step(self, now: float) -> list[bytes]:
        """One 4 ms firmware tick at clock ``now`` (s): the datagrams to send to the host.

        Cuts the motors if no valid reference arrived for 200 ms, advances the simulation by one
        tick (the onboard loop, the sensors sampled during it; the packet carries those measured
        up to its stamp, the rest go with the next), and returns the step's
        ``CarState`` (<= 255 bytes), followed by the discovery ping when it is due and the
        answer to a host ping if one came.
        """
        self._clock(now)
        if self._cutoff.expired(now):
            self._apply("torque", self._steer_ref, 0.0)
        t_tick = self.steps * TICK_S  # the simulation time this tick's packet is stamped at
        measurements = self.session.advance((self.steps + 1) * TICK_S)
        self.steps += 1
        self.last_measurements = tuple(measurements)
        # a packet carries what was measured up to its stamp, as the firmware's does (the host
        # stamps a sweep from its deck ticks assuming it was measured before its packet): a
        # sweep of the tick's later part goes out with the next packet
        waiting, self._later = [*self._later, *measurements], []
        for measurement in waiting:
            if measurement.stamp > t_tick + 1e-9:
                self._later.append(measurement)
                continue
            if measurement.sensor == "wheel_encoders":
                self._wheels = measurement.values
            self._assembler.add(measurement)
        stamp = round((self.unix_offset + now) * 1e6) if self.timestamps else None
        out = []
        state = self._state_datagram(stamp)
        if state is not None:
            out.append(state)
            self.states_sent += 1
        if self._next_ping is None or now >= self._next_ping - 1e-9:
            out.append(encode_discovery_ping(stamp))
            self.pings_sent += 1
            previous = self._next_ping
            due = (previous if previous is not None else now) + PING_PERIOD_S
            self._next_ping = due if due > now else now + PING_PERIOD_S
        if self._reply_pending:
            self._reply_pending = False
            out.append(encode_packet(Packet(Ping(False), stamp)))
        return out

    def _state_datagram(self, stamp: int | None) -> bytes | None:
        loop = self.session.onboard
        assert loop is not None
        drive = _clip(self.session.applied_command[1], 1.0)
        steer_power = _clip(loop.motor_command, 1.0)
        try:
            self.last_battery = self._battery.step(TICK_S, drive, steer_power)
            velocity = rear_axle_speed(self._wheels, self.onboard_settings.velocity.wheel_radius)
            return self._assembler.encode_step(
                stamp,
                reference=ControlInput(
                    self._throttle_ref,
                    self._steer_ref,
                    torque_limit=CURRENT_TORQUE_REF_LIMIT,
                ),
                steering=self._steering(loop.steering.angle),
                drive_power=drive,
                steer_power=steer_power,
                battery=self.last_battery,
                longitudinal_velocity=_clip(velocity, CAR_VELOCITY_LIMIT),
            )
        except (FieldError, ValueError):  # a diverged simulation must not stop the loop
            self.encode_failures += 1
            if self.encode_failures == 1:
                _log.exception("car state not encodable; skipped")
            return None

    def _steering(self, angle: float) -> Steering:
        """The firmware's ``SteeringPositionMeasurement``: its angle estimate (rad) from the
        potentiometer, the ADC counts of that reading, and the counts of the calibration's ends
        as ``adc_limits``."""
        lsb = self._pot.adc_reference / (2 ** (self._pot.adc_bits or 12) - 1)
        calibration = self.onboard_settings.steering.potentiometer

        def counts(volts: float) -> int:
            return min(max(round(volts / lsb), 0), 0xFFFF)

        low, high = (counts(v) for v in self._voltage_range)
        adc = counts(float(calibration.voltage(angle)))
        return Steering(_clip(angle, 1.0), adc, (low & 0xFFFF) | (high << 16))
