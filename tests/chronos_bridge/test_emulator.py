"""The car emulator: the clock-driven core (fast, no sockets)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from chronos_bridge.car_state import GRAVITY, PLANE_OFFSETS, CarStateConverter
from chronos_bridge.codec import (
    CAR_DATAGRAM_MAX,
    decode_from_car,
    encode_control_input,
    encode_ping_reply,
    encode_torque_command,
    encode_velocity_command,
)
from chronos_bridge.emulator import (
    DEFAULT_UNIX_OFFSET,
    TICK_S,
    BatteryModel,
    CarEmulator,
)
from chronos_bridge.packets import CarState, ControlInput, Ping
from chronos_bridge.proto import chronos_pb2 as pb
from crs_core.errors import FieldError
from sim.cutoff import DISCONNECT_THRESHOLD_S
from sim.sensors import SensorSuite
from tests.chronos_bridge.bridge_builders import HOST_STAMP_US as STAMP_US


def run(emulator: CarEmulator, steps: int, start: int = 0, command=None, every: int = 5):
    """Steps ``start .. start + steps - 1`` at ``now = k · 4 ms``; ``command(k)`` -> datagram
    sent before every ``every``-th step. Returns the decoded packets per step."""
    out = []
    for k in range(start, start + steps):
        now = k * TICK_S
        if command is not None and k % every == 0:
            assert emulator.receive(command(k), now)
        out.append([decode_from_car(d) for d in emulator.step(now)])
    return out


def states(packets) -> list[CarState]:
    return [p.contents for step in packets for p in step if isinstance(p.contents, CarState)]


def torque(steer: float, value: float):
    return lambda k: encode_torque_command(steer, value, STAMP_US)


def velocity(steer: float, value: float):
    return lambda k: encode_velocity_command(steer, value, STAMP_US)


def test_250_car_states_per_second_fit_decode_and_convert() -> None:
    emulator = CarEmulator(seed=1)
    converter = CarStateConverter()
    sizes, sensors = [], set()
    for k in range(250):
        datagrams = emulator.step(k * TICK_S)
        assert len(datagrams) == (2 if k == 0 else 1)  # + the discovery ping at boot
        sizes.append(len(datagrams[0]))
        packet = decode_from_car(datagrams[0])
        assert isinstance(packet.contents, CarState)
        assert packet.timestamp_us == round((DEFAULT_UNIX_OFFSET + k * TICK_S) * 1e6)
        out = converter.convert(packet, 0.0)
        sensors.update(m.sensor for m in out.measurements)
        assert [m.sensor for m in out.measurements[:2]] == ["imu", "wheel_encoders"]
        assert all(m.stamp == packet.stamp_s for m in out.measurements[:2])
        assert out.telemetry.battery_voltage == pytest.approx(8.05, abs=0.01)  # idle, 80 %
    assert emulator.steps == emulator.states_sent == 250
    assert emulator.sim_time == pytest.approx(1.0)
    assert max(sizes) <= CAR_DATAGRAM_MAX
    assert {"lighthouse/0/1", "lighthouse/0/2"} <= sensors
    assert emulator.paused and emulator.drive_power == 0.0  # no reference yet
    unstamped = CarEmulator(seed=1, timestamps=False)
    assert decode_from_car(unstamped.step(0.0)[0]).timestamp_us is None


def test_imu_is_in_board_axes_and_is_the_truth_model_output() -> None:
    emulator = CarEmulator(seed=2, sensors=SensorSuite().ideal())
    model = emulator.model
    p = model.parameters.vector()
    emulator.receive(encode_torque_command(0.3, 0.6, STAMP_US), 0.0)
    for k in range(150):
        x = emulator.truth()  # the state at the tick, where the IMU samples
        if k % 5 == 0:
            emulator.receive(encode_torque_command(0.3, 0.6, STAMP_US), k * TICK_S)
        state = decode_from_car(emulator.step(k * TICK_S)[0]).contents
        u = emulator.session.applied_command  # set by the tick, held until the next
        ax, ay, omega = model.numeric.outputs(model.initial_state(x), u, p)["imu"]
        acc, gyro = state.imu.linear_acceleration, state.imu.angular_velocity
        np.testing.assert_allclose(acc, [-ax, -ay, GRAVITY], rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(gyro, [0.0, 0.0, omega], rtol=1e-6, atol=1e-6)
    assert abs(omega) > 0.5 and abs(ay) > 0.5  # really turning: the flip is visible


def _sweeps(emulator: CarEmulator, steps: int):
    """Sweeps the simulator made, sweeps the car sent (polynomial, raw angles), and the
    host's Lighthouse measurements from them, over ``steps`` steps of gentle driving."""
    converter = CarStateConverter()
    sent, received, raw = [], [], []
    for k in range(steps):
        if k % 5 == 0:
            emulator.receive(encode_torque_command(0.1, 0.3, STAMP_US), k * TICK_S)
        packet = decode_from_car(emulator.step(k * TICK_S)[0])
        sent += [m for m in emulator.last_measurements if m.sensor.startswith("lighthouse")]
        raw += [(s.polynomial, s.angles) for s in packet.contents.sweeps]
        received += [
            m for m in converter.convert(packet, 0.0).measurements if "lighthouse" in m.sensor
        ]
    return sent, raw, received


def test_lighthouse_sweeps_are_raw_and_host_offsets_give_back_the_model_convention() -> None:
    sent, raw, received = _sweeps(CarEmulator(seed=3, sensors=SensorSuite().ideal()), 500)
    assert len(sent) == 200 and len(received) == len(sent) == len(raw)  # 2 planes x 50 Hz
    for a, b in zip(sent, received, strict=True):
        assert a.sensor == b.sensor
        np.testing.assert_allclose(b.values, a.values, rtol=1e-6, atol=2e-6)
    # on the wire: the raw convention, i.e. the model's angle minus the plane's offset
    for m, (polynomial, angles) in zip(sent, raw, strict=True):
        assert polynomial == 0
        plane = int(m.sensor[-1])
        np.testing.assert_allclose(angles, m.values - PLANE_OFFSETS[plane], atol=2e-6)
        assert all(abs(a) > 1.5 for a in angles)  # not the model convention
    # default sensors (5 % of the sweeps lost, jitter): a lone plane 2 does not pair, as on a car
    sent, _, received = _sweeps(CarEmulator(seed=3), 500)
    assert 0.85 * len(sent) <= len(received) <= len(sent)


def test_the_host_stamps_each_sweep_at_its_measurement_time() -> None:
    """A packet carries the sweeps measured up to its stamp, as the firmware's does: the host's
    deck clock (which takes the smallest packet-minus-deck-time offset as no latency) then
    stamps every sweep when it was measured. Carrying a sweep measured later in the tick with
    a packet stamped at the tick's start stamped every sweep up to a tick early, 4 ms, which
    the IMU and wheel speeds (stamped right) contradicted by a car's 4 ms of motion."""
    emulator = CarEmulator(seed=3, sensors=SensorSuite().ideal())
    sent, _, received = _sweeps(emulator, 500)
    measured = {(m.sensor, round(m.stamp + emulator.unix_offset, 4)) for m in sent}
    assert {m.sensor for m in sent} == {"lighthouse/0/1", "lighthouse/0/2"}
    assert len(received) >= len(sent) - 2  # the last tick's sweeps wait for the next packet
    assert {(m.sensor, round(m.stamp, 4)) for m in received} <= measured


def test_discovery_ping_every_5_s_and_host_pings() -> None:
    emulator = CarEmulator(seed=4)
    pings = []
    for k in range(2 * 1250 + 10):
        for data in emulator.step(k * TICK_S):
            packet = decode_from_car(data)
            if isinstance(packet.contents, Ping):
                assert packet.contents.should_bounce
                pings.append(k * TICK_S)
    assert pings == pytest.approx([0.0, 5.0, 10.0]) and emulator.pings_sent == 3
    now = emulator.steps * TICK_S
    assert emulator.receive(encode_ping_reply(STAMP_US), now)
    assert emulator.ping_replies == 1
    bounce = pb.Packet()
    bounce.ping.should_bounce = True
    assert emulator.receive(bounce.SerializeToString(), now)
    answer = [decode_from_car(d).contents for d in emulator.step(now)]
    assert answer[1] == Ping(False)
    assert emulator.paused  # pings are no references


def test_a_torque_command_moves_the_car() -> None:
    emulator = CarEmulator(seed=5)
    start = emulator.truth()
    sent = states(run(emulator, 250, command=torque(0.0, 0.5)))
    end = emulator.truth()
    assert not emulator.paused and emulator.commands == 50
    assert end[3] > 0.8 and np.hypot(*(end[:2] - start[:2])) > 0.4
    last = sent[-1]
    assert last.drive_power == pytest.approx(0.5)
    assert last.current_reference.torque_ref == pytest.approx(0.5)
    assert last.longitudinal_velocity == pytest.approx(end[3], abs=0.1)  # noisy wheel speeds
    assert sent[-1].battery.voltage < 8.05 - 0.1  # the battery sags (8.05 V idle)
    assert sent[-1].battery.current == pytest.approx(-(0.25 + 3.0 * 0.5), abs=0.1)


def test_velocity_reference_is_tracked_by_the_onboard_pid() -> None:
    emulator = CarEmulator(seed=6)
    vx = []
    for k in range(375):
        run(emulator, 1, start=k, command=velocity(0.0, 1.0))
        if k * TICK_S >= 1.0:
            vx.append(emulator.truth()[3])
    assert emulator.reference == ("velocity", 0.0, 1.0)
    np.testing.assert_allclose(vx, 1.0, rtol=0.03)
    assert 0.0 < emulator.drive_power < 1.0


def test_motors_cut_200_ms_after_the_last_command_and_driving_resumes() -> None:
    emulator = CarEmulator(seed=7)
    run(emulator, 125, command=torque(0.1, 0.4))  # commands every 20 ms for 0.5 s
    last_command = 120 * TICK_S
    assert not emulator.paused and emulator.drive_power == pytest.approx(0.4)
    cut = None
    for k in range(125, 200):
        state = decode_from_car(emulator.step(k * TICK_S)[0]).contents
        if cut is None and emulator.paused:
            cut = k * TICK_S
            assert state.drive_power == 0.0 and emulator.drive_power == 0.0
        if cut is None:
            assert state.drive_power == pytest.approx(0.4)
    assert cut is not None
    assert DISCONNECT_THRESHOLD_S - 1e-9 <= cut - last_command <= DISCONNECT_THRESHOLD_S + TICK_S
    assert emulator.pauses == 1 and emulator.reference[2] == 0.0
    assert emulator.reference[1] == pytest.approx(0.1)  # the steering reference is held
    coasting = emulator.truth()[3]
    run(emulator, 100, start=200)
    assert emulator.truth()[3] < coasting  # no drive: the car slows down
    slow = emulator.truth()[3]
    sent = states(run(emulator, 125, start=300, command=velocity(0.0, 1.2)))
    assert not emulator.paused and emulator.pauses == 1
    assert sent[-1].drive_power > 0.0 and emulator.truth()[3] > slow + 0.3


def test_malformed_datagrams_are_counted_never_raise_and_change_nothing() -> None:
    emulator = CarEmulator(seed=8)
    assert emulator.receive(encode_torque_command(0.2, 0.3, STAMP_US), 0.0)
    before = emulator.reference
    rng = np.random.default_rng(0)
    garbage = [rng.bytes(int(n)) for n in rng.integers(0, 120, 300)]
    nan = pb.Packet()
    nan.reference.throttle = math.nan
    nan.reference.angle = 0.1
    big = pb.Packet()
    big.reference.throttle = 0.5
    big.timestamp = STAMP_US
    oversize = big.SerializeToString() + bytes(300)  # valid start, 300 bytes of padding
    low_voltage = pb.Packet()
    low_voltage.reference.throttle = 0.5
    low_voltage.reference.voltage = 100  # 0.1 V: outside the potentiometer's calibration
    bad = [
        *garbage,
        nan.SerializeToString(),
        oversize,
        low_voltage.SerializeToString(),
        b"",
        "not bytes",  # type: ignore[list-item]
    ]
    accepted = sum(emulator.receive(d, 0.001) for d in bad)
    rejected = emulator.rejected
    assert accepted + emulator.rejected_total == len(bad)
    assert accepted <= 5  # a few random strings are valid pings by chance
    assert emulator.reference == before
    assert rejected["reference.throttle"] == 1  # NaN
    assert rejected["reference.voltage"] == 1  # outside the calibration
    assert rejected["datagram"] >= 2  # oversize, not bytes, undecodable
    emulator.step(0.004)
    assert emulator.session.onboard.reference.tolist() == pytest.approx([0.2, 0.3])


def test_voltage_and_older_control_input_references() -> None:
    emulator = CarEmulator(seed=9)
    calibration = emulator.onboard_settings.steering.potentiometer
    reference = pb.Packet()
    reference.reference.throttle = 0.2
    reference.reference.voltage = 2020  # mV
    assert emulator.receive(reference.SerializeToString(), 0.0)
    assert emulator.reference[1] == pytest.approx(calibration.angle(2.02))
    no_steering = pb.Packet()
    no_steering.reference.longitudinal_velocity = 0.5
    assert emulator.receive(no_steering.SerializeToString(), 0.0)
    assert emulator.reference == ("velocity", pytest.approx(calibration.angle(2.02)), 0.5)
    assert emulator.receive(encode_control_input(ControlInput(0.3, -0.1), STAMP_US), 0.0)
    assert emulator.reference == ("torque", pytest.approx(-0.1), pytest.approx(0.3))
    older = ControlInput(0.3, -0.1, steer_angle=0.2)
    assert emulator.receive(encode_control_input(older, STAMP_US), 0.0)
    assert emulator.reference[1] == pytest.approx(0.2)
    assert emulator.commands == 4 and emulator.rejected_total == 0
    with pytest.raises(FieldError, match="capacity_ah") as error:
        BatteryModel(capacity_ah=0.0)
    assert error.value.field == "capacity_ah"
    with pytest.raises(FieldError) as error:
        BatteryModel(idle_current=-1.0)
    assert str(error.value) == "idle_current: must be a finite number >= 0, got -1.0"
