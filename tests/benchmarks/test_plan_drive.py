"""Tests of ``crs bench plan-drive``'s pieces (the run itself takes minutes: not here)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.plan_drive import (
    OPEN,
    REPORTED,
    TRUTH_TAU_MOTOR,
    RaceThenDrive,
    beats,
    format_table,
    truth_model,
)
from benchmarks.workflow import truth_parameters
from crs_core.discrepancy.drive_design import DesignSettings, slalom_drive
from crs_core.track import load_demo_track


def test_the_truth_is_issue_27s_car_with_a_motor_lag() -> None:
    truth = truth_model()
    assert truth.parameters.value("tau_motor") == TRUTH_TAU_MOTOR
    for name, value in truth_parameters().items():
        assert truth.parameters.value(name) == pytest.approx(value)


def test_the_drive_follows_the_race_in_one_recording() -> None:
    track = load_demo_track()
    drive = slalom_drive(DesignSettings(duration_s=2.0), OPEN, track, 0.2, 1.5)
    controller = RaceThenDrive(track, 0.09, 5.0, drive)
    x = track.start_state(1.0)
    race = RaceThenDrive(track, 0.09, 5.0, None)
    assert np.allclose(controller(1.0, x), race(1.0, x))
    assert controller.drive is not None and controller.drive.t_start == 5.0


def _case(sigma: float) -> dict:
    row = {"truth": 1.0, "fitted": 1.0, "error": 0.0, "sigma_fie": sigma}
    return {
        "parameters": {n: {**row, "sigma_predicted": sigma} for n in REPORTED},
        "drive_on_truth": {
            "grip_used_max": {"front": 0.9, "rear": 0.6},
            "peak_slip_fraction_max": {"front": 0.6, "rear": 0.3},
            "max_lateral_error_m": 0.1,
            "track_half_width_m": 0.23,
            "lighthouse_fraction": 1.0,
        },
        "drive_on_model": {"limited_by": ["track"]},
    }


def test_the_verdict_and_the_table() -> None:
    cases = {"race": _case(0.3), "race_designed": _case(0.1), "race_slalom": _case(0.2)}
    verdict = beats(cases)
    assert verdict["sigma_fie"]["designed_better"] and verdict["sigma_predicted"]["designed_better"]
    text = format_table({"cases": cases, "designed_beats_slalom": verdict})
    assert "| Dr |" in text and "limited by track" in text and "FIE True" in text
