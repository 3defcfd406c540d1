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

from crs_core.discrepancy.statistics import (
    autocorrelation,
    ljung_box,
    mean_z,
    no_regime,
    regime_regression,
    strongest,
    worst_regime,
)

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
#: A significant regime regression explaining at least this share of the variance is structure
#: whatever its size against the assumed noise floor (that sigma is the estimator's tuning and
#: may be far from a recording's real noise, e.g. pre-filtered signals); clean data stay
#: below 0.031.
REGIME_R2_DOMINANT = 0.2
#: Offset evidence: the residual mean is at least this many standard errors from 0.
MEAN_Z_MIN = 8.0
#: Non-negligible: the structured part (offset and regime-explained part, RMS) is at least
#: this fraction of the noise floor.
STRUCTURE_MIN = 0.2
#: A residual RMS this many times the noise floor is a misfit by itself (white or not).
NORMALIZED_RMS_MAX = 3.0
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
    states : (N, 6) array
        Car states ``x, y, yaw, vx, vy, omega`` (m, m, rad, m/s, m/s, rad/s).
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
        stamps, identified car states and commands.

    Returns
    -------
    list of ChannelDiagnosis
        In the order of :data:`CHANNEL_GROUPS`, groups without measured samples left out.
    """
    if regressors is None:
        regressors = regime_regressors(result.t, result.car_states, result.data.u)
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

    lag1 = float(np.mean([autocorrelation(c[np.isfinite(c)], 1)[0] for c in e.T]))
    whiteness_p, mean, offset_z = 1.0, float(np.mean(average)) if n_used else 0.0, 0.0
    r2, regime_p, regressor, worst = 0.0, 1.0, names[0], no_regime(names[0])
    if n_used >= MIN_SAMPLES:
        whiteness_p = ljung_box(average)
        offset_z = mean_z(average)
        r2, regime_p = regime_regression(average, design)
        regressor = strongest(average, design, names)
        column = names.index(regressor)
        worst = worst_regime(e[rows][keep], design[:, column], regressor)
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
        strongest_regressor=regressor,
        worst_regime=worst,
        structured=False,
        mean=mean,
        mean_z=float(offset_z),
    )
    diagnosis.structured = is_structured(diagnosis)
    return diagnosis


def is_structured(diagnosis: ChannelDiagnosis) -> bool:
    r"""Whether a residual carries clear, non-negligible structure.

    Structured means there is *evidence* and the structure is not *negligible*, or the residual
    is far above the noise floor:

    .. math::

        \text{structured} = \big[(E_{regime} \lor E_{offset}) \land M\big] \lor
        \big[\text{rms} / \sigma \ge \text{NORMALIZED\_RMS\_MAX}\big] \lor D_{regime}

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
    * :math:`D_{regime}`: the regime regression is significant and explains at least
      ``REGIME_R2_DOMINANT`` of the variance: most of the residual follows the operating
      regime, however small it is against an assumed sigma that may not be the recording's.

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
    dominant = diagnosis.regime_p < REGIME_P_MAX and diagnosis.regime_r2 >= REGIME_R2_DOMINANT
    large = diagnosis.normalized_rms >= NORMALIZED_RMS_MAX
    return bool(((regime or offset) and visible) or large or dominant)


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
        "mean", "also_structured"}`` (the worst regime's regressor, bin and residual RMS,
        channel units; the other structured channels), or None when no channel is structured.
    """
    structured = [d for d in diagnoses if d.structured]
    if not structured:
        return None
    best = max(structured, key=_misfit_score)
    also = [d.channel for d in structured if d is not best]
    return where_entry(
        best.channel, best.worst_regime, best.normalized_rms, best.regime_r2, best.mean, also
    )


def where_entry(
    channel: str,
    regime: dict[str, Any],
    normalized_rms: float,
    regime_r2: float,
    mean: float,
    also_structured: list[str],
) -> dict[str, Any]:
    """The ``where`` of a verdict (:func:`where_misfit`): the channel, its worst regime's
    regressor, bin and RMS, and the channel's size, regime R², mean and the other structured
    channels."""
    return {
        "channel": channel,
        "regressor": str(regime["regressor"]),
        "low": float(regime["low"]),
        "high": float(regime["high"]),
        "rms": float(regime["rms"]),
        "normalized_rms": float(normalized_rms),
        "regime_r2": float(regime_r2),
        "mean": float(mean),
        "also_structured": list(also_structured),
    }


def _misfit_score(d: ChannelDiagnosis) -> float:
    return d.structure_rms / d.noise_floor if d.noise_floor > 0 else float("inf")


def _moving_average(t: np.ndarray, x: np.ndarray, window: float) -> np.ndarray:
    """Centred moving average of ``x`` over ``window`` seconds of ``t`` (shrinks at the ends)."""
    if len(t) < 2 or window <= 0:
        return x.copy()
    cumulative = np.concatenate([[0.0], np.cumsum(x)])
    start = np.searchsorted(t, t - window / 2, side="left")
    stop = np.searchsorted(t, t + window / 2, side="right")
    return (cumulative[stop] - cumulative[start]) / (stop - start)
