r"""Blind start: a full initial state from a few consecutive pose fixes.

Each Lighthouse sweep pair (both planes of a station within ``max_pair_gap``) is solved for the
car's pose by :class:`~crs_core.estimation.lighthouse_pose.LighthousePoseSolver`; a
motion-capture ``pose`` sample is a fix as it is. Once ``min_fixes`` fixes within ``span_s``
agree with each other (no jump faster than ``HealthSettings.max_speed`` allows, plus
``jump_tolerance``), a straight line through them gives

* position and yaw at the newest fix (the fit's value there),
* the world velocity and the yaw rate (the fit's slopes); the velocity is turned into the body
  frame, :math:`v_b = R(\psi)^\top \dot p`.

The covariance is the newest fix's pose covariance, widened in position by the distance the
car covers in half the largest plane gap (the two planes of a pair are swept at different
times), and, for the velocities, the fit's standard error floored at ``velocity_std`` /
``yaw_rate_std`` (the fixes are few and close together).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from crs_core.analysis.angles import wrap_angle
from crs_core.errors import FieldError
from crs_core.estimation.lighthouse_pose import LighthouseFixes, LighthousePoseSolver, PoseFix
from crs_core.estimation.noise import EstimatorNoise
from crs_core.measurements import Measurement, parse_lighthouse
from crs_core.settings import Settings, positive


@dataclass(frozen=True)
class InitializationSettings(Settings, prefix="initialization"):
    """How a blind start builds its state (see the module docstring).

    Attributes
    ----------
    min_fixes : int
        Consecutive consistent fixes needed.
    span_s : float
        They must lie within this many seconds.
    max_pair_gap : float
        Largest stamp difference of the two planes of a sweep pair, s.
    jump_tolerance : float
        Allowed position jump between consecutive fixes beyond what ``max_speed`` covers, m.
    velocity_std, yaw_rate_std : float
        Floors of the initial standard deviation of ``v_x, v_y`` (m/s) and ``omega`` (rad/s).
    """

    min_fixes: int = 3
    span_s: float = positive(0.3)
    max_pair_gap: float = positive(0.03)
    jump_tolerance: float = positive(0.05)
    velocity_std: float = positive(0.3)
    yaw_rate_std: float = positive(1.0)

    def _check_relations(self) -> None:
        if self.min_fixes < 2:
            raise FieldError("initialization.min_fixes", "must be >= 2 (velocities need two)")


@dataclass(frozen=True)
class InitialState:
    """A state to start from: ``x`` (6,) at ``stamp`` (s) with ``covariance`` (6, 6)."""

    stamp: float
    x: np.ndarray
    covariance: np.ndarray


class PoseInitializer:
    """Turns a stream of Lighthouse sweeps (or motion-capture poses) into an initial state.

    Parameters
    ----------
    model : CarModel
        The estimation model (its Lighthouse geometry).
    sensors : set of str
        The estimator's sensor groups: ``lh`` and/or ``pose`` are used.
    noise : EstimatorNoise
        Angle and pose standard deviations.
    settings : InitializationSettings
    max_speed : float
        Fastest plausible car speed, m/s (consistency of consecutive fixes).
    """

    def __init__(
        self,
        model,
        sensors: frozenset[str],
        noise: EstimatorNoise,
        settings: InitializationSettings,
        max_speed: float = 10.0,
    ) -> None:
        self.settings, self.noise, self.max_speed = settings, noise, max_speed
        self._use_lighthouse = "lh" in sensors and model.n_base_stations > 0
        self._use_pose = "pose" in sensors
        self._lighthouse = LighthouseFixes(
            LighthousePoseSolver(model, noise.lighthouse_std), settings.max_pair_gap
        )
        self._fixes: list[PoseFix] = []

    def add(self, measurement: Measurement) -> InitialState | None:
        """Take one measurement; an initial state once enough fixes agree, else ``None``."""
        fix = None
        if self._use_lighthouse and parse_lighthouse(measurement.sensor):
            fix = self._lighthouse.add(measurement)
        elif self._use_pose and measurement.sensor == "pose":
            std = np.asarray(self.noise.pose_std)
            pose = measurement.values.copy()
            pose[2] = wrap_angle(pose[2])
            fix = PoseFix(measurement.stamp, pose, np.diag(std**2), 0.0, ())
        if fix is None:
            return None
        return self._add_fix(fix)

    def _add_fix(self, fix: PoseFix) -> InitialState | None:
        s = self.settings
        if self._fixes:
            last = self._fixes[-1]
            dt = fix.stamp - last.stamp
            jump = float(np.hypot(*(fix.pose[:2] - last.pose[:2])))
            if dt <= 0 or jump > self.max_speed * dt + s.jump_tolerance:
                self._fixes.clear()  # inconsistent with the run so far: start a new one
        self._fixes.append(fix)
        self._fixes = [f for f in self._fixes if f.stamp >= fix.stamp - s.span_s]
        if len(self._fixes) < s.min_fixes:
            return None
        return self._fit()

    def _fit(self) -> InitialState:
        s = self.settings
        fixes = list(self._fixes)
        t = np.array([f.stamp for f in fixes]) - fixes[-1].stamp
        poses = np.array([f.pose for f in fixes])
        poses[:, 2] = np.unwrap(poses[:, 2])
        design = np.column_stack([np.ones_like(t), t])
        coefficients, *_ = np.linalg.lstsq(design, poses, rcond=None)
        value, slope = coefficients
        residual = poses - design @ coefficients
        dof = max(len(t) - 2, 1)
        spread = max(float(np.sum((t - t.mean()) ** 2)), 1e-12)
        slope_std = np.sqrt(np.sum(residual**2, axis=0) / dof / spread)
        yaw = wrap_angle(value[2])
        c, sn = math.cos(yaw), math.sin(yaw)
        vx = c * slope[0] + sn * slope[1]
        vy = -sn * slope[0] + c * slope[1]
        x = np.array([value[0], value[1], yaw, vx, vy, slope[2]])
        covariance = np.zeros((6, 6))
        covariance[:3, :3] = fixes[-1].covariance
        # the two planes of a pair are swept up to max_pair_gap apart while the car moves: the
        # pair's pose is a blend (measured on the simulated stream: 11 mm median at 1.4 m/s)
        blur = float(np.hypot(slope[0], slope[1])) * s.max_pair_gap / 2
        covariance[:2, :2] += np.eye(2) * blur**2
        velocity_std = max(s.velocity_std, float(np.hypot(slope_std[0], slope_std[1])))
        covariance[3, 3] = covariance[4, 4] = velocity_std**2
        covariance[5, 5] = max(s.yaw_rate_std, float(slope_std[2])) ** 2
        self._fixes.clear()
        self._lighthouse.clear()
        return InitialState(float(fixes[-1].stamp), x, covariance)
