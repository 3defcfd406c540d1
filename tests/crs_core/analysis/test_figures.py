"""Tests of crs_core.analysis.figures: y limits of the error bands, panel titles, status shading."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure

from crs_core.analysis.figures import (
    STATUS_COLOURS,
    band_limit,
    clip_to_band,
    draw_error_panel,
    error_legend_handles,
    label_band_panel,
    shade_status_strip,
)
from crs_core.analysis.metrics import band_statistics


def test_band_limit_ignores_a_short_peak():
    """One huge error and one huge sigma (before the first fix) do not set the scale."""
    error = np.r_[np.full(199, 1.0), 500.0]
    sigma = np.r_[np.full(199, 1.0), 1000.0]
    assert band_limit([error], [sigma]) == pytest.approx(1.15 * 2.0)


def test_clip_to_band_names_the_off_scale_peaks_in_the_title():
    """The limits are symmetric; the peaks beyond them are named with their unit, next to the
    RMSE and the ±2σ fraction."""
    ax = Figure().add_subplot()
    error = np.r_[np.full(199, 1.0), 2500.0]
    sigma = np.r_[np.full(199, 1.0), np.nan]
    note = clip_to_band(ax, [error], [sigma], "mm")
    assert ax.get_ylim() == pytest.approx((-2.3, 2.3))
    assert note == "off-scale peaks: max |error| 2500 mm"
    label_band_panel(ax, "x", "mm", [("", band_statistics(error, sigma))], note)
    assert ax.get_ylabel() == "x error [mm]"
    assert ax.get_title(loc="left").endswith(
        "% inside ±2σ   (off-scale peaks: max |error| 2500 mm)"
    )
    assert clip_to_band(ax, [np.ones(5)], [np.ones(5)], "mm") == ""


def test_status_is_shaded_up_to_the_next_stamp():
    """One span per run of degraded or lost samples, from its first stamp to the next run's;
    none for ok."""
    ax = Figure().add_subplot()
    t = np.arange(6.0)
    shade_status_strip(ax, t, np.array(["ok", "degraded", "degraded", "lost", "ok", "ok"]))
    spans = [(p.get_x(), p.get_x() + p.get_width()) for p in ax.patches]
    assert spans == [(1.0, 3.0), (3.0, 4.0)]
    colours = [p.get_facecolor()[:3] for p in ax.patches]
    assert colours == [to_rgb(STATUS_COLOURS["degraded"]), to_rgb(STATUS_COLOURS["lost"])]


def test_error_panel_and_its_legend():
    """The panel: band, error line, zero line, status strip, grid, the limits' note; the legend
    names the reference (none without one), the band and each shaded status."""
    ax = Figure().add_subplot()
    t = np.arange(200.0)
    status = np.array(["ok", "lost"] + ["ok"] * 198)
    error = np.r_[1.0, np.nan, np.full(197, 1.0), 500.0]
    note = draw_error_panel(ax, t, error, np.ones(200), status, "mm")
    assert note == "off-scale peaks: max |error| 500 mm"
    assert len(ax.lines) == 2 and len(ax.collections) == 1 and len(ax.patches) == 1
    labels = [h.get_label() for h in error_legend_handles("truth", status_prefix="status ")]
    assert labels[0] == "estimate − truth" and labels[2] == "status degraded (bottom strip)"
    assert len(error_legend_handles(None)) == 1 + len(STATUS_COLOURS)
