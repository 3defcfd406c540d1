r"""Planar car pose from one set of Lighthouse V2 sweeps (a single-shot fix, no dynamics).

:class:`LighthousePoseSolver` finds the pose :math:`q = (x, y, \psi)` (world frame, m, m, rad)
explaining the sweep angles of the 4 photodiodes for every station whose two planes are given:

.. math::

    \hat q = \arg\min_q \sum_{s, l, k} \operatorname{wrap}\big(\alpha_{s,l,k} - h_{s,l,k}(q)\big)^2,
    \qquad \Sigma = \sigma_\alpha^2 \,(J^\top J)^{-1},

with :math:`h` the model's own CasADi sweep-angle expressions (:mod:`crs_core.model.lighthouse`),
:math:`J = \partial h / \partial q` at :math:`\hat q` and :math:`\sigma_\alpha` the angle noise
std. A closed-form ray inversion gives the start. :class:`SweepPairer` pairs planes in a stream;
:class:`LighthouseFixes` turns a stream into fixes (pairing, then solving).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import casadi as ca
import numpy as np

from crs_core.analysis.angles import wrap_angle
from crs_core.codegen import SX_OPTIONS, compile_functions
from crs_core.errors import FieldError
from crs_core.measurements import Measurement, lighthouse_sensor, parse_lighthouse
from crs_core.model import CarModel
from crs_core.model.chronos import base_station_from_parameters
from crs_core.model.sensors import N_PHOTODIODES

__all__ = ["LighthouseFixes", "LighthousePoseSolver", "PoseFix", "SweepPairer"]

_MAX_ITERATIONS = 30
_STEP_TOLERANCE = 1e-10


@dataclass(frozen=True)
class PoseFix:
    """One Lighthouse pose fix.

    Attributes
    ----------
    stamp : float
        Time the fix refers to, s (the stream's clock).
    pose : np.ndarray
        ``(x, y, yaw)`` of the car body frame in the world frame: m, m, rad (yaw wrapped to
        [-pi, pi), counter-clockwise from world x).
    covariance : np.ndarray
        3x3 covariance of ``pose`` (m^2, m rad, rad^2): :math:`\\sigma_\\alpha^2 (J^\\top J)^{-1}`.
    residual_rms : float
        RMS of the wrapped sweep-angle residuals at the solution, rad.
    stations : tuple of int
        Base stations whose two planes were used.
    """

    stamp: float
    pose: np.ndarray
    covariance: np.ndarray
    residual_rms: float
    stations: tuple[int, ...]


class LighthousePoseSolver:
    r"""Least-squares planar pose from the sweep angles of one or more base stations.

    Parameters
    ----------
    model : CarModel
        Supplies the sweep-angle expressions, station geometry and photodiode positions (its
        current ``parameters``).
    angle_std : float
        Sweep-angle noise std :math:`\sigma_\alpha`, rad; scales the covariance.
    max_rms_ratio : float
        A fix is rejected (``None``) when ``residual_rms > max_rms_ratio * angle_std``. The
        default 5 is far outside the noise: with :math:`m = 8 n_s` residuals,
        :math:`m \cdot \mathrm{rms}^2/\sigma_\alpha^2 \sim \chi^2_{m-3}`, so rms above
        :math:`5\sigma_\alpha` has probability below 1e-30 under the model.

    Notes
    -----
    Start (no ``guess``): with :math:`a = \tan t_1`, :math:`b = \tan t_2` and the model
    :math:`\alpha_l = \theta + \arcsin(\zeta \tan t_l)`, :math:`\zeta = z/r` in the station frame,
    :math:`b \sin(\alpha_1 - \theta) = a \sin(\alpha_2 - \theta)` gives
    :math:`\tan\theta = (b \sin\alpha_1 - a \sin\alpha_2)/(b \cos\alpha_1 - a \cos\alpha_2)`
    (branch with :math:`|\alpha_1 - \theta| < \pi/2`) and :math:`\zeta = \sin(\alpha_1-\theta)/a`.
    The ray :math:`p_{bs} + s R_{bs} (\cos\theta, \sin\theta, \zeta)` meets the floor z = 0 at
    :math:`s > 0` (else the angles are unreachable and the fix is ``None``). A 2-D Procrustes fit
    maps the body photodiodes onto the 4 floor points; several stations are averaged.

    Refinement: damped Newton steps :math:`(H + \lambda\,\mathrm{diag}(J^\top J))\,\Delta q =
    J^\top r` with :math:`H = J^\top J - \sum_i r_i \nabla^2 h_i` (the exact cost Hessian: plain
    Gauss-Newton converges only linearly here, since the 3 cm photodiode baseline makes yaw weak
    and the residual term large), Gauss-Newton where :math:`H` is not positive definite,
    :math:`\lambda` raised on a cost increase. :math:`r`, :math:`J` and :math:`\nabla^2 h` are
    CasADi derivatives of ``model.output_expressions`` w.r.t. ``x[0:3]``, compiled once. Stops
    when a step is below 1e-10 (at most 30 iterations). ``None`` if it does not converge, the
    model is undefined at the iterate (photodiode outside a light plane), :math:`J^\top J` is
    singular (condition > 1e12) or the rms test fails.
    """

    def __init__(self, model: CarModel, angle_std: float = 2e-3, max_rms_ratio: float = 5.0):
        if not (math.isfinite(angle_std) and angle_std > 0):
            raise FieldError("angle_std", f"must be finite and > 0, got {angle_std!r}")
        if not (math.isfinite(max_rms_ratio) and max_rms_ratio > 0):
            raise FieldError("max_rms_ratio", f"must be finite and > 0, got {max_rms_ratio!r}")
        if model.n_base_stations < 1:
            raise FieldError("model", "has no Lighthouse base station")
        self.model = model
        self.angle_std = float(angle_std)
        self.max_rms_ratio = float(max_rms_ratio)
        n = model.n_base_stations
        params = model.parameters
        self._p = params.vector()
        self._x = np.zeros(model.nx)
        self._u = np.zeros(model.nu)
        self._body = np.array(
            [[params.value(f"lh_d{k}_{a}") for a in "xy"] for k in range(N_PHOTODIODES)]
        )
        self._stations = [base_station_from_parameters(params, i) for i in range(n)]
        pose, measured = model.x_sym[0:3], ca.SX.sym("m", 2 * N_PHOTODIODES)
        weights = ca.SX.sym("w", 2 * N_PHOTODIODES)
        functions = []
        for s in range(n):
            y = ca.vertcat(*[model.output_expressions[lighthouse_sensor(s, pl)] for pl in (1, 2)])
            residual = ca.atan2(ca.sin(measured - y), ca.cos(measured - y))  # wrapped
            curvature = ca.hessian(ca.dot(weights, y), pose)[0]  # sum_i w_i d2 h_i / dq2
            functions.append(
                ca.Function(
                    f"lh_pose_h{s}",
                    [model.x_sym, model.u_sym, model.p_sym, measured],
                    [
                        residual,
                        ca.densify(ca.jacobian(y, pose)),
                        ca.densify(ca.substitute(curvature, weights, residual)),
                    ],
                    ["x", "u", "p", "measured"],
                    ["residual", "J", "Hr"],
                    SX_OPTIONS,
                )
            )
        tag = "_".join(e.name for e in model.effects) or "base"
        compiled = compile_functions(functions, f"lh_pose_{tag}_{n}bs")
        self._h = [compiled[f"lh_pose_h{s}"] for s in range(n)]

    def solve(
        self,
        sweeps: Mapping[str, np.ndarray],
        stamp: float = 0.0,
        guess: np.ndarray | None = None,
    ) -> PoseFix | None:
        """Pose fix from sweep angles.

        Parameters
        ----------
        sweeps : mapping of str to array
            ``lighthouse/<station>/<plane>`` -> 4 angles (rad). Stations with only one plane
            are ignored.
        stamp : float
            Copied into the fix, s.
        guess : array, optional
            ``(x, y, yaw)`` start (m, m, rad) instead of the closed-form inversion.

        Returns
        -------
        PoseFix or None
            ``None`` when no station has both planes or the solution is not credible.

        Raises
        ------
        ValueError
            A key that is not a Lighthouse sensor of the model, or values that are not 4 finite
            numbers (the message names the sensor); a malformed ``guess``.
        """
        angles: dict[tuple[int, int], np.ndarray] = {}
        for sensor, values in sweeps.items():
            parsed = parse_lighthouse(sensor) if isinstance(sensor, str) else None
            if parsed is None or parsed[0] >= self.model.n_base_stations:
                raise FieldError(
                    "sweeps",
                    f"{sensor!r} is not a Lighthouse sensor of this model "
                    f"({self.model.n_base_stations} station(s): lighthouse/<0..n-1>/<1|2>)",
                )
            array = np.asarray(values, dtype=float)
            if array.shape != (N_PHOTODIODES,) or not np.all(np.isfinite(array)):
                raise FieldError("sweeps", f"{sensor} needs 4 finite angles, got {values!r}")
            angles[parsed] = array
        stations = tuple(sorted(s for s, pl in angles if pl == 1 and (s, 2) in angles))
        if not stations:
            return None
        measured = [np.concatenate([angles[s, 1], angles[s, 2]]) for s in stations]
        if guess is None:
            start = self._closed_form(angles, stations)
        else:
            start = np.asarray(guess, dtype=float)
            if start.shape != (3,) or not np.all(np.isfinite(start)):
                raise FieldError("guess", f"needs (x, y, yaw) as 3 finite numbers, got {guess!r}")
        if start is None:
            return None
        return self._refine(start.copy(), measured, float(stamp), stations)

    def _evaluate(self, pose: np.ndarray, measured: list[np.ndarray], stations):
        """Wrapped residuals r, Jacobian J, cost r'r and ``sum_i r_i d2h_i/dq2`` at ``pose``."""
        self._x[0:3] = pose
        parts = [self._h[s](self._x, self._u, self._p, measured[i]) for i, s in enumerate(stations)]
        residual = np.concatenate([r for r, _, _ in parts])
        jacobian = np.vstack([j for _, j, _ in parts])
        return residual, jacobian, float(residual @ residual), sum(h for _, _, h in parts)

    def _refine(self, pose, measured, stamp, stations) -> PoseFix | None:
        residual, jacobian, cost, curvature = self._evaluate(pose, measured, stations)
        damping, converged = 0.0, False
        for _ in range(_MAX_ITERATIONS):
            if not (math.isfinite(cost) and np.all(np.isfinite(jacobian + curvature[0]))):
                return None
            normal = jacobian.T @ jacobian
            scale = damping * np.diag(np.diag(normal))
            gradient = jacobian.T @ residual  # minus the cost gradient
            try:  # Newton: H = J'J - sum r_i d2h_i; Gauss-Newton where H is not positive
                step = _cho_solve(normal - curvature + scale, gradient)
            except np.linalg.LinAlgError:
                try:
                    step = _cho_solve(normal + scale, gradient)
                except np.linalg.LinAlgError:
                    return None
            candidate = pose + step
            new = self._evaluate(candidate, measured, stations)
            if math.isfinite(new[2]) and new[2] <= cost:
                pose, (residual, jacobian, cost, curvature) = candidate, new
                damping *= 0.1
            else:
                damping = max(10.0 * damping, 1e-3)
            if np.linalg.norm(step) < _STEP_TOLERANCE:
                converged = True
                break
        if not converged or not np.all(np.isfinite(jacobian)):
            return None
        normal = jacobian.T @ jacobian
        if np.linalg.cond(normal) > 1e12:
            return None
        rms = math.sqrt(cost / residual.size)
        if rms > self.max_rms_ratio * self.angle_std:
            return None
        covariance = self.angle_std**2 * np.linalg.inv(normal)
        pose = np.array([pose[0], pose[1], wrap_angle(pose[2])])
        return PoseFix(stamp, pose, 0.5 * (covariance + covariance.T), rms, stations)

    def _closed_form(self, angles, stations) -> np.ndarray | None:
        """Mean of the per-station ray-inversion + Procrustes poses; ``None`` if a ray misses."""
        poses = []
        for s in stations:
            station = self._stations[s]
            a = math.tan(-math.pi / 6 - station.dt1)
            b = math.tan(math.pi / 6 - station.dt2)
            a1, a2 = angles[s, 1], angles[s, 2]
            theta = np.arctan2(b * np.sin(a1) - a * np.sin(a2), b * np.cos(a1) - a * np.cos(a2))
            theta = np.where(np.abs(wrap_angle(a1 - theta)) < math.pi / 2, theta, theta + math.pi)
            zeta = np.sin(a1 - theta) / a
            rays = station.rotation @ np.vstack([np.cos(theta), np.sin(theta), zeta])
            origin = np.asarray(station.position)
            with np.errstate(divide="ignore", invalid="ignore"):
                reach = -origin[2] / rays[2]
            if not np.all(np.isfinite(reach) & (reach > 0)):
                return None
            floor = (origin[:2, None] + reach * rays[:2]).T  # (4, 2) world points
            poses.append(_rigid_fit(self._body, floor))
        mean = np.mean(poses, axis=0)
        mean[2] = math.atan2(
            np.mean(np.sin([p[2] for p in poses])), np.mean(np.cos([p[2] for p in poses]))
        )
        return mean


def _cho_solve(matrix: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve with a symmetric positive definite ``matrix``; ``LinAlgError`` if it is not."""
    lower = np.linalg.cholesky(matrix)
    return np.linalg.solve(lower.T, np.linalg.solve(lower, rhs))


def _rigid_fit(body: np.ndarray, world: np.ndarray) -> np.ndarray:
    r"""``(x, y, yaw)`` minimising :math:`\sum_k \|R(\psi) b_k + t - w_k\|^2` (2-D Procrustes)."""
    bc, wc = body - body.mean(axis=0), world - world.mean(axis=0)
    yaw = math.atan2(
        float(np.sum(bc[:, 0] * wc[:, 1] - bc[:, 1] * wc[:, 0])), float(np.sum(bc * wc))
    )
    c, s = math.cos(yaw), math.sin(yaw)
    t = world.mean(axis=0) - np.array([[c, -s], [s, c]]) @ body.mean(axis=0)
    return np.array([t[0], t[1], yaw])


class SweepPairer:
    """Pairs the two light planes of each base station from a measurement stream.

    Keeps the latest sweep of every ``lighthouse/<station>/<plane>`` sensor. When a sweep arrives
    and the latest sweep of the other plane of its station is within ``max_gap`` s (absolute
    stamp difference) and not used yet, :meth:`add` returns ``(stamp, sweeps)``: ``sweeps`` maps
    the two sensor names to their angles (rad) and ``stamp`` is the mean of the two stamps (s).
    Each sweep is used at most once. A pair is returned as soon as it is complete, so every other
    station's complete pair has already been returned: a result holds one station. For a
    multi-station fix, merge the ``sweeps`` of results whose stamps are close.

    Parameters
    ----------
    max_gap : float
        Largest stamp difference between paired planes, s.
    """

    def __init__(self, max_gap: float = 0.03) -> None:
        if not (math.isfinite(max_gap) and max_gap >= 0):
            raise FieldError("max_gap", f"must be finite and >= 0, got {max_gap!r}")
        self.max_gap = float(max_gap)
        self._latest: dict[tuple[int, int], tuple[float, np.ndarray, bool]] = {}

    def add(self, measurement: Measurement) -> tuple[float, dict[str, np.ndarray]] | None:
        """Take one measurement; ``(stamp, sweeps)`` when it completes a pair, else ``None``.

        Non-Lighthouse measurements are ignored (``None``).
        """
        key = parse_lighthouse(measurement.sensor)
        if key is None:
            return None
        stamp, other = measurement.stamp, (key[0], 3 - key[1])
        self._latest[key] = (stamp, measurement.values, False)
        partner = self._latest.get(other)
        if partner is None or partner[2] or abs(partner[0] - stamp) > self.max_gap:
            return None
        self._latest[key] = (stamp, measurement.values, True)
        self._latest[other] = (partner[0], partner[1], True)
        first, second = sorted([(key, measurement.values), (other, partner[1])], key=lambda e: e[0])
        sweeps = {lighthouse_sensor(*first[0]): first[1], lighthouse_sensor(*second[0]): second[1]}
        return 0.5 * (stamp + partner[0]), sweeps

    def clear(self) -> None:
        """Forget every stored sweep."""
        self._latest.clear()


class LighthouseFixes:
    """Pose fixes from a measurement stream: each station's sweep pair (:class:`SweepPairer`)
    solved by a :class:`LighthousePoseSolver` from the closed-form start (no local minima).

    Parameters
    ----------
    solver : LighthousePoseSolver
    max_pair_gap : float
        Largest stamp difference between paired planes, s.
    min_interval : float
        Fewest seconds between two solved fixes of one station (by stamp); a pair that comes
        sooner is not solved (0: every pair). A viewer needs a few fixes a second, not the
        sweep rate.
    """

    def __init__(
        self, solver: LighthousePoseSolver, max_pair_gap: float = 0.03, min_interval: float = 0.0
    ) -> None:
        if not (math.isfinite(min_interval) and min_interval >= 0):
            raise FieldError("min_interval", f"must be finite and >= 0, got {min_interval!r}")
        self.solver = solver
        self.min_interval = float(min_interval)
        self._pairer = SweepPairer(max_pair_gap)
        self._solved: dict[str, float] = {}  # the first sensor of a pair -> its last fix stamp

    def add(self, measurement: Measurement) -> PoseFix | None:
        """Take one measurement; the fix of the pair it completes (``None``: no pair, a pair
        within ``min_interval`` of the last fix, or no credible solution)."""
        paired = self._pairer.add(measurement)
        if paired is None:
            return None
        stamp, sweeps = paired
        station = next(iter(sweeps))
        last = self._solved.get(station)
        if last is not None and abs(stamp - last) < self.min_interval:
            return None
        self._solved[station] = stamp
        return self.solver.solve(sweeps, stamp)

    def clear(self) -> None:
        """Forget every stored sweep and fix stamp."""
        self._pairer.clear()
        self._solved.clear()
