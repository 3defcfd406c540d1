r"""The least-squares engine shared by static and moving calibration.

Unknowns: per base station its pose in the gimbal-free chart of
:mod:`crs_core.calibration.sweep_model` (3 rotation increments, position; the tilt offsets
``dt1, dt2`` too when fitted, chosen per station), optionally the photodiode positions
(shared by all stations), and problem-specific extras that move the car poses (static: unknown
yaws per point; moving: the clock offset). Residuals: every photodiode's wrapped sweep angle
of every observation :math:`r = \operatorname{wrap}(\alpha - h(q, \theta))`, rad. The Jacobian
is exact: CasADi derivatives of the model's sweep-angle expressions, chained through
``dq/d(extra)``.

Solved with ``scipy.optimize.least_squares`` (trust-region reflective, ``x_scale="jac"``),
linear loss for averaged static angles, ``soft_l1`` for raw moving sweeps. An angle the model
cannot produce at an iterate counts as :data:`UNREACHABLE`; at the solution it is left NaN in
:attr:`FitResult.residuals` (and out of the standard deviations) for the caller to refuse.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from crs_core.analysis.angles import wrap_angle
from crs_core.calibration.sweep_model import (
    N_DIODES,
    N_STATION,
    SweepModel,
    station_from_chart,
)
from crs_core.errors import FieldError
from crs_core.model.lighthouse import BaseStation

#: The residual of an angle the model cannot produce at an iterate (a photodiode outside a light
#: plane: the arcsine's argument beyond 1), rad; its Jacobian row is 0. Only those entries, so
#: an iterate that pushes a few sweeps near the edge of a plane's reach out of it is not a
#: cliff for the whole problem.
UNREACHABLE = 0.5 * np.pi
#: ``poses(extra) -> (poses (K, 3), d poses / d extra (K, 3, n_extra))``.
PoseFunction = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Observations:
    """Sweeps to explain: observation ``k`` is one light plane of one station.

    Attributes
    ----------
    station : (K,) station index.
    plane : (K,) 1 or 2.
    angles : (K, 4) photodiode angles, rad.
    """

    station: np.ndarray
    plane: np.ndarray
    angles: np.ndarray

    def __len__(self) -> int:
        return len(self.station)


@dataclass(frozen=True)
class FitResult:
    r"""Fitted geometry and what the fit left.

    Attributes
    ----------
    stations : fitted base stations.
    photodiodes : photodiodes 0..3 (x, y) in the body frame, m (fitted or as given).
    extra : the problem-specific unknowns at the solution.
    residuals : (K, 4) wrapped angle residuals measured - model, rad.
    station_std : (S, 8) one-sigma of ``delta1..3`` (rad), x, y, z (m), dt1, dt2 (rad) from
        :math:`\hat\sigma^2 (J^\top J)^{-1}` (0 for parameters held fixed).
    extra_std : one-sigma of ``extra``.
    diode_std : (8,) one-sigma of the photodiode coordinates, m (0 if not fitted).
    iterations : function evaluations used.
    tilt_fitted : per station, whether its tilt offsets were fitted (else held as given).
    """

    stations: tuple[BaseStation, ...]
    photodiodes: tuple[tuple[float, float], ...]
    extra: np.ndarray
    residuals: np.ndarray
    station_std: np.ndarray
    extra_std: np.ndarray
    diode_std: np.ndarray
    iterations: int
    tilt_fitted: tuple[bool, ...]

    def require_converged(self, field: str, sweeps: str, advice: str) -> None:
        """Refuse a fit whose stations cannot produce some of the sweeps (non-finite residuals:
        a photodiode outside a light plane at the solution): :class:`FieldError` naming
        ``field``, counting the ``sweeps`` (what they are) and ending with ``advice``."""
        unexplained = int(np.sum(~np.all(np.isfinite(self.residuals), axis=1)))
        if unexplained:
            raise FieldError(
                field,
                f"the fit did not converge: its stations cannot produce {unexplained} of "
                f"{len(self.residuals)} {sweeps} (a photodiode outside a light plane); {advice}",
            )


class LighthouseFit:
    """Builds and solves one calibration least-squares problem (module docstring).

    ``fit_tilt`` frees the tilt offsets of every station (True), of none (False), or per
    station (one bool each); tilts not fitted stay at the start stations' values.
    """

    def __init__(
        self,
        observations: Observations,
        start: Sequence[BaseStation],
        photodiodes: Sequence[tuple[float, float]],
        poses: PoseFunction,
        n_extra: int,
        fit_tilt: bool | Sequence[bool] = False,
        fit_photodiodes: bool = False,
        sweep_model: SweepModel | None = None,
    ) -> None:
        self.obs = observations
        self.model = sweep_model or SweepModel()
        self.rotations0 = [np.asarray(s.rotation) for s in start]
        self.theta0 = np.array(
            [[0.0, 0.0, 0.0, *s.position, s.dt1, s.dt2] for s in start], dtype=float
        )
        self.diodes0 = np.asarray(photodiodes, dtype=float).reshape(-1)
        self.poses = poses
        self.n_extra = n_extra
        self.fit_photodiodes = fit_photodiodes
        self.n_stations = len(start)
        if isinstance(fit_tilt, bool):
            fit_tilt = [fit_tilt] * self.n_stations
        self.tilt_fitted = tuple(bool(f) for f in fit_tilt)
        if len(self.tilt_fitted) != self.n_stations:
            raise ValueError("fit_tilt needs one flag per start station")
        #: per station, the chart parameters it fits, and where they start in the unknowns
        self.free = [list(range(N_STATION if f else 6)) for f in self.tilt_fitted]
        self._first = np.concatenate([[0], np.cumsum([len(f) for f in self.free])]).astype(int)
        self._index = [np.flatnonzero(observations.station == s) for s in range(self.n_stations)]
        self.n_station_vars = int(self._first[-1])
        self.n_vars = self.n_station_vars + (N_DIODES if fit_photodiodes else 0) + n_extra

    def _unpack(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        theta = self.theta0.copy()
        for s in range(self.n_stations):
            theta[s, self.free[s]] = z[self._first[s] : self._first[s + 1]]
        offset = self.n_station_vars
        diodes = self.diodes0.copy()
        if self.fit_photodiodes:
            diodes = z[offset : offset + N_DIODES]
            offset += N_DIODES
        return theta, diodes, z[offset:]

    def start_vector(self, extra0: np.ndarray) -> np.ndarray:
        parts = [self.theta0[s, self.free[s]] for s in range(self.n_stations)]
        if self.fit_photodiodes:
            parts.append(self.diodes0)
        parts.append(np.asarray(extra0, dtype=float).reshape(-1))
        return np.concatenate(parts)

    def evaluate(self, z: np.ndarray, jacobian: bool = True):
        """Residuals ``(4K,)`` (and Jacobian ``(4K, n_vars)``) at ``z``."""
        theta, diodes, extra = self._unpack(z)
        poses, dposes = self.poses(extra)
        k_total = len(self.obs)
        residuals = np.zeros((k_total, 4))
        jac = np.zeros((k_total, 4, self.n_vars)) if jacobian else None
        for s, rows in enumerate(self._index):
            if rows.size == 0:
                continue
            # plane 1 -> model rows 0..3, plane 2 -> rows 4..7
            pick = (self.obs.plane[rows] - 1)[:, None] * 4 + np.arange(4)[None, :]
            sel = np.arange(rows.size)[:, None]
            if jac is None:
                y = self.model.angles(poses[rows], theta[s], self.rotations0[s], diodes)
                residuals[rows] = wrap_angle(self.obs.angles[rows] - y[sel, pick])
                continue
            y, jq, jt, jd = self.model.evaluate(poses[rows], theta[s], self.rotations0[s], diodes)
            residuals[rows] = wrap_angle(self.obs.angles[rows] - y[sel, pick])
            jac[rows, :, self._first[s] : self._first[s + 1]] = -jt[sel, pick][:, :, self.free[s]]
            offset = self.n_station_vars
            if self.fit_photodiodes:
                jac[rows, :, offset : offset + N_DIODES] = -jd[sel, pick]
                offset += N_DIODES
            if self.n_extra:
                jac[rows, :, offset:] = -np.einsum("kij,kjn->kin", jq[sel, pick], dposes[rows])
        if jac is None:
            return residuals.reshape(-1)
        return residuals.reshape(-1), jac.reshape(4 * k_total, self.n_vars)

    def solve(
        self,
        extra0: np.ndarray,
        loss: str = "linear",
        f_scale: float = 1.0,
        max_nfev: int = 200,
        bounds: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> FitResult:
        """Least squares from the start stations and ``extra0``."""
        z0 = self.start_vector(extra0)
        cache: dict[str, object] = {}

        def fun(z):
            r, j = self.evaluate(z)
            unreachable = ~np.isfinite(r)
            j[unreachable] = 0.0
            cache["z"], cache["j"] = z.copy(), j
            return np.where(unreachable, UNREACHABLE, r)

        def jac(z):
            if "z" not in cache or not np.array_equal(cache["z"], z):
                fun(z)
            j = cache["j"]
            return np.where(np.isfinite(j), j, 0.0)

        lower = np.full(self.n_vars, -np.inf)
        upper = np.full(self.n_vars, np.inf)
        if bounds is not None:
            lower[-self.n_extra :], upper[-self.n_extra :] = bounds
            z0[-self.n_extra :] = np.clip(
                z0[-self.n_extra :], lower[-self.n_extra :] + 1e-12, upper[-self.n_extra :] - 1e-12
            )
        solution = least_squares(
            fun,
            z0,
            jac=jac,
            method="trf",
            x_scale="jac",
            loss=loss,
            f_scale=f_scale,
            bounds=(lower, upper),
            max_nfev=max_nfev,
            xtol=1e-12,
            ftol=1e-12,
            gtol=1e-12,
        )
        z = solution.x
        residual, jacobian = self.evaluate(z)
        theta, diodes, extra = self._unpack(z)
        stations = tuple(
            station_from_chart(theta[s], self.rotations0[s]) for s in range(self.n_stations)
        )
        std = _standard_deviations(residual, jacobian)
        station_std = np.zeros((self.n_stations, N_STATION))
        for s in range(self.n_stations):
            station_std[s, self.free[s]] = std[self._first[s] : self._first[s + 1]]
        offset = self.n_station_vars
        diode_std = np.zeros(N_DIODES)
        if self.fit_photodiodes:
            diode_std = std[offset : offset + N_DIODES]
            offset += N_DIODES
        return FitResult(
            stations=stations,
            photodiodes=tuple((float(diodes[2 * k]), float(diodes[2 * k + 1])) for k in range(4)),
            extra=np.asarray(extra, dtype=float).copy(),
            residuals=residual.reshape(-1, 4),
            station_std=station_std,
            extra_std=std[offset:],
            diode_std=diode_std,
            iterations=int(solution.nfev),
            tilt_fitted=self.tilt_fitted,
        )


def _standard_deviations(residual: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
    r"""One-sigma of each unknown, :math:`\sqrt{\operatorname{diag}(\hat\sigma^2 (J^\top J)^+)}`,
    from the residuals the model can produce (a non-finite one, a photodiode outside a light
    plane at an unconverged solution, is left out)."""
    finite = np.isfinite(residual) & np.all(np.isfinite(jacobian), axis=1)
    residual, jacobian = residual[finite], jacobian[finite]
    m, n = jacobian.shape
    dof = max(m - n, 1)
    sigma2 = float(residual @ residual) / dof
    normal = jacobian.T @ jacobian
    covariance = np.linalg.pinv(normal, rcond=1e-12) * sigma2
    return np.sqrt(np.clip(np.diag(covariance), 0.0, None))
