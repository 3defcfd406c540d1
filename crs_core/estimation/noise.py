"""Noise settings the estimators assume (their tuning), shared by the EKF and the MHE."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crs_core.measurements import parse_lighthouse


@dataclass(frozen=True)
class EstimatorNoise:
    """Standard deviations assumed by an estimator.

    Attributes
    ----------
    process_std : tuple of float
        Continuous-time white process noise on ``[x, y, yaw, vx, vy, omega]`` (per sqrt(s)):
        the covariance added over ``dt`` is ``diag(process_std)^2 * dt``. Velocities carry most
        of it: they absorb model error in the tire and drive forces.
    lighthouse_std : float
        Sweep angle, rad.
    imu_std : tuple of float
        ``a_x, a_y`` (m/s^2) and yaw rate (rad/s).
    gyro_std : float
        Yaw rate alone (rad/s).
    wheel_std : float
        Wheel speed, rad/s.
    pose_std : tuple of float
        Motion capture ``x, y`` (m) and yaw (rad).
    """

    process_std: tuple[float, ...] = (0.02, 0.02, 0.02, 1.0, 1.0, 6.0)
    lighthouse_std: float = 2e-3
    imu_std: tuple[float, float, float] = (1.0, 1.0, 0.06)
    gyro_std: float = 0.06
    wheel_std: float = 2.5
    pose_std: tuple[float, float, float] = (0.003, 0.003, 0.01)

    def __post_init__(self) -> None:
        values = [
            *self.process_std,
            self.lighthouse_std,
            *self.imu_std,
            self.gyro_std,
            self.wheel_std,
            *self.pose_std,
        ]
        if not all(np.isfinite(v) and v > 0 for v in values):
            raise ValueError("noise: every standard deviation must be finite and > 0")

    def measurement_std(self, sensor: str) -> np.ndarray:
        """Per-channel standard deviation of a stream sensor."""
        if parse_lighthouse(sensor):
            return np.full(4, self.lighthouse_std)
        table = {
            "imu": self.imu_std,
            "gyro": (self.gyro_std,),
            "wheel_encoders": (self.wheel_std,) * 4,
            "pose": self.pose_std,
        }
        return np.array(table[sensor], dtype=float)

    def process_std_for(self, nx: int) -> np.ndarray:
        """Process noise for an ``nx``-state model: extra (effect) states get 1e-3 per sqrt(s)."""
        base = np.array(self.process_std[:nx], dtype=float)
        return np.concatenate([base, np.full(max(0, nx - base.size), 1e-3)])
