r"""Parameter covariance of the FIE from the curvature at the optimum (Laplace / Gauss-Newton).

With residuals ``r(z)`` whitened by their standard deviations and ``z = [theta_s, x]``
(``theta = theta_bar + prior_std * theta_s``), the Gauss-Newton Hessian of ``0.5 r'r`` is
``H = J'J``. The covariance of ``z`` is ``H^{-1}``; its parameter block is the inverse of the
reduced Hessian (the Schur complement, states and process noise eliminated)

.. math:: H_\theta = H_{\theta\theta} - H_{\theta x} H_{xx}^{-1} H_{x\theta},

computed with a sparse LU of the block-banded ``H_xx``. In these scaled coordinates the prior
contributes exactly the identity, so ``H_theta - I`` is the information the data add.

A parameter is flagged **not identifiable** when

* the data barely inform it (**flat**): its posterior standard deviation is more than
  :data:`FLAT_FRACTION` of its prior one, or its relative standard deviation exceeds
  :data:`MAX_RELATIVE_STD`;
* it sits on a bound (**bound active**): the Laplace approximation does not hold there;
* it is **strongly correlated** (:math:`|\rho| >` :data:`MAX_CORRELATION`) with another fitted
  parameter: only a combination of the two is determined.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

#: Posterior / prior standard deviation above which the data are said not to inform a parameter.
FLAT_FRACTION = 0.7
#: Relative standard deviation (std / |value|) above which a parameter is not identified.
MAX_RELATIVE_STD = 0.5
#: Correlation magnitude above which two parameters are not separately identifiable.
MAX_CORRELATION = 0.95


@dataclass(frozen=True)
class ParameterUncertainty:
    """Covariance of the fitted parameters and the identifiability verdict.

    Attributes
    ----------
    names : tuple of str
    covariance : (n, n) in the parameters' units
    std : (n,)
    correlation : (n, n)
    information_eigenvalues : (n,) eigenvalues of the data's information in prior-scaled
        coordinates (0: the data say nothing along that direction; 1: as much as the prior)
    identifiable : (n,) bool
    reasons : tuple of str, why a parameter is not identifiable ("" when it is)
    """

    names: tuple[str, ...]
    covariance: np.ndarray
    std: np.ndarray
    correlation: np.ndarray
    information_eigenvalues: np.ndarray
    identifiable: np.ndarray
    reasons: tuple[str, ...]

    def warnings(self) -> list[str]:
        """One line per unidentifiable parameter, naming it and the reason."""
        return [
            f"parameter {name!r} is not identifiable: {reason}"
            for name, ok, reason in zip(self.names, self.identifiable, self.reasons, strict=True)
            if not ok
        ]


def reduced_hessian(jacobian: sp.spmatrix, n_theta: int) -> np.ndarray:
    """Schur complement of ``J'J`` on its first ``n_theta`` variables (dense ``(n, n)``)."""
    jac = sp.csc_matrix(jacobian)
    h = (jac.T @ jac).tocsc()
    h_tt = h[:n_theta, :n_theta].toarray()
    h_tx = h[:n_theta, n_theta:].toarray()
    h_xx = h[n_theta:, n_theta:].tocsc()
    if h_xx.shape[0] == 0:
        return h_tt
    lu = spla.splu(h_xx)
    return h_tt - h_tx @ lu.solve(np.ascontiguousarray(h_tx.T))


def parameter_uncertainty(
    jacobian: sp.spmatrix,
    names: Sequence[str],
    theta: np.ndarray,
    prior_std: np.ndarray,
    at_bound: np.ndarray | None = None,
) -> ParameterUncertainty:
    """Covariance, correlation and identifiability flags of the fitted parameters.

    ``jacobian`` is ``dr/dz`` at the optimum with the parameters first, scaled by
    ``prior_std`` (so the prior rows are the identity).
    """
    n = len(names)
    reduced = reduced_hessian(jacobian, n)
    reduced = 0.5 * (reduced + reduced.T)
    covariance_scaled = np.linalg.pinv(reduced, hermitian=True)
    scale = np.asarray(prior_std, dtype=float)
    covariance = covariance_scaled * np.outer(scale, scale)
    std = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        correlation = covariance / np.outer(std, std)
    correlation = np.nan_to_num(correlation)
    information = np.linalg.eigvalsh(reduced - np.eye(n))
    at_bound = np.zeros(n, dtype=bool) if at_bound is None else np.asarray(at_bound, dtype=bool)
    theta = np.asarray(theta, dtype=float)
    reasons = []
    for i in range(n):
        why = []
        fraction = std[i] / scale[i]
        if fraction > FLAT_FRACTION:
            why.append(
                f"flat direction (the data barely inform it: sigma is {fraction:.0%} of the "
                "prior's)"
            )
        relative = std[i] / abs(theta[i]) if theta[i] != 0 else np.inf
        if relative > MAX_RELATIVE_STD:
            why.append(f"relative std {relative:.0%}")
        if at_bound[i]:
            why.append("bound active")
        partners = [
            f"{names[j]} (rho {correlation[i, j]:+.2f})"
            for j in range(n)
            if j != i and abs(correlation[i, j]) > MAX_CORRELATION
        ]
        if partners:
            why.append("strongly correlated with " + ", ".join(partners))
        reasons.append("; ".join(why))
    return ParameterUncertainty(
        names=tuple(names),
        covariance=covariance,
        std=std,
        correlation=correlation,
        information_eigenvalues=information,
        identifiable=np.array([not r for r in reasons]),
        reasons=tuple(reasons),
    )
