"""``crs launch car --emulate``: the whole stack against emulated cars over loopback UDP.

(a) the controller killed: the emulated car cuts its motors
200 ms after the last reference, and drives again when a new controller sends (backing out
first if it coasted to a stand off the track); (b) two emulated cars at once in /car1 and /car2
on their own ports, racing with the MPCC and the MHE: each completes a lap on the track with its
estimate within a few mm of its emulator's truth, each bridge paired with its own emulator only,
every reference of a car's controller reaches that car. One emulated car watched live (the
visualizer, the latency chain, the bridge's counters) races in
tests/integration/test_link_presets.py's ``typical`` link.

Ports of their own (not the defaults), so a ``crs launch car`` running beside does not collide.
"""

from __future__ import annotations

import signal
import time

import numpy as np
import pytest

from crs_core.track import load_demo_track
from launch_scripts.car_stack import car_nodes, run_car_stack
from launch_scripts.launcher import Launcher, NodeSpec
from launch_scripts.sim_stack import StackOptions
from ros4crs.conversions import seconds_from_stamp
from sim.closed_loop import off_track
from tests.integration.stack_probe import Probe, log_text, wait_for

pytestmark = pytest.mark.integration

DOMAIN_CUTOFF = 124
DOMAIN_TWO_EMULATED = 125


def test_motors_cut_200_ms_after_the_last_command_and_drive_again(tmp_path, warm_codegen) -> None:
    out = tmp_path / "run"
    out.mkdir()
    # a process per node: the controller alone is killed
    options = StackOptions("mhe", record="estimates", process_per_node=True)
    nodes = car_nodes(1, options, out / "bag", out, True, ports=(21221, 21321))
    launcher = Launcher(nodes, DOMAIN_CUTOFF, out / "logs")
    controller = next(n for n in nodes if n.name == "controller")
    again = Launcher(
        [NodeSpec(controller.name, controller.module, controller.namespace, controller.parameters)],
        DOMAIN_CUTOFF,
        out / "logs_again",
    )
    emulator_log = lambda: log_text(out / "logs", "/car1/emulator")  # noqa: E731
    from geometry_msgs.msg import TwistStamped

    probe = Probe(DOMAIN_CUTOFF)
    # the car's own v_x estimate through the bridge, stamped by the car (the truth log's clock)
    speeds = probe.collect(TwistStamped, "/car1/telemetry/velocity")

    def driving_since(after: float) -> tuple[float, float] | None:
        """The car's stamps of the first and last of the last 25 readings (0.5 s at 50 Hz), if
        20 of them are above 1 m/s and all are stamped after ``after`` (one reading once passed
        1.1 s after the start, with the car barely moving)."""
        last = [(seconds_from_stamp(m.header.stamp), m.twist.linear.x) for _, m in speeds[-25:]]
        fast = sum(v > 1.0 for _, v in last)
        if len(last) == 25 and fast >= 20 and last[0][0] > after:
            return last[0][0], last[-1][0]
        return None

    try:
        launcher.start()
        wait_for(
            lambda: driving_since(0.0) is not None,
            60.0,
            lambda: f"the car driving; bridge log: {log_text(out / 'logs', '/car1/bridge')[-400:]}",
        )
        # no cut-off so far (a cold start that held the references back would be one)
        assert "motors cut" not in emulator_log(), emulator_log()
        launcher.processes["/car1/controller"].send_signal(signal.SIGKILL)
        wait_for(lambda: "motors cut (pause 1)" in emulator_log(), 5.0, "the motor cut-off")
        time.sleep(1.0)
        again.start()
        wait_for(
            lambda: "references again: drives" in emulator_log(),
            60.0,
            lambda: f"references again; emulator log: {emulator_log()[-400:]}",
        )
        cut_stamp = seconds_from_stamp(speeds[-1][1].header.stamp)
        # the car coasted with its last steering and may stand off the track, facing out: the
        # new controller then backs it out first (its StuckRecovery), which takes a few seconds
        driving_again = wait_for(
            lambda: driving_since(cut_stamp),
            20.0,
            lambda: (
                f"driving again; log: {log_text(out / 'logs_again', '/car1/controller')[-600:]}"
            ),
        )
        time.sleep(0.5)
        assert not [e for e in launcher.poll() if e.node != "/car1/controller"]
        assert not again.poll()
    finally:
        probe.close()
        again.stop()
        launcher.stop()
    with np.load(out / "truth_car1.npz") as log:
        # every cut-off 200 ms (+ one 4 ms tick) after the last reference: the kill, and the
        # stop at the end (the controller stops before the emulator)
        gaps = log["pause_t"] - log["pause_last_command_t"]
        assert gaps.size >= 1 and np.all((gaps >= 0.195) & (gaps <= 0.25)), gaps
        assert log["resume_t"].size == 1 and log["pause_t"][0] < log["resume_t"][0]
        t, x = log["t"], log["x"]
        cut, resumed = log["pause_t"][0], log["resume_t"][0]
    before = x[(t > cut - 0.5) & (t < cut), 3]
    stopped = x[(t > resumed - 0.3) & (t < resumed), 3]
    again_v = x[(t >= driving_again[0]) & (t <= driving_again[1]), 3]
    assert before.max() > 0.5  # it was driving
    assert stopped.max() < before.max() * 0.7  # it slowed with the motor cut
    # and drives again on the new controller's references: the emulator's truth agrees with
    # what the car reported (its wheel speeds carry ~0.05 m/s of noise)
    assert again_v.size > 0 and np.median(again_v) > 0.8, again_v


def test_two_emulated_cars_on_their_own_ports_and_namespaces(tmp_path, warm_codegen) -> None:
    """Two cars, each with the MHE and the path follower (1 m/s), over their own links: nine
    processes on two cores. Each car completes a lap without leaving the track (its footprint,
    from the emulator's truth) or losing its estimate, its estimate within a few mm of the truth
    and its bridge decoding every datagram; the two links stay apart. (Racing both with the
    MPCC took 189-192 % of the two cores on a slow day, the host's yardstick 13.8 µs: starved
    loops, motor cuts and cars 11-14 cm over the border. Whether several racing cars fit a
    machine is ``crs bench stack``'s question, issue 38's.)"""
    report = run_car_stack(
        2,
        StackOptions("mhe", controller="path", after_start_up=True, record="estimates"),
        16.0,  # of driving (the run counts from the moment every process has started)
        tmp_path / "run",
        True,
        domain_id=DOMAIN_TWO_EMULATED,
        ports=(21231, 21331),
    )
    assert report["node_deaths"] == []
    assert (tmp_path / "run" / "path.png").is_file()
    track = load_demo_track()
    for i in (1, 2):
        car = report["cars"][f"car{i}"]
        diagnostics = car["bridge_diagnostics"]
        assert diagnostics["car"] == f"127.0.0.1:{21331 + i - 1}"  # its own emulator only
        assert diagnostics["counts"]["foreign"] == 0
        with np.load(tmp_path / "run" / f"truth_car{i}.npz") as log:
            outside = off_track(log["t"], log["x"], track)
        assert car["laps_completed"] >= 1, (i, car["lap_times_s"])
        assert outside["seconds"] == 0.0, (i, outside)
        assert car["estimator_reinitializations"] == 0, i
        rmse = car["estimation_rmse"]
        assert rmse["x"] < 0.008 and rmse["y"] < 0.008 and rmse["yaw"] < 0.03, (i, rmse)
        counts = diagnostics["counts"]
        assert counts["car_state"] > 2000 and counts["invalid"] == counts["undecodable"] == 0
        assert " 0 rejected" in car["emulator_summary"], (i, car["emulator_summary"])
        # the references this car's bridge sent (the commands and their repeats) this car's
        # emulator read (and no other's), but for the last ones: the cars stop first
        sent_log = car["bridge_final_log"].split("sent: commands ")[1]
        commands = int(sent_log.split(",")[0])
        sent = commands + int(sent_log.split("repeats ")[1].split(",")[0])
        read = int(car["emulator_summary"].split(" commands received")[0].rsplit(" ", 1)[1])
        assert commands > 150 and 0.9 * sent <= read <= sent, (i, commands, sent, read)
