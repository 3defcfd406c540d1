"""The estimator node built in this process (rclpy, no other node): its model and sensors."""

from __future__ import annotations

import pytest


@pytest.mark.parametrize(("model", "sensors"), [("dynamic", "lh+imu+we"), ("kinematic", "lh+we")])
def test_the_model_parameter_sets_the_model_and_its_default_sensors(
    model: str, sensors: str
) -> None:
    """``model`` is the estimator's model; the default ``sensors`` are those of lh+imu+we the
    model explains (the kinematic bicycle does not explain the IMU of a car that understeers)."""
    import rclpy

    from ros4crs.estimator_node import EstimatorNode

    rclpy.init(args=["--ros-args", "-p", "estimator:=ekf", "-p", f"model:={model}"])
    try:
        node = EstimatorNode()
        try:
            assert node.estimator.model.plant.name == model
            assert node.get_parameter("sensors").value == sensors
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown()
