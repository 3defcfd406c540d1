r"""What a drive tells about the parameters: the FIE's posterior covariance, predicted.

The FIE (:mod:`crs_core.identification.problem`) fits the parameters :math:`\theta` and the
state trajectory to a recording with process noise :math:`Q_k` and measurement noise :math:`R`;
its Laplace covariance (:mod:`crs_core.identification.uncertainty`) is the inverse of the
Gauss-Newton Hessian with the states eliminated. Linearised along a trajectory that is the same
as the covariance of the constant :math:`\theta` in a Kalman filter over the augmented state
:math:`[x;\theta]` run through the whole recording (for a linear-Gaussian system the filter's
last marginal of a constant is the batch posterior), which needs no problem to be built:

.. math:: A_k = \begin{bmatrix} \partial F/\partial x & \partial F/\partial \theta \\
          0 & I \end{bmatrix},\quad
          C_k = \begin{bmatrix} \partial h/\partial x & \partial h/\partial \theta \end{bmatrix},

with ``F`` the model's RK4 step and ``h`` its outputs in the FIE's layout
(:data:`~crs_core.identification.data.Y_LAYOUT`), their Jacobians by CasADi from the one model
definition (:func:`~crs_core.identification.jacobian.block_jacobian`), and the FIE's own weights:
:math:`Q_k` from the estimator's process noise times the process scale, :math:`R` from its sensor
noise, the first state's prior :data:`~crs_core.identification.problem.X0_STD`. Starting from a
prior covariance of :math:`\theta` (the model's prior, or what a race already gave), the filter
ends at the covariance after the drive: :func:`posterior_covariance`. A drive read by
:func:`drive_samples` is sampled like a recording (every channel at each Lighthouse stamp; the
Lighthouse only where the base station sees the car).

Units: states and inputs as the model's (SI, rad); covariances in the parameters' units.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from crs_core.estimation.noise import EstimatorNoise
from crs_core.identification.data import Y_LAYOUT
from crs_core.identification.jacobian import block_jacobian
from crs_core.identification.problem import X0_STD, substeps_for
from crs_core.model import CarModel

#: Sweep angles beyond this (rad) are outside the base station's view (the simulator's and the
#: host's limit, ``sim.simulator.LIGHTHOUSE_VIEW_LIMIT``; a test keeps the two equal).
LIGHTHOUSE_VIEW_LIMIT = 1.5
#: Standard deviation of the first state's prior for effect states (as the FIE's).
EFFECT_X0_STD = 0.05


@dataclass(frozen=True)
class DriveSamples:
    """A drive as the FIE would see it: states, commands and which channels are measured.

    Attributes
    ----------
    t : (N,) stamps, s
    x : (N, nx) model states
    u : (N, 2) commands ``[steer (rad), torque (-)]`` held from each stamp to the next
    measured : (N, 13) bool, the dataset columns measured at each stamp
    in_view : (N,) bool, the base station sees every photodiode
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    measured: np.ndarray
    in_view: np.ndarray


class DriveInformation:
    """The model's per-sample Jacobians for :func:`posterior_covariance`, built once.

    Parameters
    ----------
    model : CarModel
        The model (with any open effect already switched on) whose values are the
        linearisation point.
    fit : sequence of str
        The fitted parameters (the FIE's ``fit``), in the order of the covariances.
    sample_period : float
        Interval between samples, s (one RK4 step function for it).
    noise : EstimatorNoise, optional
        Measurement and process noise (the FIE's default).
    process_scale : float
        Factor on the process noise standard deviation (the FIE's ``process_scale``).
    """

    def __init__(
        self,
        model: CarModel,
        fit: Sequence[str],
        sample_period: float,
        noise: EstimatorNoise | None = None,
        process_scale: float = 1.0,
    ) -> None:
        self.model, self.fit = model, tuple(fit)
        self.sample_period = float(sample_period)
        self.noise = noise or EstimatorNoise()
        self.index = np.array([model.parameters.index(n) for n in self.fit])
        step = model.step_function(substeps_for(self.sample_period), "drive_rk4")
        self.step_jacobian = block_jacobian(step)
        outputs = ca.vertcat(*(model.output_expressions[name] for name, _ in Y_LAYOUT))
        h = ca.Function("drive_h", [model.x_sym, model.u_sym, model.p_sym], [outputs])
        self.output_jacobian = block_jacobian(h)
        self.sigma = np.concatenate([self.noise.measurement_std(s) for s, _ in Y_LAYOUT])
        self.q_std = self.noise.process_std_for(model) * process_scale
        self.x0_std = np.concatenate([X0_STD, np.full(model.nx - len(X0_STD), EFFECT_X0_STD)])

    def jacobians(
        self, samples: DriveSamples, p: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(dF/dx, dF/dtheta, dh/dx, dh/dtheta)`` per sample, ``(N, rows, cols)`` each, at the
        parameter vector ``p`` (default the model's)."""
        p = self.model.parameters.vector() if p is None else np.asarray(p, dtype=float)
        n = len(samples.t)
        nx, n_p = self.model.nx, self.model.np
        x, u = samples.x.T, samples.u.T
        dt = np.diff(samples.t, append=samples.t[-1] + self.sample_period)
        pp = np.repeat(p[:, None], n, axis=1)
        fx, fp = self.step_jacobian.map(n)(x, u, pp, dt[None, :])
        hx, hp = self.output_jacobian.map(n)(x, u, pp)
        ny = hx.shape[0]

        def blocks(matrix: ca.DM, rows: int, cols: int) -> np.ndarray:
            return np.asarray(matrix).reshape(rows, n, cols).transpose(1, 0, 2)

        return (
            blocks(fx, nx, nx),
            blocks(fp, nx, n_p)[:, :, self.index],
            blocks(hx, ny, nx),
            blocks(hp, ny, n_p)[:, :, self.index],
        )

    def posterior_covariance(
        self,
        samples: DriveSamples,
        prior: np.ndarray,
        p: np.ndarray | None = None,
    ) -> np.ndarray:
        """The covariance of the fitted parameters after the drive, starting from ``prior``
        (``(n, n)`` in the parameters' units: the model's prior, or a race's posterior), as the
        FIE's Laplace covariance on the drive's recording would be, linearised along
        ``samples`` (``(n, n)``, the parameters' units)."""
        fx, ftheta, hx, htheta = self.jacobians(samples, p)
        nx, n = self.model.nx, len(self.fit)
        prior = np.asarray(prior, dtype=float)
        scale = np.sqrt(np.clip(np.diag(prior), 1e-300, None))  # theta in prior sigmas
        cov = np.zeros((nx + n, nx + n))
        cov[:nx, :nx] = np.diag(self.x0_std**2)
        cov[nx:, nx:] = prior / np.outer(scale, scale)
        dt = np.diff(samples.t, append=samples.t[-1])
        for k in range(len(samples.t)):
            rows = samples.measured[k]
            if rows.any():
                c = np.hstack([hx[k][rows], htheta[k][rows] * scale])
                r = self.sigma[rows] ** 2
                pc = cov @ c.T
                gain = np.linalg.solve(c @ pc + np.diag(r), pc.T).T
                cov = cov - gain @ pc.T
                cov = 0.5 * (cov + cov.T)
            if k + 1 < len(samples.t):
                a = np.eye(nx + n)
                a[:nx, :nx] = fx[k]
                a[:nx, nx:] = ftheta[k] * scale
                cov = a @ cov @ a.T
                cov[:nx, :nx] += np.diag(self.q_std**2 * dt[k])
        return cov[nx:, nx:] * np.outer(scale, scale)


def marginal_covariance(covariance: np.ndarray, fit: Sequence[str], open_names: Sequence[str]):
    """The open parameters' block of a covariance of ``fit`` (the others refitted: the
    marginal, i.e. the inverse of the information's Schur complement)."""
    index = [list(fit).index(n) for n in open_names]
    return np.asarray(covariance)[np.ix_(index, index)]


def log_det(matrix: np.ndarray) -> float:
    """``log det`` of a symmetric positive definite matrix (``inf`` if it is not)."""
    sign, value = np.linalg.slogdet(0.5 * (matrix + matrix.T))
    return float(value) if sign > 0 else float("inf")
