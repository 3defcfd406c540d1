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

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import yaml

from crs_core.analysis.figures import clip_to_band
from crs_core.dataset import Y_CHANNELS, plain
from crs_core.discrepancy.hypotheses import DELAY_EFFECT, Hypothesis
from crs_core.discrepancy.residuals import CHANNEL_UNITS, ChannelDiagnosis, fie_residuals
from crs_core.discrepancy.workflow import DiscrepancyResult
from crs_core.identification.report import write_params_yaml
from crs_core.identification.solve import FieResult
from crs_core.model import CarModel

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
#: Display unit and factor from the channel unit in the residual figure.
DISPLAY_UNITS = {"rad": ("mrad", 1e3), "rad/s": ("rad/s", 1.0)}
#: Colours of the current and the final model in every figure.
COLOURS = {"current": "tab:orange", "final": "tab:blue"}
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
    _hypotheses_figure(result, folder / "hypotheses.png")
    _gap_figure(summary, folder / "gap.png")
    _residuals_figure(result, folder / "residuals.png")
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
    document = yaml.safe_load(text)
    entries = document["parameters"]
    delay = _named_delay(result)
    if delay is not None and DELAY_EFFECT not in entries:
        value, std = delay
        entry = CarModel({DELAY_EFFECT: {DELAY_EFFECT: value}}).parameters.to_dict()[DELAY_EFFECT]
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
    body = yaml.safe_dump({"parameters": entries}, sort_keys=False)
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
        ``effect``, ``**No effect needed** — ...`` for ``none`` and ``**Unexplained misfit in
        <channel> when <regressor> in [low, high] <unit>** — ...`` for ``unexplained``.
    """
    summary = summary if summary is not None else result.summary()
    gap = _gap_text(summary)
    if result.verdict == "effect":
        values = "; ".join(
            f"{name.replace('_', ' ')} = {_value_std(entry)}"
            for effect in summary["parameters"].values()
            for name, entry in effect.items()
        )
        chosen = _chosen(result)
        if gap is None and chosen is not None and chosen.comparison is not None:
            gap = f"held-out prediction score {100 * chosen.comparison.improvement:+.1f} %"
        parts = [p for p in (values, gap) if p]
        return f"**Finding: {' + '.join(result.effects)}** — " + "; ".join(parts)
    tried = len({h.effects for h in result.hypotheses if len(h.effects) == 1})
    if result.verdict == "unexplained" and result.where is not None:
        w = result.where
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
        "predictions significantly, and the current model's residuals show no structure"
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


def _number(value: Any, form: str = ".3g") -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return format(value, form)


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
        + f"; {summary['time_s']:.0f} s.",
        "",
        "## Hypotheses",
        "",
        "Each candidate effect is added to the current model, fitted on the training data (FIE) "
        "and tested on the held-out data: improvement = relative decrease of the open-loop "
        "prediction error (every channel group weighted equally), p = one-sided paired block "
        "t-test. A finding needs a small p, a practical improvement and every effect parameter "
        "clearly away from 'no effect'.",
        "",
        "| effects | fitted parameters (± std) | held-out improvement | p | verdict |",
        "|---|---|---|---|---|",
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
        lines.append(
            f"| {' + '.join(h.effects)} | {values or '—'} | "
            f"{_number(None if improvement is None else 100 * improvement, '+.1f')} % | "
            f"{_number(held.get('p_value'), '.2g')} | {verdict} |"
        )
    lines += ["", "## Gap on the held-out data", ""]
    horizon = summary.get("gap_horizon_s")
    lines += [
        "| | current model | final model |",
        "|---|---|---|",
        f"| {_number(horizon, 'g')} s open-loop position RMSE (m) | "
        f"{_number(summary['gap_before'], '.4f')} | {_number(summary['gap_after'], '.4f')} |",
    ]
    before, after = summary["residual_rms_before"] or {}, summary["residual_rms_after"] or {}
    for name in before:
        unit = "rad" if name.startswith("lh_") else "rad/s"
        lines.append(
            f"| {name} open-loop RMS ({unit}) | {_number(before.get(name), '.3g')} | "
            f"{_number(after.get(name), '.3g')} |"
        )
    lines += ["", "## Residual diagnostics of the training fit", ""]
    lines += _diagnostics_table(summary, result)
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
    fits = [("current", summary["diagnostics_before"])]
    if not same:
        fits.append(("final", summary["diagnostics_after"]))
    rows = {}
    for label, diagnoses in fits:
        for d in diagnoses:
            rows.setdefault(d["channel"], []).append((label, d))
    for channel, entries in rows.items():
        for label, d in entries:
            lines.append(
                f"| {channel} | {label} | {_number(d['rms'])} {CHANNEL_UNITS.get(channel, '')} | "
                f"{_number(d['normalized_rms'], '.2f')} | "
                f"{_number(d['lag1_autocorrelation'], '.2f')} | "
                f"{_number(d['whiteness_p'], '.2g')} | {_number(d['regime_r2'], '.3f')} | "
                f"{d['strongest_regressor']} | {'**yes**' if d['structured'] else 'no'} |"
            )
    return lines


def _hypotheses_figure(result: DiscrepancyResult, path: Path) -> None:
    hypotheses = result.hypotheses
    n = max(len(hypotheses), 1)
    fig, ax = plt.subplots(figsize=(8, 0.45 * n + 1.6))
    chosen = _chosen(result)
    rows = np.arange(len(hypotheses))
    values = np.array([100 * h.comparison.improvement if h.comparison else 0.0 for h in hypotheses])
    colours = ["tab:green" if h.significant else "0.65" for h in hypotheses]
    edges = ["black" if h is chosen else "none" for h in hypotheses]
    ax.barh(rows, values, color=colours, edgecolor=edges, linewidth=1.5)
    span = max(float(np.max(np.abs(values))) if len(values) else 1.0, 1.0)
    for row, value, h in zip(rows, values, hypotheses, strict=True):
        note = "not tested" if h.comparison is None else f"p = {h.comparison.p_value:.2g}"
        ax.annotate(
            note,
            (value, row),
            xytext=(4 if value >= 0 else -4, 0),
            textcoords="offset points",
            ha="left" if value >= 0 else "right",
            va="center",
            fontsize=8,
        )
    ax.axvline(0.0, color="0.3", lw=0.8)
    low = float(values.min(initial=0.0))
    ax.set_xlim(low - (0.25 if low < 0 else 0.02) * span, 1.3 * span)
    ax.set_yticks(rows, ["+".join(h.effects) for h in hypotheses])
    ax.invert_yaxis()
    ax.set_xlabel("held-out improvement of the open-loop prediction error (%)")
    ax.set_title(
        f"Hypotheses (green: finding, outlined: named); verdict: {result.verdict}", fontsize=9
    )
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _gap_figure(summary: dict[str, Any], path: Path) -> None:
    before, after = summary["residual_rms_before"] or {}, summary["residual_rms_after"] or {}
    names = [n for n in Y_CHANNELS if before.get(n) and after.get(n) is not None]
    fig, (ax, ax_pos) = plt.subplots(1, 2, figsize=(13, 4.5), gridspec_kw={"width_ratios": [4, 1]})
    x = np.arange(len(names))
    ratio = np.array([after[n] / before[n] for n in names])
    ax.bar(x - 0.2, np.ones(len(names)), 0.4, color=COLOURS["current"], label="current model")
    ax.bar(x + 0.2, ratio, 0.4, color=COLOURS["final"], label="final model")
    for xi, r in zip(x, ratio, strict=True):
        ax.annotate(f"{100 * r:.0f} %", (xi + 0.2, r), ha="center", va="bottom", fontsize=7)
    ax.set_xticks(x, names, rotation=45, ha="right", fontsize=8)
    ax.set_ylabel("held-out open-loop RMS / current model's")
    ax.axhline(1.0, color="0.3", lw=0.6, ls="--")
    ax.set_ylim(0.0, max(1.3, 1.15 * float(ratio.max(initial=1.0))))
    ax.legend(fontsize=8, loc="upper left", ncol=2)
    horizon = summary.get("gap_horizon_s")
    ax.set_title(f"Per channel, {_number(horizon, 'g')} s open-loop predictions", fontsize=9)
    gap = [summary.get("gap_before"), summary.get("gap_after")]
    if None in gap:
        ax_pos.text(0.5, 0.5, "no position reference\nin the held-out data", ha="center")
        ax_pos.axis("off")
    else:
        bars = ax_pos.bar([0, 1], gap, color=[COLOURS["current"], COLOURS["final"]], width=0.6)
        for bar, value in zip(bars, gap, strict=True):
            ax_pos.annotate(
                f"{value:.3f}",
                (bar.get_x() + bar.get_width() / 2, value),
                ha="center",
                va="bottom",
                fontsize=8,
            )
        ax_pos.set_xticks([0, 1], ["current", "final"])
        ax_pos.set_ylabel("position RMSE (m)")
        ax_pos.set_title(f"{_number(horizon, 'g')} s open-loop position RMSE", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _group_series(result: FieResult) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Per channel group, the residual averaged over the group's measured columns (NaN where
    none is measured), and the noise floor."""
    residuals, floors = fie_residuals(result)
    series = {}
    for name, e in residuals.items():
        measured = np.isfinite(e).any(axis=1)
        average = np.full(len(e), np.nan)
        if measured.any():
            average[measured] = np.nanmean(e[measured], axis=1)
        series[name] = average
    return series, floors


def _residuals_figure(result: DiscrepancyResult, path: Path) -> None:
    fits = {"current": result.current}
    if result.final is not result.current:
        fits["final"] = result.final
    series = {label: _group_series(fit) for label, fit in fits.items()}
    channels = [n for n, e in series["current"][0].items() if np.isfinite(e).any()]
    diagnoses: dict[str, dict[str, ChannelDiagnosis]] = {
        "current": {d.channel: d for d in result.diagnostics_before},
        "final": {d.channel: d for d in result.diagnostics_after},
    }
    fig, axes = plt.subplots(
        max(len(channels), 1),
        1,
        figsize=(12, 2.4 * max(len(channels), 1) + 0.6),
        sharex=True,
        squeeze=False,
    )
    t0 = float(result.current.t[0])
    for ax, channel in zip(axes[:, 0], channels, strict=False):
        unit, factor = DISPLAY_UNITS.get(CHANNEL_UNITS.get(channel, ""), ("", 1.0))
        floor = factor * series["current"][1][channel]
        errors, parts = [], []
        for label, fit in fits.items():
            e = factor * series[label][0][channel]
            t = fit.t - t0
            ok = np.isfinite(e)
            ax.plot(t[ok], e[ok], lw=0.7, color=COLOURS[label], label=f"{label} model fit")
            errors.append(e[ok])
            d = diagnoses[label].get(channel)
            if d is not None:
                parts.append(f"{label} RMS {factor * d.rms:.3g} {unit}")
        t = result.current.t - t0
        ax.fill_between(
            t, -floor, floor, color="0.5", alpha=0.2, lw=0, label="± noise floor (sensor σ)"
        )
        off_scale = clip_to_band(ax, errors, [np.full(1, floor)], unit)
        ax.axhline(0.0, color="0.3", lw=0.5)
        ax.set_ylabel(f"{channel}\n[{unit}]", fontsize=8)
        title = ", ".join(parts) + (f"   ({off_scale})" if off_scale else "")
        ax.set_title(title, loc="left", fontsize=8)
    if channels:
        axes[0, 0].legend(fontsize=7, loc="upper right", ncol=3)
    axes[-1, 0].set_xlabel("time (s)")
    fig.suptitle(
        "Residual (measured - model) of the training fit, mean over each group's channels",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
