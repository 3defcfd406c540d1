"""Files written by ``crs discrepancy``: JSON, markdown, the final model's YAML and figures.

:func:`write_discrepancy_report` writes into one folder

* ``report.json``: :meth:`~crs_core.discrepancy.workflow.DiscrepancyResult.summary` plus the
  dataset names and the headline, strict JSON (a NaN or an infinity is ``null``);
* ``report.md``: the verdict in plain words on its first line, then every hypothesis, the
  held-out gap, the residual diagnostics before and after, the figures and how to use the result;
* ``params.yaml``: the final model's parameters in the format of ``crs sysid``
  (:func:`~crs_core.identification.report.write_params_yaml`, loadable with ``--params``); the
  named effects' parameters are in it, so every command infers the effects from the file (a
  named ``input_delay``, fitted through the data rather than the model, is added as an entry);
* ``hypotheses.png``, ``gap.png``, ``residuals.png``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import yaml

from crs_core.dataset import plain
from crs_core.discrepancy.figures import (
    format_number,
    gap_figure,
    hypotheses_figure,
    residuals_figure,
)
from crs_core.discrepancy.hypotheses import DELAY_EFFECT, Hypothesis, information_criterion
from crs_core.discrepancy.prediction import COHERENCE_MAX, PREDICTION_CHANNEL
from crs_core.discrepancy.residuals import CHANNEL_UNITS
from crs_core.discrepancy.sweep_lag import SweepLag
from crs_core.discrepancy.workflow import DiscrepancyResult
from crs_core.identification.report import write_params_yaml
from crs_core.model import CarModel
from crs_core.yaml_io import load_yaml

#: Units of the regime regressors of :func:`crs_core.discrepancy.residuals.regime_regressors`.
REGRESSOR_UNITS = {
    "vx": "m/s",
    "steering": "rad",
    "abs_steering": "rad",
    "yaw_rate": "rad/s",
    "abs_yaw_rate": "rad/s",
    "torque": "(normalised)",
    "acceleration": "m/s²",
    "time": "s",
}
#: The commands whose ``--params`` takes the written ``params.yaml``.
PARAMS_COMMANDS = ("crs sysid", "crs validate", "crs sim", "crs estimate")


def write_discrepancy_report(
    result: DiscrepancyResult, folder: Path, train_name: str, held_out_name: str | None
) -> dict[str, Any]:
    """Write the report of :func:`~crs_core.discrepancy.workflow.find_discrepancy`.

    Parameters
    ----------
    result : DiscrepancyResult
        What the workflow found.
    folder : pathlib.Path
        Output folder (created if missing).
    train_name : str
        Name of the training dataset (its folder), for the report.
    held_out_name : str or None
        Name of the held-out dataset; None when the held-out data are the end of the training
        run (the summary's ``held_out`` says which part).

    Returns
    -------
    dict
        The summary written to ``report.json`` (JSON builtins, non-finite numbers as None):
        ``result.summary()`` plus ``train_dataset``, ``held_out_dataset`` and ``headline`` (the
        first line of ``report.md``).
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    summary = result.summary()
    summary["train_dataset"] = train_name
    summary["held_out_dataset"] = held_out_name
    summary["headline"] = headline(result, summary)
    summary = plain(summary, nonfinite_as_none=True)
    (folder / "report.json").write_text(json.dumps(summary, indent=2, allow_nan=False) + "\n")
    write_final_params(result, folder / "params.yaml")
    hypotheses_figure(result, folder / "hypotheses.png", _chosen(result))
    gap_figure(summary, folder / "gap.png")
    residuals_figure(result, folder / "residuals.png")
    (folder / "report.md").write_text(_markdown(result, summary, folder))
    return summary


def write_final_params(result: DiscrepancyResult, path: Path) -> Path:
    """The final model's parameters as ``crs sysid`` writes them, with the named effects'.

    :func:`~crs_core.identification.report.write_params_yaml` of the final fit (every
    parameter a full entry, the fitted ones with their identified std as ``prior_std`` and a
    comment with prior -> identified), under a header naming the verdict. A named
    ``input_delay`` (not part of the final fit: the commands were shifted instead) is added
    with its fitted value and std, so ``--params`` infers it too.

    Parameters
    ----------
    result : DiscrepancyResult
    path : pathlib.Path
        The YAML file to write.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    write_params_yaml(result.final, path)
    text = path.read_text()
    comments = [line for line in text.splitlines() if line.startswith("#")][1:]
    document = load_yaml(text)
    entries = document["parameters"]
    delay = _named_delay(result)
    if delay is not None and DELAY_EFFECT not in entries:
        value, std = delay
        delayed = CarModel({DELAY_EFFECT: {DELAY_EFFECT: value}}, model=result.final.model)
        entry = delayed.parameters.to_dict()[DELAY_EFFECT]
        if math.isfinite(std) and std > 0:
            entry["prior_std"] = std
        entries[DELAY_EFFECT] = entry
        comments.append(f"# {DELAY_EFFECT}: {value:.6g} +- {std:.3g} s (commands shifted)")
    named = " + ".join(result.effects) if result.effects else "no effect named"
    header = [
        f"# Final model of crs discrepancy (verdict: {result.verdict}; {named}).",
        "# Load it with --params on crs sysid / validate / sim / estimate (effects inferred).",
        "# Fitted parameters: prior -> identified +- std.",
    ]
    document = {"model": result.final.model, "parameters": entries}
    if result.terms:
        header.append("# Terms proposed from the data (coefficients: <name>_c1, ...):")
        header += [f"#   {term.equation()}" for term in result.terms]
        document = {
            "model": result.final.model,
            "terms": [term.to_dict() for term in result.terms],
            "parameters": entries,
        }
    body = yaml.safe_dump(document, sort_keys=False)
    path.write_text("\n".join(header + comments) + "\n" + body)
    return path


def headline(result: DiscrepancyResult, summary: dict[str, Any] | None = None) -> str:
    """The verdict in plain words (the first line of ``report.md``).

    Parameters
    ----------
    result : DiscrepancyResult
    summary : dict, optional
        ``result.summary()`` (computed when not given).

    Returns
    -------
    str
        ``**Finding: <effects>** — <parameter> = value ± std unit; held-out ...`` for
        ``effect`` (with a term proposed beside it, when one was), ``**Proposed term:
        <equation>** — ...`` for ``proposed``, ``**No effect needed** — ...`` for ``none`` and
        ``**Unexplained misfit in <channel> when <regressor> in [low, high] <unit>** — ...``
        (or ``**Unexplained: open-loop predictions miss coherently ...**``) for
        ``unexplained``.
    """
    summary = summary if summary is not None else result.summary()
    gap = _gap_text(summary)
    accepted = [entry for entry in summary["proposed_terms"] if entry["accepted"]]
    if result.verdict == "proposed":
        entry = accepted[0]
        held = entry["held_out"]
        text = (
            f"**Proposed term: {entry['equation']}** — none of the registry's effects explains "
            f"the data; this term, found by sparse regression on what the fit leaves, predicts "
            f"{100 * held['improvement']:.1f} % better held out (p = {held['p_value']:.2g}): a "
            "term that predicts better, not a proof of physics"
        )
        return text + (f"; {gap}" if gap else "")
    if result.verdict == "effect":
        values = "; ".join(
            f"{name.replace('_', ' ')} = {_value_std(entry)}"
            for effect in summary["parameters"].values()
            for name, entry in effect.items()
        )
        chosen = _chosen(result)
        if gap is None and chosen is not None and chosen.comparison is not None:
            gap = f"held-out prediction score {100 * chosen.comparison.improvement:+.1f} %"
        beside = f"and the proposed term {accepted[0]['equation']}" if accepted else None
        parts = [p for p in (values, beside, gap) if p]
        return f"**Finding: {' + '.join(result.effects)}** — " + "; ".join(parts)
    tried = len({h.effects for h in result.hypotheses if len(h.effects) == 1})
    if result.verdict == "unexplained" and result.where is not None:
        w = result.where
        if w["channel"] == PREDICTION_CHANNEL:
            d = result.prediction_before
            text = (
                f"**Unexplained: open-loop predictions miss coherently, most when "
                f"{w['regressor']} in [{w['low']:.3g}, {w['high']:.3g}] "
                f"{REGRESSOR_UNITS.get(w['regressor'], '')}** — over {d.horizon_s:g} s from the "
                f"fit's states they miss by {1e3 * d.gap:.1f} mm, {d.coherence:.2f}× the "
                f"{1e3 * d.shuffled_gap:.1f} mm of the same drive with the fit's process "
                "residuals shuffled, while the measurement residuals show no structure; none of "
                f"the {tried} candidate effects explains it on the held-out data"
            )
            return text + (f"; {gap}" if gap else "")
        unit = REGRESSOR_UNITS.get(w["regressor"], "")
        channel_unit = CHANNEL_UNITS.get(w["channel"], "")
        text = (
            f"**Unexplained misfit in {w['channel']} when {w['regressor']} in "
            f"[{w['low']:.3g}, {w['high']:.3g}] {unit}** — residual RMS there "
            f"{w['rms']:.3g} {channel_unit} (normalised RMS {w['normalized_rms']:.2g}, regime "
            f"R² {w['regime_r2']:.2f}); none of the {tried} candidate effects explains it on "
            "the held-out data"
        )
        return text + (f"; {gap}" if gap else "")
    text = (
        f"**No effect needed** — none of the {tried} candidate effects improves the held-out "
        "predictions significantly, the current model's residuals show no structure and its "
        "open-loop predictions miss no more coherently than noise"
    )
    return text + (f"; {gap}" if gap else "")


def _chosen(result: DiscrepancyResult) -> Hypothesis | None:
    """The hypothesis the verdict names (the last significant one with exactly its effects)."""
    named = [
        h for h in result.hypotheses if h.significant and tuple(h.effects) == tuple(result.effects)
    ]
    return named[-1] if named else None


def _named_delay(result: DiscrepancyResult) -> tuple[float, float] | None:
    """(value, std) of a named input delay, s; None when none is named."""
    if DELAY_EFFECT not in result.effects:
        return None
    chosen = _chosen(result)
    entry = chosen.parameters.get(DELAY_EFFECT, {}).get(DELAY_EFFECT) if chosen else None
    std = float(entry["std"]) if entry else math.inf
    return float(result.delay_s), std


def _gap_text(summary: dict[str, Any]) -> str | None:
    before, after = summary.get("gap_before"), summary.get("gap_after")
    if before is None or after is None:
        return None
    horizon = summary.get("gap_horizon_s") or 2.0
    if before == after:
        return f"held-out {horizon:g} s open-loop position RMSE {before:.3f} m"
    return f"held-out {horizon:g} s open-loop position RMSE {before:.3f} → {after:.3f} m"


def _value_std(entry: dict[str, Any]) -> str:
    value, std = entry.get("value"), entry.get("std")
    unit = entry.get("unit", "")
    if value is None:
        return "n/a"
    spread = f" ± {std:.2g}" if std is not None and math.isfinite(std) else " (std n/a)"
    return f"{value:.3g}{spread} {unit}".rstrip()


def _lag_sentence(lag: SweepLag) -> str:
    """The first-plane sweep lag of the fits, when it was not known from a stream."""
    if lag.source == "estimated" and lag.value_s is not None:
        spread = f" ± {1e3 * lag.std_s:.1f}" if lag.std_s is not None else ""
        return f" First-plane sweep lag (no stream): fitted, {1e3 * lag.value_s:.1f}{spread} ms."
    if lag.source == "dataset" and lag.value_s is not None:
        return f" First-plane sweep lag: {1e3 * lag.value_s:.1f} ms (stated by the dataset)."
    if lag.source == "taken as 0":
        return " First-plane sweep lag: unknown (no stream), taken as 0."
    return ""


def _markdown(result: DiscrepancyResult, summary: dict[str, Any], folder: Path) -> str:
    held_out = (
        f"{summary['held_out_dataset']} ({summary['held_out_samples']} samples)"
        if summary["held_out_dataset"]
        else f"the {summary['held_out']} ({summary['held_out_samples']} samples)"
    )
    lines = [
        summary["headline"],
        "",
        f"# Discrepancy analysis of {summary['train_dataset']}",
        "",
        f"Training data: {summary['train_dataset']} ({summary['train_samples']} samples); "
        f"held out: {held_out}. Verdict: **{result.verdict}**"
        + (f" ({', '.join(result.effects)})" if result.effects else "")
        + f"; {summary['time_s']:.0f} s."
        + _lag_sentence(result.plane1_lag),
        "",
        "## Hypotheses",
        "",
        "Each candidate effect is added to the current model, fitted on the training data (FIE) "
        "and tested on the held-out data: improvement = relative decrease of the open-loop "
        "prediction error (every channel group weighted equally), p = twice the smaller of two "
        "one-sided paired block tests (a t-test on the blocks' log ratios, a signed-rank test on "
        "their differences). A finding needs a small p, a practical improvement and, for every "
        "effect added, a parameter clearly away from 'no effect'. Of competing findings the one "
        "with the lowest Akaike criterion on the training data (ΔAIC: FIE cost plus twice the "
        "number of effect parameters, against the current model) is named.",
        "",
        "| effects | fitted parameters (± std) | ΔAIC (train) | held-out improvement | p "
        "| verdict |",
        "|---|---|---|---|---|---|",
    ]
    chosen = _chosen(result)
    for h, entry in zip(result.hypotheses, summary["hypotheses"], strict=True):
        values = "<br>".join(
            f"{name} = {_value_std(e)}"
            for effect in entry["parameters"].values()
            for name, e in effect.items()
        )
        held = entry["held_out"] or {}
        improvement = held.get("improvement")
        verdict = "**finding**" if h.significant else "no: " + "; ".join(h.reasons)
        if h is chosen:
            verdict += " (named)"
        aic = information_criterion(h) - result.current.cost
        lines.append(
            f"| {' + '.join(h.effects)} | {values or '—'} | {format_number(aic, '+.1f')} | "
            f"{format_number(None if improvement is None else 100 * improvement, '+.1f')} % | "
            f"{format_number(held.get('p_value'), '.2g')} | {verdict} |"
        )
    lines += ["", "## Gap on the held-out data", ""]
    horizon = summary.get("gap_horizon_s")
    lines += [
        "| | current model | final model |",
        "|---|---|---|",
        f"| {format_number(horizon, 'g')} s open-loop position RMSE (m) | "
        f"{format_number(summary['gap_before'], '.4f')} | "
        f"{format_number(summary['gap_after'], '.4f')} |",
    ]
    before, after = summary["residual_rms_before"] or {}, summary["residual_rms_after"] or {}
    for name in before:
        unit = "rad" if name.startswith("lh_") else "rad/s"
        lines.append(
            f"| {name} open-loop RMS ({unit}) | {format_number(before.get(name), '.3g')} | "
            f"{format_number(after.get(name), '.3g')} |"
        )
    lines += ["", "## Residual diagnostics of the training fit", ""]
    lines += _diagnostics_table(summary, result)
    lines += ["", "## Open-loop predictions from the training fit's states", ""]
    lines += _prediction_table(summary, result)
    lines += ["", "## Terms proposed beyond the registry", ""]
    lines += _proposed_table(summary)
    lines += [
        "",
        "## Figures",
        "",
        "![hypotheses](hypotheses.png)",
        "![gap](gap.png)",
        "![residuals](residuals.png)",
        "",
        "## How to use",
        "",
        f"`{folder}/params.yaml` holds the final model (the named effects inferred from it): "
        f"pass `--params {folder}/params.yaml` to "
        + ", ".join(f"`{c}`" for c in PARAMS_COMMANDS)
        + ".",
        "",
    ]
    return "\n".join(lines)


def _diagnostics_table(summary: dict[str, Any], result: DiscrepancyResult) -> list[str]:
    same = result.diagnostics_after is result.diagnostics_before
    lines = [
        "Residual = measured - model on the training data. Normalised RMS = RMS / assumed "
        "sensor sigma (about 1 for a good fit); whiteness p: Ljung-Box; regime R²: share of the "
        "residual explained by the driving regime (speed, steering, yaw rate, acceleration, "
        "time)." + (" No effect was named: the final model is the current one." if same else ""),
        "",
        "| channel | model | RMS | normalised RMS | lag-1 autocorr. | whiteness p | regime R² "
        "| strongest regressor | structured |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    fits = _current_and_final(summary, "diagnostics", same)
    rows: dict[str, list[tuple[str, dict[str, Any]]]] = {}  # channel -> (model, diagnosis)
    for label, diagnoses in fits:
        for d in diagnoses:
            rows.setdefault(d["channel"], []).append((label, d))
    for channel, entries in rows.items():
        for label, d in entries:
            lines.append(
                f"| {channel} | {label} | "
                f"{format_number(d['rms'])} {CHANNEL_UNITS.get(channel, '')} | "
                f"{format_number(d['normalized_rms'], '.2f')} | "
                f"{format_number(d['lag1_autocorrelation'], '.2f')} | "
                f"{format_number(d['whiteness_p'], '.2g')} | "
                f"{format_number(d['regime_r2'], '.3f')} | "
                f"{d['strongest_regressor']} | {'**yes**' if d['structured'] else 'no'} |"
            )
    return lines


def _prediction_table(summary: dict[str, Any], result: DiscrepancyResult) -> list[str]:
    same = result.prediction_after is result.prediction_before
    lines = [
        "Gap = position RMSE of predictions over the horizon from the fit's states, against "
        "them; shuffled = the same drive with the fit's process residuals in shuffled order "
        "(median and range); coherence = gap / shuffled (about 1 for white process noise, "
        "below for a right model; structured above "
        f"{COHERENCE_MAX:g}). Strongest: the error series (gap, or the signed miss along or "
        "across the heading) most correlated with a regime variable.",
        "",
        "| model | horizon | gap | shuffled | coherence | strongest (correlation) | structured |",
        "|---|---|---|---|---|---|---|",
    ]
    for label, d in _current_and_final(summary, "prediction", same):
        low, high = d["shuffled_range"]
        strongest = d["strongest"]
        lines.append(
            f"| {label} | {d['horizon_s']:g} s | {format_number(1e3 * d['gap'], '.3g')} mm | "
            f"{format_number(1e3 * d['shuffled_gap'], '.3g')} mm "
            f"[{format_number(1e3 * low, '.3g')}, {format_number(1e3 * high, '.3g')}] | "
            f"{format_number(d['coherence'], '.2f')} | {strongest['series']} with "
            f"{strongest['regressor']} ({format_number(strongest['correlation'], '+.2f')}) | "
            f"{'**yes**' if d['structured'] else 'no'} |"
        )
    return lines


def _proposed_table(summary: dict[str, Any]) -> list[str]:
    entries = summary["proposed_terms"]
    if not entries:
        return [
            "None: what the final fit leaves follows no monomial of the library (products of up "
            "to three of vx, vy, omega, steer, torque and t) enough to propose one, or "
            "`--no-propose`."
        ]
    lines = [
        "From what the final fit leaves (process residual rates of vx, vy, omega; the wheel "
        "speeds' and the gyro's residuals), a sparse regression on products of the model's "
        "variables proposes a term per target; each is fitted with the model and tested on the "
        "held-out data as an effect is. A term that passes predicts better, it is not a proof "
        "of physics.",
        "",
        "| target | regression (R²) | fitted term | held-out improvement | p | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for entry in entries:
        regression = entry["regression"]
        held = entry["held_out"] or {}
        improvement = held.get("improvement")
        verdict = "**finding**" if entry["significant"] else "no: " + "; ".join(entry["reasons"])
        if entry["accepted"]:
            verdict += " (added)"
        lines.append(
            f"| {entry['target']} | {' + '.join(regression['monomials'])} "
            f"({format_number(regression['r2'], '.2f')}) | {entry['equation']} | "
            f"{format_number(100 * improvement if improvement is not None else None, '+.1f')} % | "
            f"{format_number(held.get('p_value'), '.2g')} | {verdict} |"
        )
    return lines


def _current_and_final(summary: dict[str, Any], key: str, same: bool) -> list[tuple[str, Any]]:
    """``("current", summary[key_before])`` and, unless the final fit is the current one,
    ``("final", summary[key_after])``."""
    fits = [("current", summary[f"{key}_before"])]
    return fits if same else [*fits, ("final", summary[f"{key}_after"])]
