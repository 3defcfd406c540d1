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


def test_the_params_file_noise_section_is_the_estimators_noise(tmp_path) -> None:
    """A ``noise:`` section (``crs tune-noise``'s) in ``params_file`` sets the estimator's
    process noise; a bad entry stops the node naming ``params_file`` and the entry."""
    import rclpy

    from ros4crs.estimator_node import EstimatorNode
    from ros4crs.node_support import ParameterError

    good = tmp_path / "params.yaml"
    good.write_text("parameters: {}\nnoise:\n  process_std: [0.004, 0.004, 0.004, 1, 1, 6]\n")
    bad = tmp_path / "bad.yaml"
    bad.write_text("parameters: {}\nnoise:\n  process_std: [0.004, 0.004]\n")
    for path, expected in ((good, (0.004, 0.004, 0.004, 1, 1, 6)), (bad, None)):
        rclpy.init(args=["--ros-args", "-p", "estimator:=ekf", "-p", f"params_file:={path}"])
        try:
            if expected is None:
                with pytest.raises(ParameterError, match=r"params_file.*noise\.process_std"):
                    EstimatorNode()
                continue
            node = EstimatorNode()
            try:
                assert node.estimator.settings.noise.process_std == expected
            finally:
                node.destroy_node()
        finally:
            rclpy.shutdown()
