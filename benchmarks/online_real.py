"""Online parameters on the two real recordings (``crs bench online-real``).

Each run is estimated offline with ``Cm1`` and ``gyro_bias`` online (the MHE, every sensor the
run has, the recorded commands; the Chronos parameters with the run's Lighthouse geometry), and
what the two parameters do over the run is summarised: their value and standard deviation at
the start, the middle and the end, their range, and the share of the run the data inform each.
The values at the end of one run are then tried on the other: its held-out open-loop prediction
over 2 s (:func:`~crs_core.identification.validation.validate`, the paper's metric, the
reference the car's own on-line estimate) with the model's own values and with the online ones;
the position RMSE says what ``Cm1`` changes and the gyro channel's RMS what the bias changes
(a sensor offset does not move the car). A figure per run draws each parameter with its ±2σ band.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.machine import REAL_DATA

#: The real runs, in order.
RUNS = ("fie_mpc_lighthouse_1", "fie_mpc_lighthouse_2")
#: What is estimated online.
ONLINE = ("Cm1", "gyro_bias")
#: The estimator.
ESTIMATOR = "mhe"


def online_run(run: str, plots: Path | None = None) -> dict[str, Any]:
    """One run estimated with :data:`ONLINE` online: their course over the run (and its
    figure in ``plots``)."""
    from crs_core.dataset import Dataset
    from crs_core.estimation import MheSettings
    from crs_core.estimation.offline import estimate_dataset

    dataset = Dataset.load(REAL_DATA / run)
    settings = MheSettings(online_parameters=ONLINE)
    result = estimate_dataset(dataset, ESTIMATOR, settings=settings)
    track = result.online
    since = result.t - result.t[0]
    priors = result.estimator.model.online.priors
    out: dict[str, Any] = {"duration_s": round(float(since[-1]), 2), "parameters": {}}
    for i, name in enumerate(track.names):
        known = np.flatnonzero(np.isfinite(track.value[i]))
        value = track.value[i, known]
        marks = {
            label: known[int(fraction * (len(known) - 1))]
            for label, fraction in (("start", 0.0), ("middle", 0.5), ("end", 1.0))
        }
        out["parameters"][name] = {
            **{
                label: {
                    "t_s": round(float(since[k]), 2),
                    "value": round(float(track.value[i, k]), 5),
                    "std": round(float(track.std[i, k]), 5),
                }
                for label, k in marks.items()
            },
            "range": [round(float(value.min()), 5), round(float(value.max()), 5)],
            "informed_share": round(float(np.mean(track.informed[i, known])), 3),
            "prior": priors[name][0],
            "prior_std": priors[name][1],
        }
    if plots is not None:
        plots.mkdir(parents=True, exist_ok=True)
        _figure(since, track, run, plots / f"online_{run}.png")
    return out


def held_out(train: dict[str, Any], test_run: str) -> dict[str, Any]:
    """The held-out 2 s prediction of ``test_run`` with the model's own values and with the
    values ``train`` (an :func:`online_run`) ended with."""
    from crs_core.dataset import Dataset
    from crs_core.estimation.offline import dataset_model
    from crs_core.identification.validation import validate

    dataset = Dataset.load(REAL_DATA / test_run)
    model = dataset_model(dataset, effects={"gyro_bias": None}, values={"gyro_bias": 0.0})
    ended = {name: entry["end"]["value"] for name, entry in train["parameters"].items()}
    online = model.parameters.updated(ended)
    summary, _ = validate(dataset, model, online, model.parameters)
    return {
        "values": ended,
        "position_rmse_m": _rounded(summary["position_rmse_m"]),
        "position_rmse_at_horizon_m": _rounded(summary["position_rmse_at_horizon_m"]),
        "gyro_rms_rad_s": _rounded(
            {label: channels["yaw_rate"] for label, channels in summary["channel_rms"].items()}
        ),
        "starts": summary["starts"],
    }


def _rounded(values: dict[str, float | None]) -> dict[str, float | None]:
    return {k: None if v is None else round(float(v), 5) for k, v in values.items()}


def online_real_benchmark(plots: Path | None = None) -> dict[str, Any]:
    """``crs bench online-real``: both runs with online parameters, each one's end values
    tried on the other run (JSON-ready)."""
    runs = {}
    for run in RUNS:
        print(f"[bench] {run}: {ESTIMATOR} with {', '.join(ONLINE)} online", flush=True)
        runs[run] = online_run(run, plots)
    cross = {}
    for train, test in ((RUNS[0], RUNS[1]), (RUNS[1], RUNS[0])):
        print(f"[bench] the end values of {train} on {test}: held-out 2 s prediction", flush=True)
        cross[f"{train} -> {test}"] = held_out(runs[train], test)
    return {"estimator": ESTIMATOR, "online_parameters": list(ONLINE), "runs": runs, "cross": cross}


def _figure(since: np.ndarray, track: Any, run: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(track.names), 1, figsize=(7, 2.4 * len(track.names)), sharex=True)
    for ax, i in zip(np.atleast_1d(axes), range(len(track.names)), strict=True):
        value, std = track.value[i], track.std[i]
        ax.fill_between(since, value - 2 * std, value + 2 * std, alpha=0.25, label="±2σ")
        ax.plot(since, value, lw=1.2, label="online estimate")
        ax.set_ylabel(track.names[i])
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].legend(loc="best", fontsize=8)
    np.atleast_1d(axes)[-1].set_xlabel("t since the run's first sample, s")
    fig.suptitle(f"{run}: online parameters ({ESTIMATOR})")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def format_markdown(result: dict[str, Any]) -> str:
    """The course of each online parameter per run, and the held-out predictions."""
    lines = [
        f"{result['estimator'].upper()}, online: {', '.join(result['online_parameters'])}.",
        "",
        "| run | parameter | prior (σ) | start | middle | end (σ) | range | informed |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for run, entry in result["runs"].items():
        for name, p in entry["parameters"].items():
            lines.append(
                f"| {run} | {name} | {p['prior']:.4g} ({p['prior_std']:.3g}) | "
                f"{p['start']['value']:.4g} | {p['middle']['value']:.4g} | "
                f"{p['end']['value']:.4g} ({p['end']['std']:.2g}) | "
                f"{p['range'][0]:.4g} .. {p['range'][1]:.4g} | {100 * p['informed_share']:.0f} % |"
            )
    lines += [
        "",
        "Held out: the other run's open-loop prediction over 2 s with the model's values and with"
        " the end values of the online run (position RMSE over the horizon / at its end; the"
        " gyro channel's RMS):",
        "",
        "| values of | on | Cm1, gyro_bias | position RMSE | at 2 s | gyro RMS |",
        "|---|---|---|---|---|---|",
    ]
    for pair, entry in result["cross"].items():
        train, _, test = pair.partition(" -> ")
        values = ", ".join(f"{v:.4g}" for v in entry["values"].values())
        rmse, end, gyro = (
            entry[key]
            for key in ("position_rmse_m", "position_rmse_at_horizon_m", "gyro_rms_rad_s")
        )
        lines.append(
            f"| {train} | {test} | {values} | "
            f"{1e3 * rmse['prior']:.1f} → {1e3 * rmse['identified']:.1f} mm | "
            f"{1e3 * end['prior']:.1f} → {1e3 * end['identified']:.1f} mm | "
            f"{gyro['prior']:.4f} → {gyro['identified']:.4f} rad/s |"
        )
    return "\n".join(lines)
