"""CarStateConverter (host) and the car-side mapping (emulator), incl. the sim round trip; the
pairing of sweeps and the deck clock when datagrams arrive out of order."""

from __future__ import annotations

import math

import numpy as np
import pytest

from chronos_bridge.car_state import (
    DECK_TICK_HZ,
    MEMORY_S,
    PLANE_OFFSETS,
    CarStateAssembler,
    CarStateConverter,
    DeckClock,
    SweepClock,
    board_imu,
    raw_sweep_angles,
    steering_from_angle,
    tick_difference,
    wire_wheel_speeds,
)
from chronos_bridge.codec import decode_from_car, encode_car_state
from chronos_bridge.packets import TICKS_24BIT, ControlInput, LighthouseSweep, Packet
from crs_core.measurements import Measurement
from tests.chronos_bridge.bridge_builders import STAMP_US, make_state

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


# ---------------------------------------------------------------- the pairing, out of order

ROTATION_TICKS = round(0.02 * DECK_TICK_HZ)  # 50 Hz
PLANE2_TICKS = round(0.01 * DECK_TICK_HZ)  # plane 2 swept half a rotation after plane 1
P1, P2 = 2.0, 2.0 + 2.0 * math.pi / 3  # raw angle_0 of the planes for the same photodiode


def rotation(k: int, p1: float = P1, da: float = 0.01) -> tuple[LighthouseSweep, LighthouseSweep]:
    """The two sweeps of rotation ``k`` of station 0 as the deck reports them (shared sync),
    plane 1's raw angle_0 ``p1 + k·da`` (rad)."""
    sync = (1000 + k * ROTATION_TICKS) % TICKS_24BIT
    first = LighthouseSweep((p1 + k * da,) * 4, 0, sync, sync)
    second_ticks = (sync + PLANE2_TICKS) % TICKS_24BIT
    second = LighthouseSweep((p1 + P2 - P1 + k * da,) * 4, 0, second_ticks, sync)
    return first, second


def feed(converter: CarStateConverter, sweep: LighthouseSweep, stamp_us: int) -> list[str]:
    state = make_state(sweeps=(sweep,))
    packet = decode_from_car(encode_car_state(state, stamp_us))
    return [m.sensor for m in converter.convert(packet, 0.0).measurements if "light" in m.sensor]


def test_a_second_plane_before_its_first_is_paired_by_deck_ticks() -> None:
    converter = CarStateConverter()
    a1, a2 = rotation(0)
    b1, b2 = rotation(1)
    assert feed(converter, a1, STAMP_US) == []  # no first plane known yet: held
    assert feed(converter, a2, STAMP_US + 10_000) == ["lighthouse/0/1", "lighthouse/0/2"]
    # rotation 1 reordered: its plane 2 first (held, not a new first plane), then plane 1
    assert feed(converter, b2, STAMP_US + 30_000) == []
    assert feed(converter, b1, STAMP_US + 20_000) == ["lighthouse/0/1", "lighthouse/0/2"]
    assert converter.sweeps_out_of_order == 1
    # the same datagram's sweep again (a duplicate): dropped; a later plane 1 alone: angle rule
    c1, _ = rotation(2)
    assert feed(converter, b1, STAMP_US + 20_000) == []
    assert feed(converter, c1, STAMP_US + 40_000) == ["lighthouse/0/1"]
    assert feed(converter, c1, STAMP_US + 40_000) == []
    assert converter.sweeps_duplicate == 2


def test_every_plane_2_first_still_gives_plane_1_then_2() -> None:
    """The arrival-order rule took such a plane 2 for plane 1 and its plane 1 for plane 2 (the
    issue's ±π/3 errors); now every rotation comes out right."""
    converter = CarStateConverter()
    for k in range(5):
        first, second = rotation(k)
        assert feed(converter, second, STAMP_US + k * 20_000 + 10_000) == []
        published = feed(converter, first, STAMP_US + k * 20_000)
        assert published == ["lighthouse/0/1", "lighthouse/0/2"]
    assert converter.sweeps_out_of_order == 5


def test_with_no_known_first_plane_a_late_plane_1_is_counted_and_does_not_spread() -> None:
    """At the start only the held sweep is a reference (the spec's rule): here a lone plane 2,
    so the next plane 2, ahead of its plane 1, is published as plane 1 (in view: raw 3.3 rad).
    Its plane 1 shows the error; the next rotation compares with that known plane 1."""
    converter = CarStateConverter()
    rotations = [rotation(k, p1=1.2) for k in range(3)]
    assert feed(converter, rotations[0][1], STAMP_US + 10_000) == []  # plane 1 lost
    assert feed(converter, rotations[1][1], STAMP_US + 30_000) == ["lighthouse/0/1"]  # wrong
    assert feed(converter, rotations[1][0], STAMP_US + 20_000) == ["lighthouse/0/1"]
    assert converter.sweeps_wrong_plane == 1
    assert feed(converter, rotations[2][1], STAMP_US + 50_000) == []  # held, not a plane 1
    assert feed(converter, rotations[2][0], STAMP_US + 40_000) == [
        "lighthouse/0/1",
        "lighthouse/0/2",
    ]
    assert converter.sweeps_wrong_plane == 1


def test_a_sweep_without_partner_is_forgotten_after_the_memory() -> None:
    converter = CarStateConverter()
    _, lone = rotation(0)
    assert feed(converter, lone, STAMP_US) == []
    later, _ = rotation(10)  # 0.2 s later: the lone plane 2 is forgotten, never published
    feed(converter, later, STAMP_US + round((MEMORY_S + 0.1) * 1e6))
    assert converter.sweeps_unpaired == 1


# ---------------------------------------------------------------- the deck clock, out of order


def test_deck_clock_stamps_late_sweeps_at_their_deck_time_across_the_wrap() -> None:
    """Sweeps every 10 ms carried 0..4 ms later by packets stamped with the car's send time
    (offset 1000 s), the counter wrapping in the middle; delivered in a shuffled order."""
    rng = np.random.default_rng(7)
    n = 60
    deck = (TICKS_24BIT - 300_000 + np.arange(n) * 240_000) / DECK_TICK_HZ
    delay = rng.uniform(0.0, 0.004, n)
    delay[::5] = 0.0  # the smallest delay of a window is 0
    order = np.argsort(np.arange(n) + rng.uniform(0.0, 4.0, n))  # up to 4 places late
    assert (np.diff(order) < 0).sum() > 10
    clock = DeckClock()
    for i in order:
        ticks = round(deck[i] * DECK_TICK_HZ) % TICKS_24BIT
        stamp = clock.stamp(ticks, 1000.0 + deck[i] + delay[i])
        if i >= 10:  # once a window holds a zero delay: the deck time plus the true offset
            assert stamp - (1000.0 + deck[i]) == pytest.approx(0.0, abs=1e-6), i
    assert clock.fallbacks == 0


def test_deck_clock_on_receipt_stamps_a_late_packet_does_not_corrupt_the_offset() -> None:
    """Without packet timestamps (stamped on receipt) a sweep every 10 ms, received at once
    except the one of k = 15, received after k = 19: its offset is 45 ms too large, the
    minimum ignores it; it is stamped at its own deck time, the others are unaffected."""
    order = [k for k in range(30) if k != 15]
    order.insert(order.index(19) + 1, 15)
    clock = DeckClock()
    errors = {}
    for k in order:
        receipt = 500.0 + (0.195 if k == 15 else k * 0.01)
        errors[k] = clock.stamp(k * 240_000, receipt) - (500.0 + k * 0.01)
    np.testing.assert_allclose(list(errors.values()), 0.0, atol=1e-9)
    assert clock.fallbacks == 0
