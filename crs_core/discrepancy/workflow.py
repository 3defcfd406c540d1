"""The discrepancy workflow: fit, look at what is left, test every effect, name the winner.

:func:`find_discrepancy` runs the steps of ``crs discrepancy``:

1. identify the current model on the training data (the FIE); on a recording without a
   stream (the real recordings' layout) with the first-plane sweep lag fitted first, a
   nuisance shared by every hypothesis (:mod:`~crs_core.discrepancy.sweep_lag`);
2. diagnose its residuals channel by channel (:mod:`~crs_core.discrepancy.residuals`) and
   its open-loop predictions from the fit's states (:mod:`~crs_core.discrepancy.prediction`:
   a slow drift the fit's state absorbs shows there);
3. fit every candidate effect of the registry on the training data and test it on held-out
   data (:mod:`~crs_core.discrepancy.hypotheses`); held-out data are the validation dataset,
   or without one the last :attr:`DiscrepancySettings.held_out_fraction` of the training run;
4. name the winner (of the findings, the one the training data explain best:
   :func:`~crs_core.discrepancy.hypotheses.information_criterion`), then test on top of it the
   other findings of the first round and the (two, by default) effects whose fitted parameter
   was clear of "no effect" although the held-out test refused them, the lowest criterion first
   (one effect can hide another); two effects at once are reported when both are significant;
   no finding: ``none``, or ``unexplained`` when the residuals of the current model stay
   structured or its open-loop predictions miss coherently (with the channel and regime where
   the misfit lives);
5. beyond the registry: from what the final fit (the named effects', or the current model's)
   still leaves, propose terms in the model's own variables by sparse regression
   (:mod:`~crs_core.discrepancy.proposal`), fit each with the model and test it on the held-out
   data as an effect is tested (with a named effect: on top of it, and the terms proposed from
   the current model's fit alone, for a term can explain what the effect only imitated); of the
   named effects and the terms that pass, the lowest information criterion on the training
   data is the final model (verdict ``proposed`` when it holds a term and no registry effect);
6. report the gap before and after: the held-out open-loop position RMSE over the paper's 2 s
   horizon and the per-channel RMS, with the final model's parameters.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field, replace
from typing import Any, TypeVar

from crs_core.dataset import Dataset
from crs_core.discrepancy.hypotheses import (
    DELAY_EFFECT,
    HeldOutScores,
    Hypothesis,
    TestSettings,
    clear_of_null,
    compare_held_out,
    delayed_inputs,
    extended_model,
    fit_hypothesis,
    held_out_scores,
    information_criterion,
    judge,
    null_value,
    parameter_table,
)
from crs_core.discrepancy.prediction import (
    PREDICTION_CHANNEL,
    PredictionDiagnosis,
    diagnose_prediction,
)
from crs_core.discrepancy.proposal import Proposal, propose
from crs_core.discrepancy.residuals import ChannelDiagnosis, diagnose, where_misfit
from crs_core.discrepancy.sweep_lag import (
    SweepLag,
    estimate_plane1_lag,
    plane1_lag_source,
    with_plane1_lag,
)
from crs_core.errors import FieldError
from crs_core.identification.data import PLANE1_LAG_KEY
from crs_core.identification.problem import FieSettings, check_fit
from crs_core.identification.solve import FieResult, identify
from crs_core.identification.validation import DEFAULT_HORIZON_S, validate
from crs_core.model import EFFECTS, CarModel
from crs_core.model.terms import Term
from crs_core.settings import Settings, within

#: Verdicts of the workflow.
VERDICTS = ("effect", "proposed", "none", "unexplained")


@dataclass(frozen=True)
class DiscrepancySettings(Settings):
    """Settings of :func:`find_discrepancy`.

    Attributes
    ----------
    identification : FieSettings
        The FIE of the current model (its ``fit`` is refitted in every hypothesis, together
        with the effect's parameters).
    test : TestSettings
        How a hypothesis is judged (false-alarm rate, minimum improvement, parameter z).
    candidates : tuple of str or None
        Effects to try (default: every registry effect the model does not have).
    held_out_fraction : float
        Without a validation dataset: the last fraction of the training run is held out.
    horizon_s : float
        Horizon of the reported gap (the paper's 2 s open-loop position RMSE).
    max_effects : int
        Most effects named at once.
    hidden_candidates : int
        Besides the other findings, how many of the effects the held-out test refused but the
        training fit asked for (a parameter ``test.min_z`` std from no effect; the lowest
        :func:`~crs_core.discrepancy.hypotheses.information_criterion` first) are tested again
        on top of the named effect.
    hypothesis_max_iter : int
        IPOPT iteration limit of a hypothesis' fit (warm started at the current fit), a
        compromise for speed. Offsets, gains and fits with the delay or a time constant held
        fixed converge in 5-20 iterations. A free time constant converges slowly from a start
        far from its value (a 100 ms steering lag in 20 s of joystick data: 138 iterations from
        20 ms), so it starts at the lowest point of its profile
        (:data:`~crs_core.discrepancy.hypotheses.TIME_CONSTANT_GRID`; from 100 ms that lag
        converges in 32) and is stopped here: within a grid step of its optimum.
    workers : int
        Processes fitting hypotheses at once (1: in this process).
    estimate_plane1_lag : bool
        On training data without a stream and without a stated lag (the real recordings'
        layout), fit the first-plane sweep lag before the hypotheses
        (:func:`~crs_core.discrepancy.sweep_lag.estimate_plane1_lag`); else it is taken as 0.
    propose : bool
        Propose terms beyond the registry (:mod:`~crs_core.discrepancy.proposal`) from what the
        final fit leaves, and test them.
    """

    identification: FieSettings = field(default_factory=FieSettings)
    test: TestSettings = field(default_factory=TestSettings)
    candidates: tuple[str, ...] | None = None
    held_out_fraction: float = within(0.3, low=0.1, high=0.7)
    horizon_s: float = DEFAULT_HORIZON_S
    max_effects: int = 2
    hidden_candidates: int = 2
    hypothesis_max_iter: int = 30
    workers: int = 1
    estimate_plane1_lag: bool = True
    propose: bool = True

    def _check_relations(self) -> None:
        if self.workers < 1:
            raise FieldError("workers", f"must be >= 1, got {self.workers}")
        if self.max_effects < 1:
            raise FieldError("max_effects", f"must be >= 1, got {self.max_effects}")
        if self.hypothesis_max_iter < 1:
            raise FieldError("hypothesis_max_iter", f"must be >= 1, got {self.hypothesis_max_iter}")
        if self.hidden_candidates < 0:
            raise FieldError("hidden_candidates", f"must be >= 0, got {self.hidden_candidates}")
        for name in self.candidates or ():
            if name not in EFFECTS:
                raise FieldError(
                    "candidates", f"unknown effect {name!r}; known: {', '.join(EFFECTS)}"
                )


@dataclass
class DiscrepancyResult:
    """What the workflow found (see :meth:`summary` for the JSON report).

    Attributes
    ----------
    verdict : one of :data:`VERDICTS`
    effects : the named registry effects (empty for ``proposed``, ``none``, ``unexplained``)
    terms : the proposed terms in the final model (:mod:`crs_core.model.terms`)
    proposed : every proposed term as (its target's sparse fit, :class:`~crs_core.discrepancy.
        proposal.Proposal`; its hypothesis, fitted and tested)
    final : the final model's FIE result (the current model's when nothing was named)
    final_model : the final model (structure and fitted parameters)
    delay_s : the named input delay, s (0 without)
    current : the current model's FIE result
    hypotheses : every hypothesis tried, in order
    diagnostics_before, diagnostics_after : residual diagnoses of the current / final fit
    prediction_before, prediction_after : open-loop prediction diagnoses of the current / final
        fit
    gap : {"before": m, "after": m} held-out open-loop position RMSE (None without a reference)
    channel_rms : {"before": {...}, "after": {...}} held-out per-channel RMS
    where : the channel and regime of the misfit (``unexplained``), else None
    train_samples, held_out_samples : int
    held_out : "validation dataset" or "last N % of the training run"
    time_s : float
    plane1_lag : the first-plane sweep lag of the training fits and where it came from
    """

    verdict: str
    effects: tuple[str, ...]
    final: FieResult
    final_model: CarModel
    delay_s: float
    current: FieResult
    hypotheses: list[Hypothesis]
    diagnostics_before: list[ChannelDiagnosis]
    diagnostics_after: list[ChannelDiagnosis]
    prediction_before: PredictionDiagnosis
    prediction_after: PredictionDiagnosis
    gap: dict[str, float | None]
    channel_rms: dict[str, dict[str, float | None]]
    where: dict[str, Any] | None
    train_samples: int
    held_out_samples: int
    held_out: str
    time_s: float
    plane1_lag: SweepLag = field(default_factory=lambda: SweepLag(None, None, "none"))
    terms: tuple[Term, ...] = ()
    proposed: list[tuple[Proposal, Hypothesis]] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        """The JSON report (``report.json``)."""
        named = [
            h for h in self.hypotheses if h.significant and set(h.effects) <= set(self.effects)
        ]
        return {
            "verdict": self.verdict,
            "effects": list(self.effects),
            "parameters": parameter_table(named[-1:]) if named else {},
            "proposed_terms": [
                proposed_entry(h, proposal, h.model is self.final_model)
                for proposal, h in self.proposed
            ],
            "gap_before": self.gap["before"],
            "gap_after": self.gap["after"],
            "gap_horizon_s": self.gap["horizon_s"],
            "residual_rms_before": self.channel_rms["before"],
            "residual_rms_after": self.channel_rms["after"],
            "where": self.where,
            "held_out": self.held_out,
            "train_samples": self.train_samples,
            "held_out_samples": self.held_out_samples,
            "plane1_lag": self.plane1_lag.to_dict(),
            "hypotheses": [h.to_dict() for h in self.hypotheses],
            "diagnostics_before": [d.to_dict() for d in self.diagnostics_before],
            "diagnostics_after": [d.to_dict() for d in self.diagnostics_after],
            "prediction_before": self.prediction_before.to_dict(),
            "prediction_after": self.prediction_after.to_dict(),
            "time_s": self.time_s,
        }


def split_held_out(
    train: Dataset, validation: Dataset | None, fraction: float
) -> tuple[Dataset, Dataset, str]:
    """Training and held-out data: ``validation`` when given, else a time split of ``train``."""
    if validation is not None:
        return train, validation, "validation dataset"
    n = len(train.t)
    cut = round(n * (1.0 - fraction))
    return (
        train.samples(0, cut),
        train.samples(cut, n),
        f"last {100 * fraction:.0f} % of the training run",
    )


def find_discrepancy(
    train: Dataset,
    model: CarModel,
    validation: Dataset | None = None,
    settings: DiscrepancySettings | None = None,
    progress: Callable[[str], None] | None = None,
) -> DiscrepancyResult:
    """Run the workflow on ``train`` (held out: ``validation`` or a time split); ``model`` is
    the current model with its prior values; ``progress`` gets one line per step."""
    settings = settings or DiscrepancySettings()
    say = progress or (lambda line: None)
    started = time.perf_counter()
    check_fit(model, settings.identification.fit)
    fit_data, held_out, held_out_label = split_held_out(
        train, validation, settings.held_out_fraction
    )
    candidates = [
        name
        for name in (settings.candidates or tuple(EFFECTS))
        if name not in {e.name for e in model.effects}
    ]
    candidates.sort(key=lambda name: not _slow_to_fit(name))  # the longest fits start first
    say(f"fitting the current model ({len(fit_data.t)} samples) ...")
    current = identify(fit_data, model, settings.identification)
    fit_data, current, plane1_lag = _plane1_lag(fit_data, model, current, settings, say)
    current_model = _fitted(model, current)
    diagnostics_before = diagnose(current)
    say("open-loop predictions from the fit's states ...")
    prediction_before = diagnose_prediction(
        fit_data, current_model, current.states, settings.horizon_s
    )
    say(
        f"open-loop gap {1e3 * prediction_before.gap:.1f} mm over "
        f"{prediction_before.horizon_s:g} s, {prediction_before.coherence:.2f}x the same drive's "
        "with the fit's process residuals shuffled"
    )
    current_scores = held_out_scores(held_out, current_model, settings.test.test_horizon_s)
    say(f"current model: FIE cost {current.cost:.6g}; {len(candidates)} hypotheses to test")

    hypothesis_fie = replace(
        settings.identification,
        max_iter=min(settings.identification.max_iter, settings.hypothesis_max_iter),
    )
    fit_settings = replace(settings, identification=hypothesis_fie)
    tasks = [
        (fit_data, model, current, (name,), fit_settings, current_scores, held_out, len(candidates))
        for name in candidates
    ]
    first_round = _run_hypotheses(_fit_and_judge, tasks, settings.workers, say)
    hypotheses: list[Hypothesis] = list(first_round)
    findings = sorted((h for h in first_round if h.significant), key=information_criterion)
    chosen: Hypothesis | None = findings[0] if findings else None
    if chosen is not None:
        # on top of the winner: the other findings, and the effects the training data asked
        # for but the held-out test refused (a second effect can hide behind the first)
        asked = sorted(
            (h for h in first_round if not h.significant and _asked_for(h, settings.test.min_z)),
            key=information_criterion,
        )
        others = findings[1:] + asked[: settings.hidden_candidates]
        while others and len(chosen.effects) < settings.max_effects:
            base_data = delayed_inputs(fit_data, chosen.delay_s)
            base_scores = held_out_scores(
                held_out, chosen.model, settings.test.test_horizon_s, chosen.delay_s
            )
            say(f"on top of {'+'.join(chosen.effects)}: {len(others)} more to test")
            joint_tasks = [
                (model, chosen, other, base_data, fit_settings, base_scores, held_out, len(others))
                for other in sorted(others, key=lambda h: not _slow_to_fit(h.effects[0]))
            ]
            joint = _run_hypotheses(_fit_joint_and_judge, joint_tasks, settings.workers, say)
            hypotheses += joint
            joint_findings = [h for h in joint if h.significant]
            if not joint_findings:
                break
            chosen = min(joint_findings, key=information_criterion)
            others = [o for o in others if o.effects[0] not in chosen.effects]

    if chosen is not None:
        verdict, effects = "effect", chosen.effects
        final, final_model, delay = chosen.result, chosen.model, chosen.delay_s
    else:
        final, final_model, delay, effects = current, current_model, 0.0, ()
        verdict = "none"
    proposed: list[tuple[Proposal, Hypothesis]] = []
    terms: tuple[Term, ...] = ()
    if settings.propose:
        proposed = _propose_and_judge(
            model, fit_data, held_out, chosen, current, current_scores, fit_settings, say
        )
        passed = [h for _, h in proposed if h.significant]
        best = min(
            [*passed, *([chosen] if chosen else [])], key=information_criterion, default=None
        )
        if best is not None and best.terms:
            final, final_model, terms, delay = best.result, best.model, best.terms, best.delay_s
            effects = tuple(e for e in best.effects if e not in {t.name for t in best.terms})
            verdict = "effect" if effects else "proposed"
    diagnostics_after = diagnose(final) if final is not current else diagnostics_before
    prediction_after = (
        diagnose_prediction(
            delayed_inputs(fit_data, delay), final_model, final.states, settings.horizon_s
        )
        if final is not current
        else prediction_before
    )
    where = None
    if verdict == "none":
        where = where_misfit(diagnostics_before)
        if where is None and prediction_before.structured:
            where = prediction_before.where()
        elif where is not None and prediction_before.structured:
            where["also_structured"].append(PREDICTION_CHANNEL)
        if where is not None:
            verdict = "unexplained"
    say("gap on the held-out data ...")
    gap, channel_rms = _gap(held_out, current_model, final_model, delay, settings.horizon_s)
    return DiscrepancyResult(
        verdict=verdict,
        effects=tuple(effects),
        final=final,
        final_model=final_model,
        delay_s=delay,
        current=current,
        hypotheses=hypotheses,
        diagnostics_before=diagnostics_before,
        diagnostics_after=diagnostics_after,
        prediction_before=prediction_before,
        prediction_after=prediction_after,
        gap=gap,
        channel_rms=channel_rms,
        where=where,
        train_samples=len(fit_data.t),
        held_out_samples=len(held_out.t),
        held_out=held_out_label,
        time_s=time.perf_counter() - started,
        plane1_lag=plane1_lag,
        terms=terms,
        proposed=proposed,
    )


def _plane1_lag(
    data: Dataset,
    model: CarModel,
    current: FieResult,
    settings: DiscrepancySettings,
    say: Callable[[str], None],
) -> tuple[Dataset, FieResult, SweepLag]:
    """The training data with their first-plane sweep lag, the current model's fit at it, and
    the lag: estimated when unknown (no stream, none stated) and ``settings`` ask for it."""
    source = plane1_lag_source(data)
    if source == "dataset":
        return data, current, SweepLag(float(data.meta[PLANE1_LAG_KEY]), None, source)
    if source != "unknown":
        return data, current, SweepLag(None, None, source)
    if not settings.estimate_plane1_lag:
        return data, current, SweepLag(0.0, None, "taken as 0")
    say("no stream: fitting the first-plane sweep lag ...")
    lag, std, fit = estimate_plane1_lag(data, model, current, settings.identification)
    finite_std = std if math.isfinite(std) else None
    say(
        f"first-plane sweep lag {1e3 * lag:.1f} ms"
        + (f" ± {1e3 * std:.1f}" if finite_std is not None else "")
        + f"; FIE cost {current.cost:.6g} -> {fit.cost:.6g}"
    )
    return with_plane1_lag(data, lag), fit, SweepLag(lag, finite_std, "estimated")


#: A first-round task: one effect fitted on top of the current model, judged against it
#: (fit data, model, current fit, effects, settings, current scores, held-out data, tests).
_HypothesisTask = tuple[
    Dataset, CarModel, FieResult, tuple[str, ...], DiscrepancySettings, HeldOutScores, Dataset, int
]
#: A joint task: ``other``'s effect on top of the chosen hypothesis, judged against it
#: (model, chosen, other, delayed fit data, settings, chosen's scores, held-out data, tests).
_JointTask = tuple[
    CarModel, Hypothesis, Hypothesis, Dataset, DiscrepancySettings, HeldOutScores, Dataset, int
]
#: A term task: the proposed term on top of the chosen hypothesis (None: the current model),
#: judged against it (model, chosen, term, fit data, base fit, settings, base scores, held-out
#: data, tests).
_TermTask = tuple[
    CarModel,
    Hypothesis | None,
    Term,
    Dataset,
    FieResult,
    DiscrepancySettings,
    HeldOutScores,
    Dataset,
    int,
]
_Task = TypeVar("_Task", _HypothesisTask, _JointTask, _TermTask)


def _fit_and_judge(task: _HypothesisTask) -> Hypothesis:
    """Fit one hypothesis and judge it (a top-level function: it runs in worker processes)."""
    data, model, current, effects, settings, scores, held_out, tests = task
    hypothesis = fit_hypothesis(data, model, current, effects, settings.identification)
    return judge(hypothesis, scores, held_out, settings.test, tests)


def _fit_joint_and_judge(task: _JointTask) -> Hypothesis:
    """Fit one effect on top of the base hypothesis and judge it against the base."""
    model, base, other, data, settings, scores, held_out, tests = task
    hypothesis = _joint_hypothesis(model, base, other, data, settings)
    return judge(hypothesis, scores, held_out, settings.test, tests)


def _propose_and_judge(
    model: CarModel,
    fit_data: Dataset,
    held_out: Dataset,
    chosen: Hypothesis | None,
    current: FieResult,
    current_scores: HeldOutScores,
    settings: DiscrepancySettings,
    say: Callable[[str], None],
) -> list[tuple[Proposal, Hypothesis]]:
    """Terms proposed from what the final registry fit (``chosen``'s, else ``current``'s)
    leaves, each fitted on top of it and judged against it on the held-out data; with a
    chosen effect, also the terms proposed from what the current model's fit leaves, each fitted
    alone and judged against the current model (a term may explain what the effect only
    imitated, and leave nothing on top of it), which must also predict better than the effect
    to pass (:func:`_against_the_effect`)."""
    current_model = _fitted(model, current)
    bases: list[tuple[Hypothesis | None, Dataset, FieResult, HeldOutScores, CarModel]] = []
    if chosen is not None:
        scores = held_out_scores(
            held_out, chosen.model, settings.test.test_horizon_s, chosen.delay_s
        )
        data = delayed_inputs(fit_data, chosen.delay_s)
        bases.append((chosen, data, chosen.result, scores, chosen.model))
    bases.append((None, fit_data, current, current_scores, current_model))
    say("proposing terms beyond the registry ...")
    proposed = [
        (proposal, base) for base in bases for proposal in propose(base[1], base[4], base[2])
    ]
    if not proposed:
        say("no term to propose: what the fit leaves follows none of the library's monomials")
        return []
    tasks: list[_TermTask] = [
        (
            model,
            on_top,
            proposal.term(f"term{k + 1}"),
            data,
            fit,
            settings,
            scores,
            held_out,
            len(proposed),
        )
        for k, (proposal, (on_top, data, fit, scores, _)) in enumerate(proposed)
    ]
    say(f"{len(tasks)} proposed terms to test: " + "; ".join(t[2].equation() for t in tasks))
    judged = _run_hypotheses(_fit_term_and_judge, tasks, settings.workers, say)
    if chosen is not None:
        effect_scores = bases[0][3]
        for h in judged:
            if h.significant and not set(chosen.effects) <= set(h.effects):
                _against_the_effect(h, chosen, effect_scores, held_out, settings.test)
    return [(proposal, h) for (proposal, _), h in zip(proposed, judged, strict=True)]


def _against_the_effect(
    term: Hypothesis,
    chosen: Hypothesis,
    effect_scores: HeldOutScores,
    held_out: Dataset,
    test: TestSettings,
) -> None:
    """A term fitted without the named effect may replace it only if it predicts the held-out
    data better than the effect does (``effect_scores``; the same test, one comparison): else
    it is not a finding (a constant on the gyro is the registry's gyro bias by another name)."""
    horizon = test.test_horizon_s
    term_scores = held_out_scores(held_out, term.model, horizon, term.delay_s)
    comparison = compare_held_out(effect_scores, term_scores, horizon)
    if (
        comparison.p_value < test.false_alarm_rate
        and comparison.improvement >= test.min_improvement
    ):
        return
    term.significant = False
    term.reasons.append(
        f"predicts the held-out data no better than {'+'.join(chosen.effects)} "
        f"({100 * comparison.improvement:+.1f} %, p = {comparison.p_value:.2g})"
    )


def _fit_term_and_judge(task: _TermTask) -> Hypothesis:
    """Fit one proposed term (with the chosen effects' parameters, started at their fit) and
    judge it against its base."""
    model, chosen, term, data, base_fit, settings, scores, held_out, tests = task
    effects = tuple(e for e in chosen.effects if e != DELAY_EFFECT) if chosen else ()
    start = {
        name: float(entry["value"])
        for effect in effects
        for name, entry in chosen.parameters[effect].items()  # type: ignore[union-attr]
    }
    hypothesis = fit_hypothesis(
        data, model, base_fit, effects, settings.identification, start=start, terms=(term,)
    )
    if chosen is not None and chosen.delay_s:
        hypothesis.delay_s = chosen.delay_s
        hypothesis.parameters = {
            **hypothesis.parameters,
            DELAY_EFFECT: chosen.parameters[DELAY_EFFECT],
        }
        hypothesis.effects = (*chosen.effects, term.name)
        hypothesis.model = extended_model(
            hypothesis.model, [DELAY_EFFECT], {DELAY_EFFECT: chosen.delay_s}
        )
    return judge(hypothesis, scores, held_out, settings.test, tests)


def proposed_entry(hypothesis: Hypothesis, proposal: Proposal, accepted: bool) -> dict[str, Any]:
    """A proposed term's entry of ``report.json`` (``proposed_terms``)."""
    term = hypothesis.terms[0]
    fitted = hypothesis.parameters[term.name]
    values = [float(fitted[name]["value"]) for name in term.coefficient_names()]
    return {
        "name": term.name,
        "on_top_of": [e for e in hypothesis.effects if e != term.name],
        "target": term.target,
        "variables": term.variables(),
        "equation": term.equation(values),
        "coefficients": {
            name: {k: v for k, v in entry.items() if k != "z"} for name, entry in fitted.items()
        },
        "held_out": hypothesis.comparison.to_dict() if hypothesis.comparison else None,
        "significant": hypothesis.significant,
        "reasons": hypothesis.reasons,
        "accepted": accepted,
        "regression": proposal.to_dict(),
    }


def _slow_to_fit(effect: str) -> bool:
    """The input delay (a profile of fits) and the time constants (stiff near their null
    value) take several times longer to fit than an offset or a gain."""
    return effect == DELAY_EFFECT or any(null_value(p) != 0.0 for p in EFFECTS[effect].parameters)


def _asked_for(hypothesis: Hypothesis, min_z: float) -> bool:
    """Every effect added has a parameter at least ``min_z`` std from its null value."""
    return all(clear_of_null(values, min_z) for values in hypothesis.parameters.values())


def _run_hypotheses(
    work: Callable[[_Task], Hypothesis],
    tasks: Sequence[_Task],
    workers: int,
    say: Callable[[str], None],
) -> list[Hypothesis]:
    """``work`` over ``tasks`` on ``workers`` processes, in task order; one progress line per
    hypothesis as it finishes."""
    if workers <= 1 or len(tasks) <= 1:
        done = []
        for i, task in enumerate(tasks, 1):
            done.append(work(task))
            say(_line(i, len(tasks), done[-1]))
        return done
    results: dict[int, Hypothesis] = {}
    with ProcessPoolExecutor(max_workers=min(workers, len(tasks))) as pool:
        futures = {pool.submit(work, task): k for k, task in enumerate(tasks)}
        for i, future in enumerate(as_completed(futures), 1):
            results[futures[future]] = future.result()
            say(_line(i, len(tasks), results[futures[future]]))
    return [results[k] for k in range(len(tasks))]


def _joint_hypothesis(
    model: CarModel,
    base: Hypothesis,
    other: Hypothesis,
    data: Dataset,
    settings: DiscrepancySettings,
) -> Hypothesis:
    """``other``'s effect on top of ``base``, its parameters starting at ``other``'s fit (the
    input delay, when part of either, kept at its fitted value: ``data`` is already delayed by
    ``base``'s)."""
    state_effects = tuple(e for e in base.effects if e != DELAY_EFFECT)
    new = other.effects[0]
    if new == DELAY_EFFECT:
        data = delayed_inputs(data, other.delay_s)
        joint = fit_hypothesis(data, model, base.result, state_effects, settings.identification)
        joint.delay_s = other.delay_s
        joint.parameters = {**joint.parameters, **other.parameters}
    else:
        start = {p: float(e["value"]) for p, e in other.parameters[new].items()}
        joint = fit_hypothesis(
            data, model, base.result, (*state_effects, new), settings.identification, start=start
        )
        if base.delay_s:
            joint.delay_s = base.delay_s
            joint.parameters = {**joint.parameters, DELAY_EFFECT: base.parameters[DELAY_EFFECT]}
    joint.effects = (*base.effects, new)
    return joint


def _fitted(model: CarModel, result: FieResult) -> CarModel:
    return model.with_parameters(result.parameters)


def _gap(
    held_out: Dataset,
    current: CarModel,
    final: CarModel,
    delay_s: float,
    horizon_s: float,
) -> tuple[dict[str, float | None], dict[str, dict[str, float | None]]]:
    """Held-out open-loop position RMSE and per-channel RMS of the current and final models."""
    horizon = min(horizon_s, 0.5 * float(held_out.t[-1] - held_out.t[0]))
    before, _ = validate(held_out, current, current.parameters, horizon_s=horizon)
    after, _ = validate(
        delayed_inputs(held_out, delay_s), final, final.parameters, horizon_s=horizon
    )
    return (
        {
            "before": before["position_rmse_m"]["identified"],
            "after": after["position_rmse_m"]["identified"],
            "horizon_s": horizon,
        },
        {
            "before": before["channel_rms"]["identified"],
            "after": after["channel_rms"]["identified"],
        },
    )


def _line(i: int, n: int, h: Hypothesis) -> str:
    c = h.comparison
    verdict = "FINDING" if h.significant else "no"
    values = ", ".join(
        f"{p} = {float(e['value']):.4g} ± {float(e['std']):.2g} {e['unit']}"
        for effect in h.parameters.values()
        for p, e in effect.items()
    )
    held = f"held-out {100 * c.improvement:+.1f} %, p = {c.p_value:.2g}" if c is not None else ""
    return f"discrepancy: [{i}/{n}] {'+'.join(h.effects):28s} {values}; {held} -> {verdict}"
