"""Tests of ``crs bench plan-drive-stack``'s pieces (the run itself launches stacks for
minutes: not here)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks.plan_drive import OPEN, REPORTED, TRUTH_TAU_MOTOR
from benchmarks.plan_drive_stack import drive_began, format_table, parameter_rows, sysid_argv
from crs_core.discrepancy.drive_design import DesignSettings, slalom_drive
from crs_core.track import load_demo_track


def _drive():
    return slalom_drive(DesignSettings(duration_s=4.0), OPEN, load_demo_track(), 0.2, 1.5)


def test_the_drive_begins_at_the_first_pass_of_its_start_after_the_lead_in() -> None:
    drive = _drive()
    x0, y0, yaw0, vx0 = drive.start
    t = np.arange(0.0, 50.0, 0.5)
    x = np.zeros((len(t), 6))
    x[:, :4] = [x0 + 5.0, y0, yaw0, vx0]  # elsewhere
    at_start = [x0 + 0.05, y0, yaw0 + 0.3, vx0]
    x[np.searchsorted(t, 10.0)] = [*at_start, 0.0, 0.0]  # in the lead-in: not yet
    x[np.searchsorted(t, 36.0)] = [*at_start, 0.0, 0.0]
    x[np.searchsorted(t, 40.0)] = [*at_start, 0.0, 0.0]
    slow = np.searchsorted(t, 33.0)
    x[slow] = [x0, y0, yaw0, 0.5 * vx0, 0.0, 0.0]  # there, but too slow
    track = load_demo_track()
    assert drive_began(drive, track, t, x, 30.0) == 36.0
    assert drive_began(drive, track, t, x, 45.0) is None


def test_parameter_rows_compare_sysid_with_the_truth(tmp_path: Path) -> None:
    fitted = {n: {"value": 2.0, "std": 0.1} for n in REPORTED}
    fitted["tau_motor"] = {"value": 1.1 * TRUTH_TAU_MOTOR, "std": 0.01}
    (tmp_path / "result.json").write_text(json.dumps({"parameters": fitted}))
    rows = parameter_rows(tmp_path / "result.json")
    assert set(rows) == set(REPORTED)
    assert rows["tau_motor"]["truth"] == TRUTH_TAU_MOTOR
    assert rows["tau_motor"]["error"] == pytest.approx(0.1)
    assert rows["tau_motor"]["sigma"] == 0.01


def test_sysid_opens_the_motor_lag() -> None:
    argv = sysid_argv(Path("data"), Path("fit"))
    assert argv[:2] == ["sysid", "data"] and "motor_lag" in argv and argv[-2:] == ["--out", "fit"]


def _case(race: float, after: float, outside: float) -> dict:
    def rows(sigma: float) -> dict:
        return {"parameters": {n: {"sigma": sigma, "error": 0.02} for n in OPEN}}

    return {
        "drive_began_s": 34.0,
        "footprint_outside_max_m": outside,
        "race": rows(race),
        "race_plus_drive": rows(after),
    }


def test_the_table_shows_each_drives_change_of_sigma() -> None:
    result = {
        "cases": {"designed": _case(0.02, 0.01, -0.03), "slalom": _case(0.02, 0.019, 0.004)},
        "predicted_by_plan_drive": {n: {"before": 0.02, "after": 0.012} for n in OPEN},
    }
    table = format_table(result)
    assert "| designed | 0.02 → 0.01 (-50%; error +2.0%)" in table
    assert "| slalom | 0.02 → 0.019 (-5%" in table
    assert "3.0 cm inside" in table and "0.4 cm outside" in table
    assert "tau_motor 0.02 → 0.012" in table
