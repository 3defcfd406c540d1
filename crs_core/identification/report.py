"""Files written by ``crs sysid`` and ``crs validate``: YAML, JSON, markdown and figures.

``params.yaml`` holds every model parameter as a full entry (loadable with
:meth:`~crs_core.parameters.ParameterSet.updated_from_yaml`); the fitted ones carry their
identified standard deviation as ``prior_std`` (so the file can be the prior of a later run)
and a comment line with the prior and the verdict.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from matplotlib.figure import Figure

from crs_core.dataset import Y_CHANNELS
from crs_core.identification.solve import FieResult
from crs_core.identification.validation import OpenLoopPrediction


def result_summary(result: FieResult) -> dict[str, Any]:
    """JSON-ready summary (``result.json``)."""
    u = result.uncertainty
    parameters = {}
    for i, name in enumerate(result.fit):
        p = result.prior[name]
        parameters[name] = {
            "value": float(result.theta[i]),
            "std": float(u.std[i]),
            "identifiable": bool(u.identifiable[i]),
            "reason": u.reasons[i],
            "prior": float(result.theta_prior[i]),
            "prior_std": float(result.theta_prior_std[i]),
            "unit": p.unit,
            "lower": p.lower,
            "upper": p.upper,
        }
    residuals = (result.outputs - result.data.y) * (result.data.weight > 0)
    channel_rms = {}
    for c, name in enumerate(Y_CHANNELS):
        used = result.data.weight[:, c] > 0
        channel_rms[name] = float(np.sqrt(np.mean(residuals[used, c] ** 2))) if used.any() else None
    return {
        "parameters": parameters,
        "cost": result.cost,
        "cost_initial": result.cost_initial,
        "cost_terms": result.cost_terms,
        "iterations": result.iterations,
        "time_s": result.time_s,
        "build_s": result.build_s,
        "solve_s": result.solve_s,
        "time_per_iteration_s": result.time_per_iteration_s,
        "solver_status": result.solver_status,
        "hessian": result.settings.hessian,
        "process_scale": result.settings.process_scale,
        "samples": len(result.t),
        "sensors": result.data.channels_present,
        "starts": result.starts,
        "warnings": u.warnings(),
        "correlation": {"names": list(result.fit), "matrix": u.correlation.round(4).tolist()},
        "fit_channel_rms": channel_rms,
    }


def write_params_yaml(result: FieResult, path: Path) -> Path:
    """The model (``model:``, its spec) and every parameter as a full entry; fitted ones with
    their identified std."""
    entries = result.parameters.to_dict()
    lines = ["# Identified by crs sysid (FIE). Fitted parameters: prior -> identified +- std."]
    for i, name in enumerate(result.fit):
        std = float(result.uncertainty.std[i])
        entries[name]["prior_std"] = std
        verdict = "identifiable" if result.uncertainty.identifiable[i] else "NOT identifiable"
        lines.append(
            f"# {name}: {result.theta_prior[i]:.6g} -> {result.theta[i]:.6g} +- {std:.3g} "
            f"{result.prior[name].unit} ({verdict})"
        )
    document = {"model": result.model, "parameters": entries}
    text = "\n".join(lines) + "\n" + yaml.safe_dump(document, sort_keys=False)
    path.write_text(text)
    return path


def write_sysid_report(result: FieResult, folder: Path, dataset_name: str) -> dict[str, Any]:
    """``params.yaml``, ``result.json``, ``report.md`` and the figures into ``folder``."""
    summary = result_summary(result)
    summary["dataset"] = dataset_name
    write_params_yaml(result, folder / "params.yaml")
    (folder / "result.json").write_text(json.dumps(summary, indent=2))
    _fit_figure(result, folder / "fit.png")
    _residual_figure(result, folder / "residuals.png")
    _parameter_figure(result, folder / "parameters.png")
    _correlation_figure(result, folder / "correlation.png")
    rows = [
        "| parameter | unit | prior | identified | std | identifiable |",
        "|---|---|---|---|---|---|",
    ]
    for name, entry in summary["parameters"].items():
        flag = "yes" if entry["identifiable"] else f"**no**: {entry['reason']}"
        rows.append(
            f"| {name} | {entry['unit']} | {entry['prior']:.6g} | {entry['value']:.6g} | "
            f"{entry['std']:.3g} | {flag} |"
        )
    text = [
        f"# System identification of {dataset_name}",
        "",
        f"{summary['samples']} samples, sensors {', '.join(summary['sensors'])}; "
        f"Hessian {summary['hessian']}; IPOPT {summary['solver_status']} after "
        f"{summary['iterations']} iterations; {summary['time_s']:.1f} s "
        f"({summary['build_s']:.1f} s building, {summary['time_per_iteration_s'] * 1e3:.0f} ms "
        "per iteration).",
        "",
        f"Cost V: {summary['cost_initial']:.6g} (estimator trajectory, prior parameters) -> "
        f"{summary['cost']:.6g}; terms: "
        + ", ".join(f"{k} {v:.4g}" for k, v in summary["cost_terms"].items()),
        "",
        *rows,
        "",
        "Standard deviations: Laplace approximation (Gauss-Newton curvature, states and process "
        "noise eliminated).",
        "",
        *(f"- WARNING: {w}" for w in summary["warnings"]),
        "",
        "![fit](fit.png)",
        "![residuals](residuals.png)",
        "![parameters](parameters.png)",
        "![correlation](correlation.png)",
        "",
    ]
    (folder / "report.md").write_text("\n".join(text))
    return summary


def _fit_figure(result: FieResult, path: Path) -> None:
    t = result.t - result.t[0]
    fig = Figure(figsize=(14, 14))
    axes = fig.subplots(5, 3, sharex=True)
    for c, (name, ax) in enumerate(zip(Y_CHANNELS, axes.ravel(), strict=False)):
        used = result.data.weight[:, c] > 0
        ax.plot(t[used], result.data.y[used, c], ".", ms=2, color="0.5", label="measured")
        ax.plot(t, result.outputs[:, c], lw=0.8, color="tab:blue", label="FIE fit")
        ax.set_title(name, fontsize=9)
    axes.ravel()[0].legend(fontsize=8)
    for ax in axes.ravel()[len(Y_CHANNELS) :]:
        ax.axis("off")
    fig.supxlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)


def _residual_figure(result: FieResult, path: Path) -> None:
    fig = Figure(figsize=(12, 12))
    axes = fig.subplots(5, 3)
    for c, (name, ax) in enumerate(zip(Y_CHANNELS, axes.ravel(), strict=False)):
        used = result.data.weight[:, c] > 0
        residual = (result.outputs[used, c] - result.data.y[used, c]) * result.data.weight[used, c]
        ax.hist(residual, bins=50, color="tab:blue")
        ax.set_title(f"{name} (residual / sigma)", fontsize=9)
    for ax in axes.ravel()[len(Y_CHANNELS) :]:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=80)


def _parameter_figure(result: FieResult, path: Path) -> None:
    n = len(result.fit)
    fig = Figure(figsize=(8, 0.4 * n + 1.5))
    ax = fig.subplots()
    rows = np.arange(n)
    scale = np.where(result.theta_prior != 0, np.abs(result.theta_prior), 1.0)
    ax.errorbar(
        result.theta_prior / scale,
        rows + 0.15,
        xerr=result.theta_prior_std / scale,
        fmt="o",
        color="0.5",
        label="prior ± σ",
    )
    colours = ["tab:blue" if ok else "tab:red" for ok in result.uncertainty.identifiable]
    ax.errorbar(
        result.theta / scale,
        rows - 0.15,
        xerr=result.uncertainty.std / scale,
        fmt="none",
        # one colour per bar: matplotlib hands ecolor to a LineCollection, which takes a list
        # (its stubs declare a single colour)
        ecolor=colours,  # type: ignore[arg-type]
    )
    ax.scatter(
        result.theta / scale, rows - 0.15, c=colours, label="identified ± σ (red: not identifiable)"
    )
    ax.set_yticks(rows, result.fit)
    ax.set_xlabel("value / prior value")
    ax.invert_yaxis()
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)


def _correlation_figure(result: FieResult, path: Path) -> None:
    n = len(result.fit)
    fig = Figure(figsize=(0.45 * n + 2, 0.45 * n + 1.5))
    ax = fig.subplots()
    image = ax.imshow(result.uncertainty.correlation, vmin=-1, vmax=1, cmap="RdBu_r")
    ax.set_xticks(range(n), result.fit, rotation=90)
    ax.set_yticks(range(n), result.fit)
    fig.colorbar(image, ax=ax, label="correlation")
    fig.tight_layout()
    fig.savefig(path, dpi=80)


def write_validation_report(
    summary: dict[str, Any],
    predictions: dict[str, OpenLoopPrediction],
    reference: np.ndarray,
    folder: Path,
) -> None:
    """``validation.json`` and ``validation.png`` (predicted vs reference trajectories)."""
    (folder / "validation.json").write_text(json.dumps(summary, indent=2))
    fig = Figure(figsize=(8, 7))
    ax = fig.subplots()
    ax.plot(reference[:, 0], reference[:, 1], color="0.3", lw=1.5, label="reference")
    colours = {"prior": "tab:orange", "identified": "tab:blue"}
    for label, prediction in predictions.items():
        every = max(1, len(prediction.starts) // 15)
        for i, _ in enumerate(prediction.starts[::every]):
            track = prediction.positions[i * every]
            ax.plot(
                track[:, 0],
                track[:, 1],
                color=colours.get(label, "tab:green"),
                lw=0.9,
                label=f"{label} ({summary['position_rmse_m'][label]:.3f} m)" if i == 0 else None,
            )
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    short = (
        "simulation truth"
        if summary["reference"] == "simulation truth"
        else ("Lighthouse-based on-line estimate, not motion capture")
    )
    ax.set_title(
        f"{summary['horizon_s']:g} s open-loop predictions (position RMSE); reference: {short}",
        fontsize=9,
    )
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(folder / "validation.png", dpi=90)
    lines = [
        "# Open-loop validation",
        "",
        f"Horizon {summary['horizon_s']} s, {summary['starts']} starts. Reference: "
        f"{summary['reference']}.",
        "",
        "| parameters | position RMSE (m) | at horizon end (m) |",
        "|---|---|---|",
        *(
            f"| {label} | {summary['position_rmse_m'][label]:.4f} | "
            f"{summary['position_rmse_at_horizon_m'][label]:.4f} |"
            for label in summary["position_rmse_m"]
        ),
        "",
        summary["metric"],
        "",
        "![validation](validation.png)",
        "",
    ]
    (folder / "validation.md").write_text("\n".join(lines))
