"""Figures of the discrepancy report.

:func:`hypotheses_figure` (``hypotheses.png``), :func:`gap_figure` (``gap.png``) and
:func:`residuals_figure` (``residuals.png``), written by
:func:`~crs_core.discrepancy.report.write_discrepancy_report`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from crs_core.analysis.figures import clip_to_band
from crs_core.dataset import Y_CHANNELS
from crs_core.discrepancy.hypotheses import Hypothesis
from crs_core.discrepancy.residuals import CHANNEL_UNITS, ChannelDiagnosis, fie_residuals
from crs_core.discrepancy.workflow import DiscrepancyResult
from crs_core.identification.solve import FieResult

#: Display unit and factor from the channel unit in the residual figure.
DISPLAY_UNITS = {"rad": ("mrad", 1e3), "rad/s": ("rad/s", 1.0)}
#: Colours of the current and the final model in every figure.
COLOURS = {"current": "tab:orange", "final": "tab:blue"}


def hypotheses_figure(result: DiscrepancyResult, path: Path, chosen: Hypothesis | None) -> None:
    """Bar chart of each hypothesis' held-out improvement (%), with its p-value.

    Green: significant (a finding); outlined: ``chosen``, the hypothesis the verdict names.
    """
    hypotheses = result.hypotheses
    n = max(len(hypotheses), 1)
    fig = Figure(figsize=(8, 0.45 * n + 1.6))
    ax = fig.subplots()
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


def gap_figure(summary: dict[str, Any], path: Path) -> None:
    """Held-out open-loop RMS of the final model relative to the current one, per channel,
    and the held-out position RMSE of both (``summary``: the summary of ``report.json``)."""
    before, after = summary["residual_rms_before"] or {}, summary["residual_rms_after"] or {}
    names = [n for n in Y_CHANNELS if before.get(n) and after.get(n) is not None]
    fig = Figure(figsize=(13, 4.5))
    ax, ax_pos = fig.subplots(1, 2, gridspec_kw={"width_ratios": [4, 1]})
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
    ax.set_title(f"Per channel, {format_number(horizon, 'g')} s open-loop predictions", fontsize=9)
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
        ax_pos.set_title(f"{format_number(horizon, 'g')} s open-loop position RMSE", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def residuals_figure(result: DiscrepancyResult, path: Path) -> None:
    """Residual (measured - model) of the training fit over time, per channel group, for the
    current and (when different) the final model, against the noise floor."""
    fits = {"current": result.current}
    if result.final is not result.current:
        fits["final"] = result.final
    series = {label: _group_series(fit) for label, fit in fits.items()}
    channels = [n for n, e in series["current"][0].items() if np.isfinite(e).any()]
    diagnoses: dict[str, dict[str, ChannelDiagnosis]] = {
        "current": {d.channel: d for d in result.diagnostics_before},
        "final": {d.channel: d for d in result.diagnostics_after},
    }
    fig = Figure(figsize=(12, 2.4 * max(len(channels), 1) + 0.6))
    axes = fig.subplots(max(len(channels), 1), 1, sharex=True, squeeze=False)
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


def format_number(value: Any, form: str = ".3g") -> str:
    """``value`` formatted with ``form``; ``"n/a"`` for None or a non-finite float."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    return format(value, form)
