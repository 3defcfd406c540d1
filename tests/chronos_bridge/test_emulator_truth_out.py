"""``crs car-emulator --truth-out``: the truth and the link's timing log, on the packets' clock."""

from __future__ import annotations

import signal
import time
from pathlib import Path

import numpy as np
from emulator_run import emulator_process

from chronos_bridge.codec import decode_from_car, encode_torque_command
from chronos_bridge.packets import CarState


def test_truth_out_logs_states_commands_and_the_cut_off(tmp_path: Path) -> None:
    out = tmp_path / "truth.npz"
    with emulator_process("30", "--truth-out", str(out), timeout=5.0) as (process, host, car):
        stamps, sent = [], []
        start = time.monotonic()
        while time.monotonic() - start < 1.5:
            packet = decode_from_car(host.recvfrom(1024)[0])
            if isinstance(packet.contents, CarState):
                stamps.append(packet.stamp_s)
            if time.monotonic() - start < 0.5 and len(stamps) % 8 == 0:
                now = time.time()
                host.sendto(encode_torque_command(0.0, 0.5, round(now * 1e6)), car)
                sent.append(now)
        process.send_signal(signal.SIGTERM)
        _, errors = process.communicate(timeout=10)
    log = np.load(out)
    assert log["x"].shape == (log["t"].size, 6) and log["t"].size >= len(stamps)
    assert set(np.round(stamps, 6)) <= set(np.round(log["t"], 6))  # the packets' stamps
    assert np.all(np.diff(log["t"]) > 0) and log["x"][-1, 3] > 0.1  # it drove
    assert log["command_read_t"].size == len(sent)
    np.testing.assert_allclose(log["command_host_t"], sent, atol=2e-6)
    assert np.all(log["command_read_t"] - log["command_host_t"] < 0.02)
    # one cut-off, 200..204 ms after the last reference was read
    assert log["pause_t"].size == 1 and log["resume_t"].size == 0
    gap = log["pause_t"][0] - log["pause_last_command_t"][0]
    assert 0.195 <= gap <= 0.21, gap
    assert "motors cut (pause 1)" in errors
