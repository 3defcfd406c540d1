"""Tests of how far a drive got (crs_core.discrepancy.drive_reach)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.discrepancy.drive_design import (
    DesignSettings,
    base_drive,
    evaluate_drive,
    planned_fit,
    prior_covariance,
)
from crs_core.discrepancy.drive_reach import drive_summary, slip_used
from crs_core.model import CarModel
from crs_core.model.bicycle import peak_slip
from crs_core.track import load_demo_track


def test_the_peak_slip_fraction_is_one_at_the_curves_peak() -> None:
    model = CarModel()
    value = model.parameters.value
    peak = peak_slip(value("Cr"), value("Br"))
    vx = 1.5
    x = np.array([[0.0, 0.0, 0.0, vx, -vx * math.tan(peak), 0.0]])  # rear slip = the peak
    front, rear = slip_used(x, np.zeros((1, 2)), model)[0]
    assert rear == pytest.approx(1.0, rel=1e-6)
    assert front == pytest.approx(peak / peak_slip(value("Cf"), value("Bf")), rel=1e-6)


def test_a_gentle_drive_is_limited_by_nothing_and_tells_its_sigma() -> None:
    model, track = CarModel(), load_demo_track()
    settings = DesignSettings(duration_s=2.0, segment_s=1.0, process_scale=0.1)
    fit = planned_fit(model, ("Dr", "Br"))
    drive = base_drive(settings, ("Dr", "Br"), track)
    design = evaluate_drive(
        model, drive, fit, ("Dr", "Br"), prior_covariance(model, fit), track, settings
    )
    summary = drive_summary(design, model, track, settings.track_margin)
    assert summary["limited_by"] == [] and summary["in_view_fraction"] == 1.0
    assert summary["max_lateral_error_m"] < summary["lateral_limit_m"]
    for row in summary["sigma"].values():
        assert row["after"] <= row["before"] and row["ratio"] == row["after"] / row["before"]
    assert 0.0 < summary["peak_slip_fraction_max"]["rear"] < 0.5
