"""Statistics of a residual series: whiteness (Ljung-Box), regression on regressors, regime bins,
offset z. The generic tests behind :func:`crs_core.discrepancy.residuals.diagnose_residual`:
:func:`ljung_box` (on the sample autocorrelations of :func:`autocorrelation`),
:func:`regime_regression` (:math:`R^2` and F-test on standardised regressors), :func:`strongest`
(the regressor most correlated with the series), :func:`worst_regime` (the quartile bin with the
largest residual RMS) and :func:`mean_z` (the mean in standard errors of an autocorrelated series).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy import stats

#: Most lags of the Ljung-Box test (fewer on short series: ``min(MAX_LAGS, n // 5)``).
MAX_LAGS = 20


def ljung_box(x: np.ndarray, lags: int | None = None) -> float:
    r"""Ljung-Box p-value of a series being white.

    .. math:: Q = n (n + 2) \sum_{k=1}^{L} \frac{r_k^2}{n - k} \sim \chi^2_L

    Parameters
    ----------
    x : (n,) array
        The series (finite values, in time order).
    lags : int, optional
        :math:`L`; default ``min(MAX_LAGS, n // 5)``.

    Returns
    -------
    float
        The p-value (1 for a series too short or constant).
    """
    x = np.asarray(x, dtype=float)
    n = len(x)
    lags = min(MAX_LAGS, n // 5) if lags is None else lags
    if lags < 1 or n <= lags + 1:
        return 1.0
    r = autocorrelation(x, lags)
    q = n * (n + 2) * np.sum(r**2 / (n - np.arange(1, lags + 1)))
    return float(stats.chi2.sf(q, lags))


def regime_regression(e: np.ndarray, design: np.ndarray) -> tuple[float, float]:
    r""":math:`R^2` and F-test p-value of regressing ``e`` on the columns of ``design``.

    The regressors are standardised (constant columns dropped) and an intercept is added;
    with :math:`p` regressors (rank) and :math:`n` samples,
    :math:`F = \frac{R^2 / p}{(1 - R^2) / (n - p - 1)} \sim F_{p, n-p-1}`.

    Parameters
    ----------
    e : (n,) array
        Residual.
    design : (n, m) array
        Regressors.

    Returns
    -------
    r2, p : float
        0 and 1 when nothing can be fitted.
    """
    e = np.asarray(e, dtype=float)
    z = _standardised(np.asarray(design, dtype=float))
    n = len(e)
    sst = float(np.sum((e - e.mean()) ** 2))
    if z.shape[1] == 0 or sst <= 0.0:
        return 0.0, 1.0
    a = np.column_stack([np.ones(n), z])
    coef, _, rank, _ = np.linalg.lstsq(a, e, rcond=None)
    p = int(rank) - 1
    dof = n - p - 1
    if p < 1 or dof < 1:
        return 0.0, 1.0
    ssr = float(np.sum((e - a @ coef) ** 2))
    r2 = min(max(1.0 - ssr / sst, 0.0), 1.0)
    if r2 >= 1.0:
        return 1.0, 0.0
    f = (r2 / p) / ((1.0 - r2) / dof)
    return r2, float(stats.f.sf(f, p, dof))


def worst_regime(residual: np.ndarray, regressor: np.ndarray, name: str) -> dict[str, Any]:
    """The quartile bin of a regressor where the residual RMS is largest.

    Parameters
    ----------
    residual : (n,) or (n, k) array
        Residual per sample (NaN: not measured), channel units.
    regressor : (n,) array
        The regressor's values at the same samples.
    name : str

    Returns
    -------
    dict
        ``{"regressor": name, "low", "high"}`` (the bin's edges, regressor units), ``"rms"``
        (residual RMS over the bin's measured values, channel units) and ``"share"`` (the
        bin's share of the samples).
    """
    e = np.asarray(residual, dtype=float)
    e = e[:, None] if e.ndim == 1 else e
    x = np.asarray(regressor, dtype=float)
    edges = np.quantile(x, [0.0, 0.25, 0.5, 0.75, 1.0])
    best = no_regime(name)
    for i in range(4):
        low, high = edges[i], edges[i + 1]
        inside = (x >= low) & ((x < high) if i < 3 else (x <= high))
        values = e[inside][np.isfinite(e[inside])]
        if not values.size:
            continue
        rms = float(np.sqrt(np.mean(values**2)))
        if rms > best["rms"]:
            best = {
                "regressor": name,
                "low": float(low),
                "high": float(high),
                "rms": rms,
                "share": float(inside.mean()),
            }
    return best


def mean_z(x: np.ndarray) -> float:
    r"""``|mean|`` in standard errors, :math:`n_{eff} = n (1 - \rho_1) / (1 + \rho_1)`."""
    n = len(x)
    std = float(np.std(x, ddof=1))
    mean = float(np.mean(x))
    if std <= 0.0:
        return float("inf") if mean != 0.0 else 0.0
    rho = min(max(float(autocorrelation(x, 1)[0]), 0.0), 0.999)
    n_eff = max(n * (1.0 - rho) / (1.0 + rho), 1.0)
    return abs(mean) / (std / np.sqrt(n_eff))


def strongest(e: np.ndarray, design: np.ndarray, names: list[str]) -> str:
    """The regressor with the largest absolute correlation with ``e`` (first on ties)."""
    best, best_r = names[0], -1.0
    for j, name in enumerate(names):
        r = abs(correlation(design[:, j], e))
        if r > best_r:
            best, best_r = name, r
    return best


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two series (0 when either is constant)."""
    ac, bc = a - a.mean(), b - b.mean()
    scale = float(np.sqrt(np.sum(ac**2) * np.sum(bc**2)))
    return float(np.sum(ac * bc)) / scale if scale > 0 else 0.0


def autocorrelation(x: np.ndarray, lags: int) -> np.ndarray:
    """Sample autocorrelations :math:`r_1..r_L` of a finite series (0 where undefined)."""
    x = np.asarray(x, dtype=float)
    n = len(x)
    d = x - x.mean() if n else x
    denominator = float(np.sum(d**2))
    r = np.zeros(lags)
    if n < 2 or denominator <= 0.0:
        return r
    for k in range(1, min(lags, n - 1) + 1):
        r[k - 1] = float(np.sum(d[:-k] * d[k:])) / denominator
    return r


def no_regime(name: str) -> dict[str, Any]:
    """The empty regime bin of :func:`worst_regime` (no bin found yet, or too few samples)."""
    return {"regressor": name, "low": 0.0, "high": 0.0, "rms": 0.0, "share": 0.0}


def _standardised(design: np.ndarray) -> np.ndarray:
    """Columns scaled to zero mean and unit deviation; (near-)constant columns dropped."""
    if design.size == 0:
        return design.reshape(len(design), 0)
    std = design.std(axis=0)
    scale = np.maximum(np.abs(design).max(axis=0), 1e-300)
    keep = std > 1e-9 * scale
    return (design[:, keep] - design[:, keep].mean(axis=0)) / std[keep]
