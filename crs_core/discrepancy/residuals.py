"""What identification leaves unexplained: the measurement residuals, channel by channel.

Step 2 of the discrepancy workflow. After the FIE (:func:`~crs_core.identification.identify`)
the residual :math:`e_k = y_k - h(x_k)` of each measured channel should be white noise at the
sensor's noise floor with no dependence on how the car is driven. :func:`diagnose` checks this
for each channel group of :data:`CHANNEL_GROUPS`:

* size: the residual RMS against the assumed sensor sigma (the noise floor, ``1 / weight``);
* whiteness: the lag-1 autocorrelation and a Ljung-Box test;
* offset: the residual mean against its standard error (corrected for autocorrelation);
* regime dependence: a linear regression of the residual on the operating-regime variables of
  :func:`regime_regressors` (speed, steering, yaw rate, acceleration, time into the run), its
  :math:`R^2` and F-test, the regressor the residual follows most, and the quartile of that
  regressor where the residual is largest.

A channel is *structured* (:attr:`ChannelDiagnosis.structured`, rule in :func:`is_structured`)
when this evidence is clear and the structure is not negligible against the noise floor;
:func:`where_misfit` names the channel and regime where the misfit lives.

Missing samples (weight 0) are skipped: each channel's residual series is the sequence of its
measured samples in time order, so a channel measured at a lower rate than the dataset's grid
is analysed at its own rate, and a drop-out joins the samples on either side.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from scipy import stats

#: Dataset columns (:data:`crs_core.dataset.Y_CHANNELS`) of each diagnosed channel group.
CHANNEL_GROUPS: dict[str, tuple[int, ...]] = {
    "lighthouse_plane1": (0, 1, 2, 3),
    "lighthouse_plane2": (4, 5, 6, 7),
    "wheel_speeds": (8, 9, 10, 11),
    "yaw_rate": (12,),
}
#: Units of each channel group's residual.
CHANNEL_UNITS: dict[str, str] = {
    "lighthouse_plane1": "rad",
    "lighthouse_plane2": "rad",
    "wheel_speeds": "rad/s",
    "yaw_rate": "rad/s",
}

#: Regime evidence: the F-test p-value of the regime regression must be below this ...
REGIME_P_MAX = 1e-6
#: ... and the regression must explain at least this share of the residual's variance.
REGIME_R2_MIN = 0.05
#: Offset evidence: the residual mean is at least this many standard errors from 0.
MEAN_Z_MIN = 8.0
#: Non-negligible: the structured part (offset and regime-explained part, RMS) is at least
#: this fraction of the noise floor.
STRUCTURE_MIN = 0.2
#: A residual RMS this many times the noise floor is a misfit by itself (white or not).
NORMALIZED_RMS_MAX = 3.0
#: Most lags of the Ljung-Box test (fewer on short series: ``min(MAX_LAGS, n // 5)``).
MAX_LAGS = 20
#: Width of the centred moving average smoothing the finite-difference acceleration, s.
ACCELERATION_WINDOW_S = 0.2
#: Fewest measured samples a channel group needs for the statistics.
MIN_SAMPLES = 10


@dataclass
class ChannelDiagnosis:
    """The residual diagnosis of one channel group (:data:`CHANNEL_GROUPS`).

    Attributes
    ----------
    channel : str
        Group name, a key of :data:`CHANNEL_GROUPS`.
    samples : int
        Samples with at least one measured column of the group.
    rms : float
        Residual RMS (measured - model) over all measured values, channel units
        (:data:`CHANNEL_UNITS`).
    noise_floor : float
        The assumed sensor sigma (``1 / weight``, median over measured values), channel units.
    normalized_rms : float
        ``rms / noise_floor``; about 1 or below for a good fit with honest sigmas.
    lag1_autocorrelation : float
        Lag-1 autocorrelation of the residual, mean over the group's columns (each column's
        own series of measured samples).
    whiteness_p : float
        Ljung-Box p-value over lags ``1..L``, ``L = min(20, n // 5)``, of the group's
        column-averaged residual series; small: not white.
    regime_r2 : float
        :math:`R^2` of the linear regression (standardised regressors, with intercept) of the
        column-averaged residual on the regime regressors.
    regime_p : float
        F-test p-value of that regression; small: the residual depends on the regime.
    strongest_regressor : str
        The regressor with the largest absolute correlation with the residual.
    worst_regime : dict
        ``{"regressor", "low", "high", "rms", "share"}``: the quartile bin
        ``[low, high]`` (regressor units) of the strongest regressor with the largest residual
        RMS (channel units), and its share of the samples.
    structured : bool
        The residual carries clear, non-negligible structure (rule: :func:`is_structured`).
    mean : float
        Mean of the column-averaged residual, channel units.
    mean_z : float
        ``|mean|`` in standard errors (sample std over :math:`\\sqrt{n_{eff}}`, with the
        effective sample size of an AR(1) series of the measured lag-1 autocorrelation).
    """

    channel: str
    samples: int
    rms: float
    noise_floor: float
    normalized_rms: float
    lag1_autocorrelation: float
    whiteness_p: float
    regime_r2: float
    regime_p: float
    strongest_regressor: str
    worst_regime: dict[str, Any]
    structured: bool
    mean: float = 0.0
    mean_z: float = 0.0

    @property
    def structure_rms(self) -> float:
        """RMS of the structured part, channel units: :math:`\\sqrt{\\bar e^2 + R^2 s^2}`
        with :math:`s` the residual's standard deviation about its mean."""
        variance = max(self.rms**2 - self.mean**2, 0.0)
        return float(np.sqrt(self.mean**2 + self.regime_r2 * variance))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (plain floats, ints, strings and bools)."""
        out = asdict(self)
        out["worst_regime"] = {
            k: (v if isinstance(v, str) else float(v)) for k, v in self.worst_regime.items()
        }
        for key, value in out.items():
            if isinstance(value, (float, np.floating)):
                out[key] = float(value)
        out["samples"] = int(self.samples)
        out["structured"] = bool(self.structured)
        out["structure_rms"] = self.structure_rms
        return out


def regime_regressors(t: np.ndarray, states: np.ndarray, u: np.ndarray) -> dict[str, np.ndarray]:
    """Operating-regime variables per sample.

    Parameters
    ----------
    t : (N,) array
        Stamps, s.
    states : (N, nx) array
        States with columns ``x, y, yaw, vx, vy, omega`` first (m, m, rad, m/s, m/s, rad/s).
    u : (N, 2) array
        Commands ``[steering (rad), torque (normalised)]``.

    Returns
    -------
    dict of str to (N,) arrays
        ``vx`` (m/s), ``steering`` (rad), ``abs_steering`` (rad), ``yaw_rate`` (rad/s),
        ``abs_yaw_rate`` (rad/s), ``torque`` (normalised), ``acceleration`` (m/s^2: the
        finite difference :math:`dv_x/dt` on ``t``, smoothed by a centred moving average over
        :data:`ACCELERATION_WINDOW_S`) and ``time`` (s since the first sample).
    """
    t = np.asarray(t, dtype=float)
    states, u = np.asarray(states, dtype=float), np.asarray(u, dtype=float)
    vx, omega = states[:, 3], states[:, 5]
    acceleration = np.gradient(vx, t) if len(t) > 1 else np.zeros_like(vx)
    return {
        "vx": vx.copy(),
        "steering": u[:, 0].copy(),
        "abs_steering": np.abs(u[:, 0]),
        "yaw_rate": omega.copy(),
        "abs_yaw_rate": np.abs(omega),
        "torque": u[:, 1].copy(),
        "acceleration": _moving_average(t, acceleration, ACCELERATION_WINDOW_S),
        "time": t - t[0],
    }


def fie_residuals(result: Any) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Residuals (measured - model) per channel group, and each group's noise floor.

    Parameters
    ----------
    result : FieResult
        An identification result (:class:`~crs_core.identification.solve.FieResult`).

    Returns
    -------
    residuals : dict of str to (N, k) arrays
        Per group of :data:`CHANNEL_GROUPS`, ``y - h(x)`` in channel units, NaN where not
        measured (weight 0).
    noise_floor : dict of str to float
        Per group, the assumed sensor sigma (median of ``1 / weight`` over measured values),
        channel units; NaN when the group has no measured value.
    """
    y, weight = np.asarray(result.data.y, float), np.asarray(result.data.weight, float)
    outputs = np.asarray(result.outputs, float)
    residuals, floors = {}, {}
    for name, columns in CHANNEL_GROUPS.items():
        cols = list(columns)
        measured = weight[:, cols] > 0
        residuals[name] = np.where(measured, y[:, cols] - outputs[:, cols], np.nan)
        w = weight[:, cols][measured]
        floors[name] = float(np.median(1.0 / w)) if w.size else float("nan")
    return residuals, floors


def diagnose(
    result: Any, regressors: dict[str, np.ndarray] | None = None
) -> list[ChannelDiagnosis]:
    """Diagnose every channel group of an identification result that has measured samples.

    Parameters
    ----------
    result : FieResult
        An identification result.
    regressors : dict of str to (N,) arrays, optional
        Regime variables per sample; default :func:`regime_regressors` of the result's
        stamps, identified states and commands.

    Returns
    -------
    list of ChannelDiagnosis
        In the order of :data:`CHANNEL_GROUPS`, groups without measured samples left out.
    """
    if regressors is None:
        regressors = regime_regressors(result.t, result.states, result.data.u)
    residuals, floors = fie_residuals(result)
    return [
        diagnose_residual(name, residuals[name], floors[name], regressors)
        for name in CHANNEL_GROUPS
        if np.isfinite(residuals[name]).any()
    ]


def diagnose_residual(
    channel: str,
    residual: np.ndarray,
    noise_floor: float,
    regressors: dict[str, np.ndarray],
) -> ChannelDiagnosis:
    """The diagnosis of one channel group's residual.

    Parameters
    ----------
    channel : str
        Name of the group (any label).
    residual : (N,) or (N, k) array
        Residual (measured - model) per sample and column, channel units; NaN: not measured.
    noise_floor : float
        The assumed sensor sigma, channel units.
    regressors : dict of str to (N,) arrays
        Regime variables per sample (for example :func:`regime_regressors`).

    Returns
    -------
    ChannelDiagnosis
        With p-values of 1 and correlations and :math:`R^2` of 0 where there are fewer than
        :data:`MIN_SAMPLES` samples (no evidence either way).
    """
    e = np.asarray(residual, dtype=float)
    e = e[:, None] if e.ndim == 1 else e
    rows = np.isfinite(e).any(axis=1)
    n = int(rows.sum())
    values = e[np.isfinite(e)]
    rms = float(np.sqrt(np.mean(values**2))) if values.size else 0.0
    floor = float(noise_floor)
    normalized = rms / floor if floor > 0 else float("inf")
    with np.errstate(invalid="ignore"):
        average = np.nanmean(e[rows], axis=1) if n else np.zeros(0)
    names = list(regressors)
    design = np.column_stack([np.asarray(regressors[k], float)[rows] for k in names])
    keep = np.isfinite(design).all(axis=1)
    average, design = average[keep], design[keep]
    n_used = len(average)

    lag1 = float(np.mean([_autocorrelation(c[np.isfinite(c)], 1)[0] for c in e.T]))
    whiteness_p, mean, mean_z = 1.0, float(np.mean(average)) if n_used else 0.0, 0.0
    r2, regime_p, strongest, worst = 0.0, 1.0, names[0], _no_regime(names[0])
    if n_used >= MIN_SAMPLES:
        whiteness_p = ljung_box(average)
        mean_z = _mean_z(average)
        r2, regime_p = regime_regression(average, design)
        strongest = _strongest(average, design, names)
        column = names.index(strongest)
        worst = worst_regime(e[rows][keep], design[:, column], strongest)
    diagnosis = ChannelDiagnosis(
        channel=channel,
        samples=n,
        rms=rms,
        noise_floor=floor,
        normalized_rms=float(normalized),
        lag1_autocorrelation=lag1 if np.isfinite(lag1) else 0.0,
        whiteness_p=float(whiteness_p),
        regime_r2=float(r2),
        regime_p=float(regime_p),
        strongest_regressor=strongest,
        worst_regime=worst,
        structured=False,
        mean=mean,
        mean_z=float(mean_z),
    )
    diagnosis.structured = is_structured(diagnosis)
    return diagnosis


def is_structured(diagnosis: ChannelDiagnosis) -> bool:
    r"""Whether a residual carries clear, non-negligible structure.

    Structured means there is *evidence* and the structure is not *negligible*, or the residual
    is far above the noise floor:

    .. math::

        \text{structured} = \big[(E_{regime} \lor E_{offset}) \land M\big] \lor
        \big[\text{rms} / \sigma \ge \text{NORMALIZED\_RMS\_MAX}\big]

    * :math:`E_{regime}`: the regime regression is significant and explains a real share,
      ``regime_p < REGIME_P_MAX`` and ``regime_r2 >= REGIME_R2_MIN``. A regression with an
      intercept does not see a constant offset (:math:`R^2` measures variance about the mean),
      hence
    * :math:`E_{offset}`: the mean residual is ``>= MEAN_Z_MIN`` standard errors from zero
      (``mean_z``; the standard error uses the effective sample size of the autocorrelated
      series, so slow wander is not mistaken for an offset).
    * :math:`M`: the structured part's RMS, :math:`\sqrt{\bar e^2 + R^2 s^2}`
      (:attr:`ChannelDiagnosis.structure_rms`), is at least ``STRUCTURE_MIN`` times the noise
      floor :math:`\sigma`: with thousands of samples a tiny, harmless offset or trend is
      significant; it only matters when it is a visible part of the sensor's noise.
    * ``rms / sigma >= NORMALIZED_RMS_MAX``: a residual this large is a misfit by itself, white
      or not (or the sensor sigma is badly wrong, which is worth knowing too).

    Non-whiteness alone (``whiteness_p``, ``lag1_autocorrelation``) is reported but not used:
    the FIE's own smoothing colours the residuals even on exact-model data (yaw rate lag-1
    autocorrelation about -0.35, Ljung-Box p down to 1e-87 on a 60 s run).

    Calibration (FIE with ``fit=("Cm1", "Df", "Dr", "Iz")``, ``process_scale=0.1`` on
    :func:`sim.scenarios.simulate_dataset` runs, ``CarModel()`` as the model).
    Clean data (the model is the truth; 16 seeds of 20 s, 2 of 60 s): nothing structured;
    largest ``regime_r2`` 0.031 (wheel speeds; 0.025 yaw rate, 0.007 Lighthouse), smallest
    ``regime_p`` 6e-8 (wheel speeds, 60 s, at :math:`R^2` 0.018: hence the :math:`R^2` floor as
    well as the p-value), largest ``mean_z`` 5.6, largest ``structure_rms / sigma`` 0.095.
    Hidden effects (3 seeds of 20 s, 1 of 60 s), all caught in ``yaw_rate`` and nowhere else:
    ``gyro_bias`` 0.1 rad/s: ``mean_z`` 85-175, ``structure_rms / sigma`` 0.93-0.96;
    ``steering_offset`` 0.05 rad: ``regime_r2`` 0.08-0.13 (p < 1e-17), ``mean_z`` 33-68,
    ratio 0.45-0.50; the smallest detected, ``gyro_bias`` 0.02 rad/s and
    ``steering_offset`` 0.02 rad: ratio 0.22 and 0.31 (the FIE absorbs part of an effect into
    the states, so the residual is smaller than the effect).
    """
    floor = diagnosis.noise_floor
    if not floor > 0:
        return False
    regime = diagnosis.regime_p < REGIME_P_MAX and diagnosis.regime_r2 >= REGIME_R2_MIN
    offset = diagnosis.mean_z >= MEAN_Z_MIN
    visible = diagnosis.structure_rms >= STRUCTURE_MIN * floor
    return bool(((regime or offset) and visible) or diagnosis.normalized_rms >= NORMALIZED_RMS_MAX)


def where_misfit(diagnoses: list[ChannelDiagnosis]) -> dict[str, Any] | None:
    """The channel and regime where the misfit lives.

    The structured channel with the largest structured share of its residual's size,
    :math:`\\text{structure\\_rms} / \\sigma` (the regime :math:`R^2` times the normalised RMS
    when the residual has no offset, generalised to count an offset too).

    Parameters
    ----------
    diagnoses : list of ChannelDiagnosis

    Returns
    -------
    dict or None
        ``{"channel", "regressor", "low", "high", "rms", "normalized_rms", "regime_r2",
        "mean"}`` (the worst regime's regressor, bin and residual RMS, channel units), or
        None when no channel is structured.
    """
    structured = [d for d in diagnoses if d.structured]
    if not structured:
        return None
    best = max(structured, key=_misfit_score)
    regime = best.worst_regime
    return {
        "channel": best.channel,
        "regressor": str(regime["regressor"]),
        "low": float(regime["low"]),
        "high": float(regime["high"]),
        "rms": float(regime["rms"]),
        "normalized_rms": float(best.normalized_rms),
        "regime_r2": float(best.regime_r2),
        "mean": float(best.mean),
    }


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
    r = _autocorrelation(x, lags)
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
    best = _no_regime(name)
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


def _misfit_score(d: ChannelDiagnosis) -> float:
    return d.structure_rms / d.noise_floor if d.noise_floor > 0 else float("inf")


def _no_regime(name: str) -> dict[str, Any]:
    return {"regressor": name, "low": 0.0, "high": 0.0, "rms": 0.0, "share": 0.0}


def _autocorrelation(x: np.ndarray, lags: int) -> np.ndarray:
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


def _mean_z(x: np.ndarray) -> float:
    r"""``|mean|`` in standard errors, :math:`n_{eff} = n (1 - \rho_1) / (1 + \rho_1)`."""
    n = len(x)
    std = float(np.std(x, ddof=1))
    mean = float(np.mean(x))
    if std <= 0.0:
        return float("inf") if mean != 0.0 else 0.0
    rho = min(max(float(_autocorrelation(x, 1)[0]), 0.0), 0.999)
    n_eff = max(n * (1.0 - rho) / (1.0 + rho), 1.0)
    return abs(mean) / (std / np.sqrt(n_eff))


def _strongest(e: np.ndarray, design: np.ndarray, names: list[str]) -> str:
    """The regressor with the largest absolute correlation with ``e`` (first on ties)."""
    best, best_r = names[0], -1.0
    ec = e - e.mean()
    for j, name in enumerate(names):
        xc = design[:, j] - design[:, j].mean()
        scale = float(np.sqrt(np.sum(xc**2) * np.sum(ec**2)))
        r = abs(float(np.sum(xc * ec))) / scale if scale > 0 else 0.0
        if r > best_r:
            best, best_r = name, r
    return best


def _standardised(design: np.ndarray) -> np.ndarray:
    """Columns scaled to zero mean and unit deviation; (near-)constant columns dropped."""
    if design.size == 0:
        return design.reshape(len(design), 0)
    std = design.std(axis=0)
    scale = np.maximum(np.abs(design).max(axis=0), 1e-300)
    keep = std > 1e-9 * scale
    return (design[:, keep] - design[:, keep].mean(axis=0)) / std[keep]


def _moving_average(t: np.ndarray, x: np.ndarray, window: float) -> np.ndarray:
    """Centred moving average of ``x`` over ``window`` seconds of ``t`` (shrinks at the ends)."""
    if len(t) < 2 or window <= 0:
        return x.copy()
    cumulative = np.concatenate([[0.0], np.cumsum(x)])
    start = np.searchsorted(t, t - window / 2, side="left")
    stop = np.searchsorted(t, t + window / 2, side="right")
    return (cumulative[stop] - cumulative[start]) / (stop - start)
