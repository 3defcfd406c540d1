"""CarStateConverter (host) and the car-side mapping (emulator), incl. the sim round trip."""

from __future__ import annotations

import math

import numpy as np
import pytest
from bridge_builders import STAMP_US, make_state

from chronos_bridge.car_state import (
    DECK_TICK_HZ,
    PLANE_OFFSETS,
    CarStateAssembler,
    CarStateConverter,
    SweepClock,
    board_imu,
    raw_sweep_angles,
    steering_from_angle,
    tick_difference,
    wire_wheel_speeds,
)
from chronos_bridge.codec import decode_from_car, encode_car_state
from chronos_bridge.packets import ControlInput, LighthouseSweep, Packet
from crs_core.measurements import Measurement

RECEIPT = 1_800_000_000.5


def convert(converter: CarStateConverter, sweeps=(), stamp_us: int | None = STAMP_US, **kw):
    packet = decode_from_car(encode_car_state(make_state(sweeps=tuple(sweeps), **kw), stamp_us))
    return converter.convert(packet, RECEIPT)


def lighthouse(out) -> list[tuple[str, float]]:
    return [(m.sensor, m.stamp) for m in out.measurements if m.sensor.startswith("lighthouse")]


def sweep(angle0: float, sync: int, station: int = 0) -> LighthouseSweep:
    return LighthouseSweep((angle0, angle0, angle0, angle0), station << 1, sync, sync)


FIRST = 2.0  # raw angle of plane 1: corrected 2 - 2π/3 ≈ -0.09 (in view)
SECOND = 4.0  # raw angle of plane 2: corrected 4 - 4π/3 ≈ -0.19


def test_imu_flip_wheel_order_stamps_and_telemetry() -> None:
    converter = CarStateConverter()
    out = convert(converter)
    imu, wheels = out.measurements[:2]
    assert imu.sensor == "imu" and imu.stamp == pytest.approx(STAMP_US * 1e-6)
    np.testing.assert_allclose(imu.values, [1.5, -0.5, 1.5])  # -ax, -ay, +gyro z
    assert wheels.sensor == "wheel_encoders"
    np.testing.assert_allclose(wheels.values, [11.0, 10.0, 13.0, 12.0])  # fl fr rl rr
    t = out.telemetry
    assert (t.battery_voltage, t.battery_current) == (7.5, -1.25)
    assert t.steer_angle == 0.125 and t.steer_adc == 2100 and t.steer_adc_range == (300, 3800)
    assert t.longitudinal_velocity == 1.75 and t.drive_power == 0.5 and t.steer_power == -0.25
    assert t.reference.torque_ref == 0.25
    no_stamp = convert(converter, stamp_us=None, wheel_speeds=None)
    assert [m.stamp for m in no_stamp.measurements] == [RECEIPT]  # receipt time, no wheels
    gyro = convert(CarStateConverter(imu_sensor="gyro")).measurements[0]
    assert gyro.sensor == "gyro" and gyro.values.tolist() == [1.5]


def test_pairing_first_then_second_plane_releases_both() -> None:
    converter = CarStateConverter()
    assert lighthouse(convert(converter, [sweep(FIRST, 1000)])) == []  # held: plane unknown
    out = convert(converter, [sweep(SECOND, 1050)], stamp_us=STAMP_US + 4000)
    assert lighthouse(out) == [
        ("lighthouse/0/1", STAMP_US * 1e-6),  # the held one, with its own stamp
        # measured 50 deck ticks after the first (the deck clock), not at its packet's stamp
        ("lighthouse/0/2", pytest.approx(STAMP_US * 1e-6 + 50 / DECK_TICK_HZ, abs=1e-7)),
    ]
    plane1, plane2 = (m for m in out.measurements if m.sensor.startswith("lighthouse"))
    np.testing.assert_allclose(plane1.values, FIRST + PLANE_OFFSETS[1], rtol=1e-6)
    np.testing.assert_allclose(plane2.values, SECOND + PLANE_OFFSETS[2], rtol=1e-6)
    assert PLANE_OFFSETS == {1: -math.pi + math.pi / 3, 2: -math.pi - math.pi / 3}
    # the next period: a new first plane (angle close to the held one) is published at once
    out = convert(converter, [sweep(FIRST + 0.05, 481_000), sweep(SECOND, 480_950)])
    assert [s for s, _ in lighthouse(out)] == ["lighthouse/0/1", "lighthouse/0/2"]


def test_pairing_window_is_100_ticks_and_wraps_at_24_bits() -> None:
    assert tick_difference(5, (1 << 24) - 20) == 25
    assert tick_difference((1 << 24) - 20, 5) == -25
    converter = CarStateConverter()
    convert(converter, [sweep(FIRST, (1 << 24) - 30)])
    out = convert(converter, [sweep(SECOND, 70)])  # +100 across the wrap: paired
    assert [s for s, _ in lighthouse(out)] == ["lighthouse/0/1", "lighthouse/0/2"]
    converter = CarStateConverter()
    convert(converter, [sweep(FIRST, 1000)])
    out = convert(converter, [sweep(SECOND, 1101)])  # 101 ticks: the pair is broken
    assert lighthouse(out) == [] and converter.sweeps_held == 2


def test_broken_pair_holds_and_recovers_and_stations_are_separate() -> None:
    converter = CarStateConverter()
    convert(converter, [sweep(FIRST, 1000, station=1)])
    out = convert(converter, [sweep(SECOND, 900_000, station=1)])  # lone plane 2: held
    assert lighthouse(out) == []
    out = convert(converter, [sweep(FIRST, 1_400_000, station=1)])  # far from the held plane 2
    assert lighthouse(out) == []
    out = convert(converter, [sweep(FIRST, 5000, station=0), sweep(SECOND, 1_400_040, station=1)])
    assert [s for s, _ in lighthouse(out)] == ["lighthouse/1/1", "lighthouse/1/2"]


def test_out_of_view_sweeps_are_dropped() -> None:
    converter = CarStateConverter()
    far = 2.0 * math.pi / 3 + 1.6  # corrected angle_0 = 1.6 > 1.5
    convert(converter, [sweep(far, 1000)])
    out = convert(converter, [sweep(SECOND, 1000)])
    assert [s for s, _ in lighthouse(out)] == ["lighthouse/0/2"]
    assert converter.sweeps_out_of_view == 1


def test_car_side_mapping_is_the_inverse() -> None:
    imu = board_imu((1.0, -2.0, 0.5))
    assert imu.linear_acceleration == (-1.0, 2.0, 9.80665)
    assert imu.angular_velocity == (-0.0, -0.0, 0.5)
    assert board_imu((0.0, 0.0, 10.0)).angular_velocity[2] == pytest.approx(math.radians(250))
    w = wire_wheel_speeds((1.0, 2.0, 3.0, 4.0))
    assert (w.front_right, w.front_left, w.rear_right, w.rear_left) == (2.0, 1.0, 4.0, 3.0)
    assert raw_sweep_angles(1, [0.0] * 4)[0] == pytest.approx(math.pi - math.pi / 3)
    assert raw_sweep_angles(2, [0.0] * 4)[0] == pytest.approx(math.pi + math.pi / 3)
    clock = SweepClock()
    first, sync1 = clock.timestamps(3, 1, 10.0)
    first2, sync2 = clock.timestamps(3, 2, 10.01)
    assert first == sync1 == sync2 and first2 != first
    assert clock.timestamps(3, 2, 10.5)[1] != sync1  # no recent plane 1: not paired


def test_sim_round_trip_gives_back_the_same_measurements() -> None:
    """Simulator -> emulator (car side) -> bytes -> decode -> converter: same values (float32),
    IMU and wheels at their stamps, each sweep at its measurement time (the deck clock), not
    at the stamp of the 4 ms step that carried it."""
    from crs_core.model.car_model import CarModel
    from sim.sensors import SensorSuite
    from sim.simulator import Simulator

    simulator = Simulator(CarModel(), SensorSuite().ideal(), seed=3)
    result = simulator.run(
        lambda t, x: np.array([0.2, 0.3]), 1.0, np.array([0.0, 0.0, 0, 0.5, 0, 0])
    )
    epoch = 1_750_000_000.0
    sent = [m for m in result.measurements if m.sensor != "pose"]
    assembler = CarStateAssembler()
    converter = CarStateConverter()
    received: list[Measurement] = []
    step = 0.004
    pending = sorted(sent, key=lambda m: m.stamp)
    k = 0
    for n in range(int(1.0 / step) + 1):
        t = n * step
        while k < len(pending) and pending[k].stamp <= t + 1e-9:
            assembler.add(pending[k])
            k += 1
        data = assembler.encode_step(
            round((epoch + t) * 1e6),
            reference=ControlInput(0.3, 0.2),
            steering=steering_from_angle(0.2),
        )
        received += converter.convert(decode_from_car(data), 0.0).measurements
    imu_sent = [m for m in sent if m.sensor == "imu"]
    imu_got = [m for m in received if m.sensor == "imu"]
    assert len(imu_got) >= len(imu_sent)
    got_by_stamp = {round(m.stamp - epoch, 4): m for m in imu_got}
    for m in imu_sent:
        np.testing.assert_allclose(
            got_by_stamp[round(m.stamp, 4)].values, m.values, rtol=1e-6, atol=1e-6
        )
    sweeps_sent = sorted({m.sensor for m in sent if "lighthouse" in m.sensor})
    assert "lighthouse/0/1" in sweeps_sent and "lighthouse/0/2" in sweeps_sent
    for sensor in ["wheel_encoders", *sweeps_sent]:
        a = [m for m in sent if m.sensor == sensor]
        b = [m for m in received if m.sensor == sensor]
        assert len(a) == len(b) > 0, sensor
        for x, y in zip(a, b, strict=True):
            np.testing.assert_allclose(y.values, x.values, rtol=1e-6, atol=2e-6)
            if sensor == "wheel_encoders":  # sampled in the step that sends them
                assert abs((y.stamp - epoch) - x.stamp) < 1e-5  # µs and epoch rounding
            else:  # a sweep at its own measurement time, from the deck's ticks
                assert abs((y.stamp - epoch) - x.stamp) < 1e-5, (sensor, y.stamp - epoch, x.stamp)
    assert assembler.sweeps_dropped == 0 and converter.sweeps_out_of_view == 0


def test_convert_refuses_a_non_state_packet() -> None:
    from chronos_bridge.packets import Ping

    with pytest.raises(TypeError):
        CarStateConverter().convert(Packet(Ping(True)), RECEIPT)
    with pytest.raises(ValueError):
        CarStateConverter(imu_sensor="both")  # type: ignore[arg-type]
