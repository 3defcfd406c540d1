r"""Hypotheses: the model extended by registry effects, fitted, and tested on held-out data.

A hypothesis is a set of effects of :data:`~crs_core.model.effects.EFFECTS` added to the current
model. Each is *nested*: with its parameters at their null value (:func:`null_value`, 0 or the
lower bound of a time constant) the extended model is the current one, so the prior of every
effect parameter is centred on "no effect" and the fit starts from the current model's fit
(:class:`~crs_core.identification.solve.WarmStart`).

The held-out test (:func:`compare_held_out`) needs no noise model. On held-out data both models
predict open loop over ``test_horizon_s`` from every sample (start states from an EKF run with
each model's parameters); per start, the mean squared error of every channel group (position
against the reference when the dataset has one, each Lighthouse plane, the wheel speeds, the
yaw rate) is divided by the current model's mean for that group and summed, so every group
weighs the same whatever its units. Starts are gathered into blocks of twice the horizon (blocks
overlap in no predicted sample but the edges), and the blocks are compared in pairs by two
one-sided tests, each suited to a way an effect shows:

* a t-test on the per-block log ratios :math:`r_b = \log(s_b^\mathrm{current} /
  s_b^\mathrm{candidate})` (mean scores of the block): an effect that makes every stretch of
  the drive a little better, however hard the stretch (a bias, a gain), and few blocks suffice;
* a Wilcoxon signed-rank test on the per-block differences :math:`d_b = s_b^\mathrm{current} -
  s_b^\mathrm{candidate}`: an effect that acts only in a few stretches (a motor lag at the
  throttle's transients), where a t-test drowns in the spread of those few large gains, and
  a few blocks made much worse cannot outweigh many made better.

The test's p-value is twice the smaller of the two (Bonferroni over the two tests). A hypothesis
is a finding when all three hold:

* the test's p-value is below ``false_alarm_rate / K`` (Bonferroni over the ``K`` hypotheses
  of a round: on data that need none of them, a finding is made with probability at most
  ``false_alarm_rate`` per round);
* the relative improvement of the mean score is at least ``min_improvement`` (practically
  significant, not only statistically);
* some parameter of every effect added is at least ``min_z`` standard deviations (the FIE's
  Laplace covariance on the training data) from its null value.

``input_delay`` has no state-space form: it is fitted through the data, with the commands
delayed (:func:`delayed_inputs`): the FIE's cost as a function of the delay (a profile: the
other parameters and the states refitted at each) is walked up from no delay, and a parabola
through the lowest cost and its neighbours gives the value and, from the curvature, its
standard deviation. The fitted model
carries the ``input_delay`` effect with that value (the simulator applies it; predictions here
delay the commands).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any

import numpy as np
from scipy import stats

from crs_core.dataset import Dataset
from crs_core.discrepancy.residuals import CHANNEL_GROUPS
from crs_core.errors import FieldError
from crs_core.identification.problem import FieSettings
from crs_core.identification.solve import FieResult, WarmStart, identify
from crs_core.identification.validation import (
    OpenLoopPredictor,
    horizon_index,
    position_errors,
)
from crs_core.measurements import InputSample
from crs_core.model import EFFECTS, CarModel
from crs_core.model.terms import Term
from crs_core.parameters import Parameter

#: A hypothesis whose held-out error is this many times the current model's (or not finite)
#: diverged: its model is unstable in open loop (a proposed term's cube of a state can be).
DIVERGED = 100.0
#: Effects fitted through the data rather than the model (no state-space form).
DELAY_EFFECT = "input_delay"
#: Spacing of the delays the FIE tries for ``input_delay``, s.
DELAY_STEP_S = 0.04


@dataclass(frozen=True)
class TestSettings:
    """How a hypothesis is judged.

    Attributes
    ----------
    false_alarm_rate : float
        Designed probability of a finding per round on data that need none of the effects.
    min_improvement : float
        Smallest relative improvement of the held-out score that counts (0.03 = 3 %).
    min_z : float
        Smallest distance from its null value, in its std, of an added effect's farthest
        parameter.
    test_horizon_s : float
        Open-loop horizon of the held-out score, s.
    """

    false_alarm_rate: float = 0.01
    min_improvement: float = 0.03
    min_z: float = 3.0
    test_horizon_s: float = 0.5


@dataclass
class HeldOutScores:
    """Per-start normalisable errors of one model on held-out data.

    ``mse`` is ``(S, G)``: per start, the mean squared error of each group in :attr:`groups`
    over the horizon; ``t`` the start stamps.
    """

    t: np.ndarray
    groups: tuple[str, ...]
    mse: np.ndarray


@dataclass
class HeldOutComparison:
    """The paired block tests of a candidate against the current model (see the module).

    ``p_log_ratio`` and ``p_signed_rank`` are the two tests' one-sided p-values, ``p_value``
    the combined one (twice the smaller, at most 1).
    """

    improvement: float
    p_value: float
    p_log_ratio: float
    p_signed_rank: float
    blocks: int
    group_improvement: dict[str, float]

    def to_dict(self) -> dict[str, Any]:
        return {
            "improvement": self.improvement,
            "p_value": self.p_value,
            "p_log_ratio": self.p_log_ratio,
            "p_signed_rank": self.p_signed_rank,
            "blocks": self.blocks,
            "group_improvement": self.group_improvement,
        }


@dataclass
class Hypothesis:
    """A fitted hypothesis and its verdict.

    Attributes
    ----------
    effects : the effects added (to the current model), and the names of the terms added
    result : the FIE result of the extended model on the training data
    model : the extended model (structure; parameters = the fit)
    delay_s : the fitted input delay (``input_delay`` only), s
    parameters : effect -> parameter -> {value, std, unit, z}
    comparison : the held-out test
    significant : a finding (see the module)
    reasons : why not, when not
    terms : the proposed terms added (:mod:`crs_core.model.terms`), also named in ``effects``
    """

    effects: tuple[str, ...]
    result: FieResult
    model: CarModel
    delay_s: float = 0.0
    parameters: dict[str, dict[str, dict[str, float | str]]] = field(default_factory=dict)
    comparison: HeldOutComparison | None = None
    significant: bool = False
    reasons: list[str] = field(default_factory=list)
    terms: tuple[Term, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {
            "effects": list(self.effects),
            "parameters": self.parameters,
            "held_out": self.comparison.to_dict() if self.comparison else None,
            "significant": self.significant,
            "reasons": self.reasons,
            "train_cost": self.result.cost,
        }


def null_value(parameter: Parameter) -> float:
    """The value at which an effect parameter means "no effect": 0, or the lower bound of a
    parameter that cannot be 0 (a time constant)."""
    return 0.0 if parameter.lower <= 0.0 <= parameter.upper else parameter.lower


#: Time constants tried by the profile of a lag's fit, in multiples of its null value (its lower
#: bound). Started near its null value, where the lag dynamics are stiff, IPOPT creeps along
#: the time constant for 100+ iterations (a 100 ms steering lag in 20 s of joystick data: 138
#: iterations from 20 ms); with the time constant held fixed a fit converges in 7-20, and the
#: free fit started at the best of them in about 30.
TIME_CONSTANT_GRID = (2.0, 4.0, 10.0, 20.0, 40.0, 100.0)


def extended_model(
    model: CarModel,
    effects: Sequence[str],
    values: Mapping[str, float] = MappingProxyType({}),
    terms: Sequence[Term] = (),
) -> CarModel:
    """``model`` with ``effects`` (and ``terms``) added, their parameters at ``values`` or else
    their null values (a term's coefficients at 0); every other value kept."""
    spec: dict[str, dict[str, float] | None] = {e.name: None for e in model.effects}
    for name in effects:
        if name not in EFFECTS:
            raise FieldError("effects", f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
        spec[name] = {p.name: values.get(p.name, null_value(p)) for p in EFFECTS[name].parameters}
    all_terms = (*model.terms, *terms)
    plant, stations = model.plant, model.n_base_stations
    skeleton = CarModel(spec, n_base_stations=stations, terms=all_terms, model=plant)
    values = {n: model.parameters.value(n) for n in model.parameters.names}
    return CarModel(
        spec,
        n_base_stations=stations,
        parameters=skeleton.parameters.updated(values),
        terms=all_terms,
        model=plant,
    )


def delayed_inputs(dataset: Dataset, delay_s: float) -> Dataset:
    """``dataset`` with its commands applied ``delay_s`` later: the sampled command signal read
    ``delay_s`` earlier (linear interpolation, the first sample before the start), and the
    full-rate input stream, when present, shifted by the same amount. Continuous in
    ``delay_s``, not rounded to whole sample intervals."""
    if dataset.u is None or delay_s == 0.0:
        return dataset
    t = dataset.t
    u = np.stack([np.interp(t - delay_s, t, column) for column in dataset.u.T], axis=1)
    inputs = None
    if dataset.inputs:
        inputs = [InputSample(s.stamp + delay_s, s.u) for s in dataset.inputs]
    return replace(dataset, u=u, inputs=inputs)


def held_out_scores(
    dataset: Dataset, model: CarModel, horizon_s: float, delay_s: float = 0.0
) -> HeldOutScores:
    """Open-loop predictions of ``model`` on ``dataset`` (commands delayed by ``delay_s``) over
    ``horizon_s`` from every sample: per start and group (position, and the channel groups of
    the residual diagnosis), the mean squared error over the horizon (NaN where not
    measured)."""
    data = delayed_inputs(dataset, delay_s)
    prediction = OpenLoopPredictor(data, model, horizon_s).predict()
    index = horizon_index(data, prediction)
    groups, columns = [], []
    error = position_errors(prediction)
    if np.isfinite(error).any():
        groups.append("position")
        columns.append(np.nanmean(np.sum(error**2, axis=2), axis=1))
    residual = prediction.outputs - data.y[index]
    for name, cols in CHANNEL_GROUPS.items():
        squared = residual[..., list(cols)] ** 2
        if not np.isfinite(squared).any():
            continue
        flat = squared.reshape(len(squared), -1)
        counts = np.sum(np.isfinite(flat), axis=1)
        sums = np.nansum(flat, axis=1)
        columns.append(np.where(counts > 0, sums / np.maximum(counts, 1), np.nan))
        groups.append(name)
    return HeldOutScores(data.t[prediction.starts], tuple(groups), np.stack(columns, axis=1))


def compare_held_out(
    current: HeldOutScores, candidate: HeldOutScores, horizon_s: float
) -> HeldOutComparison:
    """The paired one-sided block tests of ``candidate`` against ``current`` (the module)."""
    if current.t.shape != candidate.t.shape or not np.allclose(current.t, candidate.t):
        raise FieldError("scores", "the two models were scored from different starts")
    groups = [g for g in current.groups if g in candidate.groups]
    a = current.mse[:, [current.groups.index(g) for g in groups]]
    b = candidate.mse[:, [candidate.groups.index(g) for g in groups]]
    valid = np.all(np.isfinite(a), axis=1) & np.all(np.isfinite(b), axis=1)
    a, b, t = a[valid], b[valid], current.t[valid]
    scale = np.mean(a, axis=0)
    scale[scale <= 0] = 1.0
    score_a, score_b = np.sum(a / scale, axis=1), np.sum(b / scale, axis=1)
    block = np.floor((t - t[0]) / (2.0 * horizon_s)).astype(int)
    labels = np.unique(block)
    mean_a = np.array([np.mean(score_a[block == k]) for k in labels])
    mean_b = np.array([np.mean(score_b[block == k]) for k in labels])
    improvement = float(1.0 - np.mean(score_b) / np.mean(score_a))
    p_log_ratio = _one_sided_t(np.log(np.maximum(mean_a, _TINY) / np.maximum(mean_b, _TINY)))
    p_signed_rank = _one_sided_signed_rank(mean_a - mean_b)
    per_group = {g: float(1.0 - np.mean(b[:, i]) / np.mean(a[:, i])) for i, g in enumerate(groups)}
    return HeldOutComparison(
        improvement,
        min(1.0, 2.0 * min(p_log_ratio, p_signed_rank)),
        p_log_ratio,
        p_signed_rank,
        len(labels),
        per_group,
    )


#: Floor of a block's mean score in the log ratio (a block predicted exactly).
_TINY = 1e-300


def _one_sided_t(d: np.ndarray) -> float:
    """p-value of a one-sided t-test that ``d`` has a positive mean (1 for fewer than three
    values or all zero; 0 for a positive constant)."""
    if len(d) < 3 or not np.any(d):
        return 1.0
    spread = float(np.std(d, ddof=1))
    if spread <= 0:
        return 0.0 if np.mean(d) > 0 else 1.0
    t_stat = float(np.mean(d)) / (spread / math.sqrt(len(d)))
    return float(stats.t.sf(t_stat, df=len(d) - 1))


def _one_sided_signed_rank(d: np.ndarray) -> float:
    """p-value of a one-sided Wilcoxon signed-rank test that ``d`` is centred above 0 (exact
    for up to 50 values, else its normal approximation; zeros left out; 1 for fewer than three
    non-zero values)."""
    if np.count_nonzero(d) < 3:
        return 1.0
    return float(stats.wilcoxon(d, alternative="greater", zero_method="wilcox").pvalue)


def fit_hypothesis(
    train: Dataset,
    model: CarModel,
    current: FieResult,
    effects: Sequence[str],
    settings: FieSettings,
    progress: Callable[[int, float], None] | None = None,
    start: Mapping[str, float] = MappingProxyType({}),
    terms: Sequence[Term] = (),
) -> Hypothesis:
    """Fit ``model`` (the current structure, its *prior* values) extended by ``effects`` and
    ``terms`` on ``train``, warm-started at ``current`` (the current model's fit). The added
    parameters start at ``start``, or else at their null value; a single added time constant at
    the best point of its profile (:func:`_profile_time_constant`)."""
    effects = tuple(effects)
    state_effects = [e for e in effects if e != DELAY_EFFECT]
    extended = extended_model(model, state_effects, terms=terms)
    added_parameters = [p for e in state_effects for p in EFFECTS[e].parameters]
    added_parameters += [p for term in terms for p in term.parameters()]
    added = tuple(p.name for p in added_parameters)
    fit = tuple(settings.fit) + tuple(n for n in added if n not in settings.fit)
    values = {n: current.parameters.value(n) for n in current.fit}
    lags = [p for e in state_effects for p in EFFECTS[e].parameters if null_value(p) != 0.0]
    for p in added_parameters:
        values.setdefault(p.name, start.get(p.name, null_value(p)))
    if not start and len(added) == 1 and len(lags) == 1:
        values[lags[0].name] = _profile_time_constant(
            train, extended, current, lags[0], replace(settings, starts=1), progress
        )
    warm = WarmStart(values, current.states)
    fit_settings = replace(settings, fit=fit, starts=1)
    delay = 0.0
    if DELAY_EFFECT in effects:
        result, delay, delay_std = _fit_delay(
            train, extended, current, fit_settings, warm, progress
        )
    else:
        result = identify(train, extended, fit_settings, progress, warm_start=warm)
    fitted_model = extended_model(
        extended.with_parameters(result.parameters),
        [DELAY_EFFECT] if DELAY_EFFECT in effects else [],
        {DELAY_EFFECT: delay},
    )
    parameters: dict[str, dict[str, dict[str, float | str]]] = {}
    owners = [(name, EFFECTS[name].parameters) for name in state_effects]
    owners += [(term.name, term.parameters()) for term in terms]
    for name, owned in owners:
        parameters[name] = {}
        for p in owned:
            j = result.fit.index(p.name)
            value, std = float(result.theta[j]), float(result.uncertainty.std[j])
            parameters[name][p.name] = {
                "value": value,
                "std": std,
                "unit": p.unit,
                "z": abs(value - null_value(p)) / std if std > 0 else math.inf,
            }
    if DELAY_EFFECT in effects:
        unit = EFFECTS[DELAY_EFFECT].parameters[0].unit
        parameters[DELAY_EFFECT] = {
            "input_delay": {
                "value": delay,
                "std": delay_std,
                "unit": unit,
                "z": delay / delay_std if delay_std > 0 else math.inf,
            }
        }
    names = (*effects, *(term.name for term in terms))
    return Hypothesis(names, result, fitted_model, delay, parameters, terms=tuple(terms))


def _profile_time_constant(
    train: Dataset,
    model: CarModel,
    current: FieResult,
    tau: Parameter,
    settings: FieSettings,
    progress: Callable[[int, float], None] | None,
) -> float:
    """Where the free fit of time constant ``tau`` starts: the FIE's profile cost (``tau`` held
    at :data:`TIME_CONSTANT_GRID` multiples of its null value, the other parameters and the
    states refitted, warm started at ``current``) walked up from no effect while it falls; its
    lowest point, or the first grid point when that is no effect."""
    null = null_value(tau)
    grid = sorted({min(k * null, tau.upper) for k in TIME_CONSTANT_GRID})
    warm = WarmStart({n: current.parameters.value(n) for n in current.fit}, current.states)
    best, best_cost = grid[0], current.cost
    for value in grid:
        fixed = model.with_parameters(model.parameters.updated({tau.name: value}))
        cost = identify(train, fixed, settings, progress, warm_start=warm).cost
        if cost >= best_cost:
            break
        best, best_cost = value, cost
    return best


def _fit_delay(
    train: Dataset,
    model: CarModel,
    current: FieResult,
    settings: FieSettings,
    warm: WarmStart,
    progress: Callable[[int, float], None] | None,
) -> tuple[FieResult, float, float]:
    """The input delay by the FIE's profile cost: fits at delays :data:`DELAY_STEP_S` apart
    (no delay: the current fit) walking up while the cost falls, then a parabola through the
    lowest and its neighbours gives the delay and, from the curvature, its std; the FIE at that
    delay is the result."""
    upper = EFFECTS[DELAY_EFFECT].parameters[0].upper
    results = {0.0: current}

    def fit(delay: float) -> float:
        if delay not in results:
            data = delayed_inputs(train, delay)
            results[delay] = identify(data, model, settings, progress, warm)
        return results[delay].cost

    delay = DELAY_STEP_S
    while fit(delay) < fit(round(delay - DELAY_STEP_S, 6)) and delay + DELAY_STEP_S <= upper:
        delay = round(delay + DELAY_STEP_S, 6)
    if min(results, key=lambda d: results[d].cost) == 0.0:
        fit(DELAY_STEP_S / 2)  # resolve the curvature next to "no delay"
    delays = sorted(results)
    k = min(range(len(delays)), key=lambda i: results[delays[i]].cost)
    k = min(max(k, 1), len(delays) - 2)
    x = np.array(delays[k - 1 : k + 2])
    a, b, _ = np.polyfit(x, [results[d].cost for d in x], 2)
    if a > 0:
        best = float(np.clip(-b / (2 * a), 0.0, upper))
        std = math.sqrt(1.0 / a)  # V = -2 log L + c: var = 2 / V'' = 1 / a
    else:
        best, std = float(min(results, key=lambda d: results[d].cost)), math.inf
    nearest = min(results, key=lambda d: abs(d - best))
    if abs(nearest - best) > 0.1 * DELAY_STEP_S:
        fit(best)
        nearest = best
    return results[nearest], best, std


def clear_of_null(values: Mapping[str, Mapping[str, Any]], min_z: float) -> bool:
    """Some parameter of one effect's ``{parameter: {value, std, unit, z}}`` is at least
    ``min_z`` std from its null value."""
    return max(float(entry["z"]) for entry in values.values()) >= min_z


def judge(
    hypothesis: Hypothesis,
    current_scores: HeldOutScores,
    validation: Dataset,
    settings: TestSettings,
    tests: int,
) -> Hypothesis:
    """Score ``hypothesis`` on ``validation`` against the current model's scores and decide."""
    scores = held_out_scores(
        validation, hypothesis.model, settings.test_horizon_s, hypothesis.delay_s
    )
    comparison = compare_held_out(current_scores, scores, settings.test_horizon_s)
    reasons = []
    threshold = settings.false_alarm_rate / max(tests, 1)
    if not comparison.p_value < threshold:
        reasons.append(f"held-out p = {comparison.p_value:.2g} (needs < {threshold:.2g})")
    if not comparison.improvement > -DIVERGED:
        reasons.append("its held-out predictions diverge (an unstable model)")
    elif comparison.improvement < settings.min_improvement:
        reasons.append(
            f"held-out improvement {100 * comparison.improvement:.1f} % "
            f"(needs >= {100 * settings.min_improvement:.0f} %)"
        )
    for effect, values in hypothesis.parameters.items():
        if not clear_of_null(values, settings.min_z):
            far = ", ".join(f"{name} {float(entry['z']):.1f}" for name, entry in values.items())
            reasons.append(f"{effect}: no parameter {settings.min_z:g} std from no effect ({far})")
    hypothesis.comparison = comparison
    hypothesis.reasons = reasons
    hypothesis.significant = not reasons
    return hypothesis


def information_criterion(hypothesis: Hypothesis) -> float:
    r"""Akaike's criterion of a fitted hypothesis on the training data: the FIE cost
    (:math:`-2 \log L` up to a constant shared by every hypothesis) plus twice the number of
    effect parameters. It ranks findings that compete for the same misfit (a steering lag and an
    input delay both explain late steering): the held-out test decides *whether* an effect is
    needed, the training likelihood, on more data and weighted by the noise, *which*."""
    added = sum(len(values) for values in hypothesis.parameters.values())
    return hypothesis.result.cost + 2.0 * added


def parameter_table(hypotheses: Sequence[Hypothesis]) -> dict[str, dict[str, Any]]:
    """Effect -> parameter -> {value, std, unit} of the given hypotheses (JSON-ready)."""
    table: dict[str, dict[str, Any]] = {}
    for h in hypotheses:
        for effect, values in h.parameters.items():
            table[effect] = {
                n: {k: v for k, v in entry.items() if k != "z"} for n, entry in values.items()
            }
    return table
