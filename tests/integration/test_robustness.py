"""Nodes survive bad input, and the launcher reports a node that dies.

One simulator and one EKF estimator run for the whole module (domain 104); the tests publish
to them from a probe node. The kill test runs last: it kills the simulator.
"""

from __future__ import annotations

import math
import os
import re
import signal
import time

import numpy as np
import pytest
from rclpy.serialization import serialize_message

from launch_scripts.launcher import Launcher, NodeSpec
from ros4crs import conversions
from ros4crs.bag_repair import BagDamagedWarning
from ros4crs.bag_replay import read_car
from tests.integration.stack_probe import launched, log_text, message_stamp, wait_for

pytestmark = pytest.mark.integration

DOMAIN = 104
DOMAIN_LAG = 126
#: The estimator's lag: large enough that no sensor data of a busy machine arrive late, so the
#: only late data are the ones the test sends.
LAG_S = 0.2


@pytest.fixture(scope="module")
def stack(tmp_path_factory, warm_codegen):
    """A running simulator and EKF estimator in ``/car1``, a probe collecting the estimates and
    diagnostics: ``(launcher, probe, estimates, diagnostics)``."""
    from chronos_msgs.msg import CarState, EstimatorDiagnostics

    log_dir = tmp_path_factory.mktemp("robustness") / "logs"
    nodes = [
        NodeSpec("simulator", "ros4crs.simulator_node", "/car1", {"seed": 5}),
        NodeSpec(
            "estimator", "ros4crs.estimator_node", "/car1", {"estimator": "ekf", "lag": LAG_S}
        ),
    ]
    with launched(nodes, DOMAIN, log_dir) as (launcher, probe):
        estimates = probe.collect(CarState, "/car1/estimate/state")
        diagnostics = probe.collect(EstimatorDiagnostics, "/car1/estimate/diagnostics")
        launcher.start()
        wait_for(lambda: len(estimates) >= 10, 90.0, "the first estimates")
        wait_for(lambda: diagnostics, 30.0, "the first diagnostics")
        yield launcher, probe, estimates, diagnostics


def _last_warning(log_dir, text: str) -> float:
    """Wall time of the estimator's last log line containing ``text`` (-inf if none)."""
    times = [
        float(match.group(1))
        for line in log_text(log_dir, "/car1/estimator").splitlines()
        if text in line and (match := re.match(r"\[\w+\] \[(\d+\.\d+)\]", line))
    ]
    return max(times, default=-math.inf)


def _after(received: list, wall_time: float) -> list:
    return [msg for t, msg in received if t > wall_time]


def test_malformed_and_late_messages_are_logged_dropped_and_counted(stack):
    """The estimator node drops each malformed or late message with a warning naming the
    problem, counts it in its diagnostics and keeps running.

    Sent, within a fraction of a second (each topic's warning is throttled on its own):
    (a) a LighthouseSweep with a NaN angle, (b) an Imu with an infinite acceleration, (c) a
    CarInput with a NaN steer (the simulator drops it too), (d) raw CDR bytes on the
    WheelSpeeds topic that do not deserialize (truncated, and a string length past the end),
    (e) a valid WheelSpeeds stamped 0.5 s before one the estimator already processed,
    (f) a SensorBatch whose two readings are bad (a NaN, a negative stamp), (g) a SensorBatch
    with fewer stamps than sensors.
    Afterwards the node is alive, publishes finite estimates, its log names each problem
    ("dropped malformed lighthouse on sensors/lighthouse: angles: contains NaN ..."), and its
    diagnostics count the five malformed messages, the batch and its two readings as ignored
    (nothing else is ignored: the simulator publishes only sensors the estimator uses) and the
    out-of-order one as late.
    """
    from sensor_msgs.msg import Imu

    from chronos_msgs.msg import CarInput, LighthouseSweep, SensorBatch, WheelSpeeds

    launcher, probe, estimates, diagnostics = stack
    assert launcher.poll() == [], "a node died before the test (the kill test runs last)"
    log_dir = launcher.log_dir
    lighthouse = probe.publisher(LighthouseSweep, "/car1/sensors/lighthouse")
    imu = probe.publisher(Imu, "/car1/sensors/imu")
    command = probe.publisher(CarInput, "/car1/input", subscribers=2)
    wheels = probe.publisher(WheelSpeeds, "/car1/sensors/wheel_speeds")
    batches = probe.publisher(SensorBatch, "/car1/sensors/batch")
    late_before = diagnostics[-1][1].late_measurements
    assert diagnostics[-1][1].ignored_measurements == 0

    now = time.time()
    sweep = LighthouseSweep(base_station=0, plane=1, angles=[math.nan, 0.1, 0.2, 0.3])
    conversions.fill_stamp(sweep.header.stamp, now)
    lighthouse.publish(sweep)
    bad_imu = Imu()
    bad_imu.linear_acceleration.x = math.inf
    conversions.fill_stamp(bad_imu.header.stamp, now)
    imu.publish(bad_imu)
    command.publish(conversions.car_input_msg(np.array([math.nan, 0.0]), now))
    valid = WheelSpeeds(front_left=1.0, front_right=1.0, rear_left=1.0, rear_right=1.0)
    valid.header.frame_id = "base_link"
    conversions.fill_stamp(valid.header.stamp, now)
    cdr = serialize_message(valid)
    wheels.publish(cdr[:20])  # truncated
    wheels.publish(cdr[:12] + b"\xf0\xff\xff\x7f" + cdr[16:])  # frame_id length past the end
    stamp_ns = conversions.stamp_ns(now)
    batches.publish(
        SensorBatch(
            sensors=["imu", "wheel_encoders"],
            stamps_ns=[stamp_ns, -1],
            values=[0.0, math.nan, 0.0, 1.0, 1.0, 1.0, 1.0],
        )
    )
    batches.publish(SensorBatch(sensors=["gyro", "gyro"], stamps_ns=[stamp_ns], values=[0.0, 0.0]))
    sent = time.time()

    # (e) out of order: once an estimate past ``now`` is out, data stamped before it are late
    wheels.publish(valid)
    wait_for(
        lambda: any(message_stamp(m) > now + 0.05 for m in _after(estimates, sent)),
        10.0,
        "an estimate past the valid wheel speeds",
    )
    # the late warning is throttled to one a second: let one pass since any natural one
    wait_for(
        lambda: time.time() > _last_warning(log_dir, "out-of-order") + 1.1,
        5.0,
        "the late-data warning throttle",
    )
    old = WheelSpeeds(front_left=1.0, front_right=1.0, rear_left=1.0, rear_right=1.0)
    late_stamp = math.floor((now - 0.5) * 100) / 100  # prints the same with 3 decimals
    conversions.fill_stamp(old.header.stamp, late_stamp)
    wheels.publish(old)

    # diagnostics come once a second
    checked = time.time()

    def counted():
        fresh = _after(diagnostics, checked)
        return next(
            (m for m in fresh if m.ignored_measurements >= 8 and m.late_measurements > late_before),
            None,
        )

    report = wait_for(
        counted,
        10.0,
        lambda: f"diagnostics counting the drops (late before {late_before}): {diagnostics[-1]}",
    )
    assert report.ignored_measurements == 8, report

    expected = {
        "/car1/estimator": [
            "dropped malformed lighthouse on sensors/lighthouse: angles: contains NaN",
            "dropped malformed imu on sensors/imu: linear_acceleration: contains NaN or inf",
            "dropped malformed input on input: steer: contains NaN",
            "dropped malformed wheel_encoders on sensors/wheel_speeds: failed to deserialize",
            "dropped 2 reading(s) of a batch on sensors/batch: readings[0] (imu): values: imu at",
            "dropped malformed batch on sensors/batch: stamps_ns: 1 stamps for 2 sensors",
            f"dropped out-of-order data stamped {late_stamp:.3f} s",
        ],
        "/car1/simulator": ["dropped malformed input on input: steer: contains NaN"],
    }
    for node, lines in expected.items():
        wait_for(
            lambda node=node, lines=lines: all(line in log_text(log_dir, node) for line in lines),
            10.0,
            f"the warnings in the log of {node}",
        )

    # still running and estimating: a second of finite estimates after all that
    resumed = time.time()
    wait_for(lambda: len(_after(estimates, resumed)) >= 30, 10.0, "estimates after the drops")
    states = np.array([[m.x, m.y, m.yaw, m.vx, m.vy, m.omega] for m in _after(estimates, sent)])
    assert np.all(np.isfinite(states))
    assert launcher.poll() == []


def test_a_killed_recorder_leaves_a_bag_readable_up_to_its_last_second(stack, tmp_path):
    """``kill -9`` of a recorder (no clean close: no MCAP summary, no metadata.yaml) after ~4 s
    of 100 Hz sensor batches: the bag is read up to its last flushed chunk, with a warning
    saying what was lost, and that chunk is at most ~``flush_period`` (1 s) older than the
    kill."""
    del stack  # the running simulator publishes the sensor batches
    bag = tmp_path / "bag"
    recorder = Launcher(
        [
            NodeSpec(
                "recorder",
                "ros4crs.recorder_node",
                "",
                {"output": str(bag), "topics": "/car1/sensors/batch", "flush_period": 1.0},
            )
        ],
        DOMAIN,
        tmp_path / "logs",
    )
    try:
        recorder.start()
        wait_for(lambda: any(bag.glob("*.mcap")), 30.0, "the recorder to create its bag")
        wait_for(lambda: "recording" in log_text(tmp_path / "logs", "/recorder"), 30.0, "its start")
        time.sleep(4.3)
        (process,) = recorder.processes.values()
        os.kill(process.pid, signal.SIGKILL)
        killed = time.time()
        process.wait(10)
    finally:
        recorder.stop()
    assert not (bag / "metadata.yaml").exists()
    with pytest.warns(BagDamagedWarning, match="cut off: read"):
        imu = [m for m in read_car(bag, "/car1").measurements if m.sensor == "imu"]
    assert len(imu) > 250 * 2.0, len(imu)  # more than 2 of the ~4 s
    last = imu[-1].stamp
    assert killed - last < 1.0 + 0.6, killed - last  # one flush period, and a busy machine


def test_launcher_reports_a_killed_node_and_the_others_keep_running(stack):
    """``kill -9`` of one node process (the simulator) is reported by ``Launcher.poll()`` once,
    with the node's full name and return code -9 (and the end of its log); the estimator
    process keeps running: without any sensor it stops publishing estimates within about its
    ``health.lost_silent_s`` (1 s; a controller then sees a stale estimate and stops the car)
    and goes on publishing its diagnostics, which say it is lost."""
    launcher, _, estimates, diagnostics = stack
    simulator = launcher.processes["/car1/simulator"]
    killed = time.time()
    os.kill(simulator.pid, signal.SIGKILL)
    exited = wait_for(launcher.poll, 10.0, "the launcher to notice the killed simulator")
    assert [(e.node, e.returncode) for e in exited] == [("/car1/simulator", -signal.SIGKILL)]
    assert isinstance(exited[0].log_tail, str)

    def lost_reports() -> list:
        return [d for d in _after(diagnostics, killed) if d.status.startswith("lost")]

    wait_for(lambda: len(lost_reports()) >= 2, 15.0, "two diagnostics saying lost after the kill")
    quiet_since = time.time()
    time.sleep(1.0)
    assert _after(estimates, quiet_since) == []  # nothing stale published while lost
    assert launcher.processes["/car1/estimator"].poll() is None
    assert launcher.poll() == []  # reported once, and nothing else died


def test_data_that_arrive_late_raise_the_estimators_lag(tmp_path, warm_codegen):
    """Sensor data that arrive 60 ms after their stamps (a loaded machine's transport) against
    an estimator asking 20 ms in the past: it raises its lag past their delay (logged), no
    more data are late after the first second, and its estimates come out stamped that far
    back."""
    from sensor_msgs.msg import Imu

    from chronos_msgs.msg import CarState, EstimatorDiagnostics, WheelSpeeds
    from crs_core.measurements import Measurement

    delay = 0.06
    estimator = NodeSpec(
        "estimator", "ros4crs.estimator_node", "/car1", {"estimator": "ekf", "sensors": "imu+we"}
    )
    with launched([estimator], DOMAIN_LAG, tmp_path / "logs") as (launcher, probe):
        estimates = probe.collect(CarState, "/car1/estimate/state")
        diagnostics = probe.collect(EstimatorDiagnostics, "/car1/estimate/diagnostics")
        launcher.start()
        imu = probe.publisher(Imu, "/car1/sensors/imu")
        wheels = probe.publisher(WheelSpeeds, "/car1/sensors/wheel_speeds")
        started = time.time()
        settled = started + 2.0
        late_at_settled = None
        while time.time() < started + 6.0:  # a standing car, 100 Hz, each sample 60 ms old
            stamp = time.time() - delay
            imu.publish(conversions.measurement_to_msg(Measurement(stamp, "imu", [0, 0, 0])))
            wheels.publish(
                conversions.measurement_to_msg(Measurement(stamp, "wheel_encoders", [0] * 4))
            )
            if late_at_settled is None and time.time() > settled and diagnostics:
                late_at_settled = diagnostics[-1][1].late_measurements
            time.sleep(0.01)
        assert not launcher.poll()
        ended = time.time()
        wait_for(lambda: _after(diagnostics, ended), 3.0, "diagnostics after the last data")
    log = log_text(tmp_path / "logs", "/car1/estimator")
    match = re.search(r"data arrive up to (\d+) ms after their stamps: estimating (\d+) ms", log)
    assert match and int(match.group(1)) >= 1e3 * delay and int(match.group(2)) > 1e3 * delay, log
    assert diagnostics[0][1].late_measurements <= late_at_settled  # late at first, then
    assert diagnostics[-1][1].late_measurements == late_at_settled  # none after 2 s
    ages = [t - message_stamp(m) for t, m in estimates if t > settled]
    assert np.median(ages) > delay, np.median(ages)
