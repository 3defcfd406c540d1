"""A car's nodes in one process (``python -m ros4crs.composed``): each with its own name,
namespace and parameters, seen in the ROS graph as the separate processes' nodes are; bad
arguments refused in one line."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from ros4crs.composed import node_argument

REPO = Path(__file__).resolve().parents[2]


def test_a_node_argument_names_the_node_its_module_and_its_parameters() -> None:
    assert node_argument("/car1/estimator=ros4crs.estimator_node:/tmp/p.yaml") == (
        "/car1/estimator",
        "ros4crs.estimator_node",
        "/tmp/p.yaml",
    )
    with pytest.raises(argparse.ArgumentTypeError, match="cannot share a process"):
        node_argument("/recorder=ros4crs.recorder_node:/tmp/p.yaml")
    with pytest.raises(argparse.ArgumentTypeError, match="expected /ns/name=module"):
        node_argument("estimator=ros4crs.estimator_node")


def _write(path: Path, name: str, parameters: dict) -> Path:
    path.write_text(yaml.safe_dump({name: {"ros__parameters": parameters}}))
    return path


def test_two_nodes_share_a_process_with_their_own_names_and_parameters(tmp_path) -> None:
    """An estimator and a path-following controller of /car7 in one process: both in the
    graph under /car7 with the parameters of their own files (the controller's rate), and one
    process stops on SIGINT with code 0."""
    import rclpy
    from rcl_interfaces.srv import GetParameters

    estimator = _write(tmp_path / "e.yaml", "/car7/estimator", {"estimator": "ekf"})
    controller = _write(
        tmp_path / "c.yaml", "/car7/controller", {"controller": "path", "rate_hz": 20.0}
    )
    env = dict(os.environ, ROS_DOMAIN_ID="97", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    command = [sys.executable, "-m", "ros4crs.composed"]
    command += ["--node", f"/car7/estimator=ros4crs.estimator_node:{estimator}"]
    command += ["--node", f"/car7/controller=ros4crs.controller_node:{controller}"]
    process = subprocess.Popen(
        command, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    previous = os.environ.get("ROS_DOMAIN_ID")
    os.environ["ROS_DOMAIN_ID"] = "97"
    rclpy.init()
    try:
        probe = rclpy.create_node("probe")
        names: set[tuple[str, str]] = set()
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and process.poll() is None:
            names = set(probe.get_node_names_and_namespaces())
            if {("estimator", "/car7"), ("controller", "/car7")} <= names:
                break
            time.sleep(0.2)
        assert {("estimator", "/car7"), ("controller", "/car7")} <= names, names
        client = probe.create_client(GetParameters, "/car7/controller/get_parameters")
        assert client.wait_for_service(timeout_sec=20)
        request = client.srv_type.Request(names=["rate_hz", "controller"])
        future = client.call_async(request)
        rclpy.spin_until_future_complete(probe, future, timeout_sec=20)
        values = future.result().values
        assert values[0].double_value == 20.0 and values[1].string_value == "path"
        probe.destroy_node()
    finally:
        rclpy.shutdown()
        if previous is None:
            os.environ.pop("ROS_DOMAIN_ID", None)
        else:
            os.environ["ROS_DOMAIN_ID"] = previous
        process.send_signal(2)
        try:
            code = process.wait(timeout=20)
        finally:
            if process.poll() is None:
                process.kill()
    log = process.stdout.read() if process.stdout else ""
    assert code == 0, log
    assert log.count(f"running (pid {process.pid})") == 2


def test_a_node_that_cannot_start_stops_the_process_in_one_line(tmp_path) -> None:
    bad = _write(tmp_path / "e.yaml", "/car1/estimator", {"estimator": "nonsense"})
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "ros4crs.composed",
            "--node",
            f"/car1/estimator=ros4crs.estimator_node:{bad}",
        ],
        cwd=REPO,
        env=dict(os.environ, ROS_DOMAIN_ID="98", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2
    line = result.stderr.strip().splitlines()[-1]
    assert line.startswith("/car1/estimator: error:") and "estimator" in line
