"""Drawing helpers shared by the error-over-time figures.

Used by the simulator report (``sim/report.py``), the ``crs estimate`` figure
(``launch_scripts/estimate_report.py``) and the ROS stack figure
(``launch_scripts/stack_plot.py``): an estimation error inside the estimator's own ±2σ band,
the panel's y limits and title with the numbers of
:func:`crs_core.analysis.metrics.band_statistics`, and the estimator's status shaded over time.

The helpers draw on matplotlib axes handed in; this module imports no matplotlib at import time
(the callers choose the backend; :func:`error_legend_handles` imports matplotlib's artists when
called).
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: The components of the error-over-time figures: name, unit and factor from SI.
ERROR_COMPONENTS = (("x", "mm", 1e3), ("y", "mm", 1e3), ("yaw", "mrad", 1e3))
#: Legend text of the ±2σ band in every error-over-time figure.
BAND_LABEL = "±2σ claimed by the estimator (≈95 % inside if consistent)"
#: Opacity of the ±2σ band.
BAND_ALPHA = 0.22
#: Colour of each estimator status that is shaded (``ok`` is not).
STATUS_COLOURS = {"degraded": "tab:orange", "lost": "tab:red"}
#: Colour of a single estimator's error and band (:func:`draw_error_panel`).
ESTIMATE_COLOUR = "tab:blue"


def draw_error_band(
    ax, t: np.ndarray, error: np.ndarray, sigma: np.ndarray, colour: str, label: str | None
) -> None:
    """The error over time (a line) inside its ±2σ band (a shaded area of the same colour).

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    t : numpy.ndarray
        (n,) times, s.
    error, sigma : numpy.ndarray
        (n,) error and claimed standard deviation, same unit. NaN in ``error`` leaves a gap in
        the line; NaN in ``sigma`` a gap in the band.
    colour : str
        Matplotlib colour of both.
    label : str or None
        Legend label of the line.
    """
    ax.fill_between(t, -2 * sigma, 2 * sigma, color=colour, alpha=BAND_ALPHA, lw=0)
    ax.plot(t, error, color=colour, lw=0.7, label=label)


def band_limit(errors: list[np.ndarray], sigmas: list[np.ndarray]) -> float:
    """A symmetric y limit that shows the bulk of the errors and bands.

    The 98th percentile of ``|error|`` and the 95th of ``2 sigma``, the larger one plus 15 %
    (1 where both are 0 or nothing is finite). Short peaks (a glitch, the huge uncertainty
    before the first fix) go off-scale instead of flattening everything; the panel says so
    (:func:`clip_to_band`).

    Parameters
    ----------
    errors, sigmas : list of numpy.ndarray
        Errors and claimed standard deviations of every line of a panel, same unit; NaN
        ignored.

    Returns
    -------
    float
        The limit, in their unit.
    """
    parts = [np.abs(e[np.isfinite(e)]) for e in errors]
    parts = [p for p in parts if p.size]
    bands = [2 * s[np.isfinite(s)] for s in sigmas]
    bands = [b for b in bands if b.size]
    limit = max([np.percentile(p, 98) for p in parts] + [np.percentile(b, 95) for b in bands])
    return 1.15 * limit if limit > 0 else 1.0


def clip_to_band(ax, errors: list[np.ndarray], sigmas: list[np.ndarray], unit: str) -> str:
    """Set the symmetric y limits of :func:`band_limit` on ``ax``.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    errors, sigmas : list of numpy.ndarray
        As for :func:`band_limit`.
    unit : str
        Their unit, for the note.

    Returns
    -------
    str
        ``"off-scale peaks: ..."`` naming the largest ``|error|`` and ``2 sigma`` beyond the
        limit, or "" when everything is inside.
    """
    limit = band_limit(errors, sigmas)
    ax.set_ylim(-limit, limit)
    peak = max([float(np.nanmax(np.abs(e))) for e in errors if np.isfinite(e).any()] + [0.0])
    peak_band = max([float(np.nanmax(2 * s)) for s in sigmas if np.isfinite(s).any()] + [0.0])
    notes = []
    if peak > limit:
        notes.append(f"max |error| {_number(peak)} {unit}")
    if peak_band > limit:
        notes.append(f"max 2σ {_number(peak_band)} {unit}")
    return "off-scale peaks: " + ", ".join(notes) if notes else ""


def label_band_panel(
    ax, name: str, unit: str, stats: list[tuple[str, dict[str, Any]]], off_scale: str = ""
) -> None:
    """The y label, and above the panel the RMSE, the ±2σ fraction and the off-scale note.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    name, unit : str
        Component (``"x"``) and the unit of its numbers (``"mm"``).
    stats : list of (str, dict)
        ``(who, band_statistics)`` pairs, one per car or estimator; ``who`` is "" for a single
        one, else a name (compact entries, four per line).
    off_scale : str
        The note of :func:`clip_to_band`.
    """
    ax.set_ylabel(f"{name} error [{unit}]")
    single = len(stats) == 1 and not stats[0][0]
    entries = []
    for who, st in stats:
        if st["rmse"] is None:
            entries.append(f"{who} no samples".strip())
            continue
        inside = (
            "no covariance"
            if st["inside_2sigma"] is None
            else f"{100 * st['inside_2sigma']:.1f} %" + (" inside ±2σ" if single else "")
        )
        rmse = f"RMSE {st['rmse']:.2f} {unit}" if single else f"{who} {st['rmse']:.2f} {unit}"
        entries.append(f"{rmse}, {inside}")
    if single:
        text = entries[0]
    else:
        rows = ["; ".join(entries[i : i + 4]) for i in range(0, len(entries), 4)]
        text = "RMSE, inside ±2σ: " + "\n".join(rows)
    ax.set_title(text + (f"   ({off_scale})" if off_scale else ""), loc="left", fontsize=8)


def shade_status_strip(
    ax, t: np.ndarray, status: np.ndarray, height: float = 0.05, alpha: float = 0.8
) -> None:
    """Shade where the estimator's status is ``degraded`` or ``lost`` (:data:`STATUS_COLOURS`).

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    t : numpy.ndarray
        (n,) stamps, s; each run of a status is shaded up to the next stamp.
    status : numpy.ndarray
        (n,) status per stamp (``"ok"``, ``"degraded"``, ``"lost"``).
    height : float
        Height of the shade from the bottom, as a fraction of the axes: the default strip
        leaves the ±2σ band visible; 1 shades the full height.
    alpha : float
        Opacity of the shade.
    """
    status = np.asarray(status).astype(str)
    edges = np.flatnonzero(status[1:] != status[:-1]) + 1
    for begin, end in zip(np.r_[0, edges], np.r_[edges, len(status)], strict=True):
        colour = STATUS_COLOURS.get(status[begin])
        if colour:
            right = t[min(end, len(t) - 1)]
            ax.axvspan(t[begin], right, ymin=0.0, ymax=height, color=colour, alpha=alpha, lw=0)


def draw_error_panel(
    ax, t: np.ndarray, error: np.ndarray, sigma: np.ndarray, status: np.ndarray, unit: str
) -> str:
    """One estimator's error panel: the error inside its ±2σ band (:func:`draw_error_band`, in
    :data:`ESTIMATE_COLOUR`), the zero line, the status strip (:func:`shade_status_strip`), the
    y limits (:func:`clip_to_band`) and a grid; the caller labels it (:func:`label_band_panel`).

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    t, error, sigma : numpy.ndarray
        As for :func:`draw_error_band`.
    status : numpy.ndarray
        As for :func:`shade_status_strip`.
    unit : str
        Unit of ``error`` and ``sigma``, for the note.

    Returns
    -------
    str
        The off-scale note of :func:`clip_to_band`.
    """
    draw_error_band(ax, t, error, sigma, ESTIMATE_COLOUR, None)
    ax.axhline(0.0, color="0.3", lw=0.6)
    shade_status_strip(ax, t, status)
    off_scale = clip_to_band(ax, [error], [sigma], unit)
    ax.grid(alpha=0.3)
    return off_scale


def error_legend_handles(reference: str | None, status_prefix: str = "") -> list[Any]:
    """Legend entries of the panels of :func:`draw_error_panel`.

    Parameters
    ----------
    reference : str or None
        What the error is measured against (``"simulation truth"``): the line's label is
        ``estimate − REFERENCE``; None: no line (no reference, only the band).
    status_prefix : str
        Put before each shaded status's name (``"status "``).

    Returns
    -------
    list of matplotlib.artist.Artist
        The line (with a reference), the ±2σ band and each status of :data:`STATUS_COLOURS`.
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles: list[Any] = []
    if reference is not None:
        label = f"estimate − {reference}"
        handles.append(Line2D([], [], color=ESTIMATE_COLOUR, lw=0.7, label=label))
    handles.append(Patch(color=ESTIMATE_COLOUR, alpha=BAND_ALPHA, label=BAND_LABEL))
    handles += [
        Patch(color=colour, alpha=0.8, label=f"{status_prefix}{status} (bottom strip)")
        for status, colour in STATUS_COLOURS.items()
    ]
    return handles


def _number(value: float) -> str:
    """3 significant digits without an exponent below 10⁶ (``2000``, ``13.2``, ``0.412``)."""
    return f"{value:.0f}" if 1000 <= abs(value) < 1e6 else f"{value:.3g}"
