"""The adaptation benchmark's judging: where an online parameter is judged, its truth from the
emulator's log, the figures and the table (its races are ``crs bench adaptation``'s)."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.adaptation import (
    SCHEDULES,
    _judged,
    _truth_of,
    format_markdown,
    parameter_figures,
    plot,
)
from crs_core.estimation.base import OnlineValue
from crs_core.model import CarModel
from sim.drift import DriftSchedule, parse_drift

ISSUE = parse_drift(SCHEDULES["issue"])


def test_a_parameter_is_judged_from_ten_seconds_after_its_changes_end():
    since = np.arange(0.0, 120.0, 1.0)
    cm1 = since[_judged("Cm1", since, ISSUE, 120.0)]  # ramp 10..100 s
    assert cm1.min() == 110.0 and cm1.max() == 119.0
    grip = since[_judged("grip", since, ISSUE, 120.0)]  # step at 60 s
    assert list(grip[:2]) == [10.0, 11.0] and 59.0 in grip and 60.0 not in grip
    assert 69.0 not in grip and 70.0 in grip
    bias = since[_judged("gyro_bias", since, ISSUE, 120.0)]  # step at 30 s
    assert 29.0 in bias and 35.0 not in bias and 40.0 in bias


def test_the_truth_comes_from_the_drift_log_or_the_car():
    t = np.array([0.0, 1.0, 2.0])
    log = {"t": t, "drift_Df": np.array([0.6, 0.6, 0.51]), "drift_Cm1": np.array([1.0, 0.9, 0.8])}
    assert _truth_of("grip", log, np.array([0.5, 2.0])) == pytest.approx([1.0, 0.85])
    assert _truth_of("Cm1", log, np.array([1.5])) == pytest.approx([0.85])
    assert _truth_of("gyro_bias", log, np.array([1.0])) == pytest.approx([0.0])
    assert _truth_of("Cm1", {"t": t}, np.array([1.0]))[0] == CarModel().parameters.value("Cm1")


def test_estimates_are_scored_within_tolerance_and_inside_two_sigma():
    """Cm1 truth 1.0 throughout: estimates 1.02 (within 5 %) with std 0.005 (truth outside
    ±2σ) for the judged time after 10 s; a schedule without Cm1 changes judges it from 10 s."""
    schedule = parse_drift({"drift": [{"effect": "gyro_bias", "at_s": 100, "value": 0.05}]})
    stamps = 1000.0 + np.arange(0.0, 20.0, 1.0 / 60.0)
    estimates = [(s, {"Cm1": OnlineValue(1.02, 0.005, True)}) for s in stamps]
    truth = {"t": stamps, "drift_Cm1": np.ones(stamps.size)}
    figures = parameter_figures(estimates, truth, 1000.0, schedule)["Cm1"]
    assert figures["within_tolerance"] == 1.0 and figures["inside_2sigma"] == 0.0
    assert figures["max_error"] == pytest.approx(0.02) and figures["judged_s"] == pytest.approx(
        10.0
    )
    assert figures["final"]["from_prior_sigmas"] == 0.0  # the first estimate is the prior
    assert figures["course"]["t_s"][:3] == [0.0, 1.0, 2.0] and len(figures["course"]["t_s"]) == 20


def test_a_car_that_does_not_change_is_judged_from_ten_seconds_on():
    since = np.arange(0.0, 30.0, 1.0)
    for name in ("Cm1", "gyro_bias", "grip"):
        assert since[_judged(name, since, DriftSchedule(()), 30.0)].min() == 10.0


def test_the_table_has_a_row_per_schedule_and_mode_and_per_online_parameter(tmp_path):
    def row(online: bool) -> dict:
        figures = {
            "within_tolerance": 0.9,
            "inside_2sigma": 0.95,
            "max_error": 0.04,
            "final": {"from_prior_sigmas": 0.8},
            "course": {"t_s": [0.0, 1.0], "value": [1.0, 0.9], "std": [0.1, 0.05], "truth": [1, 1]},
        }
        return {
            "schedule": "issue",
            "online": online,
            "laps": 16,
            "mean_flying_lap_s": 6.6,
            "mean_flying_lap_after_grip_change_s": 6.9,
            "contouring_rms_m": 0.08,
            "contouring_max_m": 0.17,
            "off_track": {"seconds": 0.0},
            "motor_cutoffs": 0,
            "estimation_rmse": {"x": 0.001, "y": 0.0012},
            **({"parameters": {"Cm1": figures}} if online else {}),
        }

    result = {
        "repeats": 1,
        "duration_s": 120.0,
        "link": "typical",
        "online_parameters": ["Cm1", "gyro_bias", "grip"],
        "schedules": {"issue": SCHEDULES["issue"]},
        "tolerances": {"Cm1": ["rel", 0.05], "grip": ["rel", 0.1], "gyro_bias": ["abs", 0.01]},
        "settle_s": 10.0,
        "rows": [row(False), row(True)],
    }
    text = format_markdown(result)
    assert "| issue | no | 16 | 6.60 s | 6.90 s | 80 / 170 mm | 0.00 s | 0 | 1.0 / 1.2 mm |" in text
    assert "| issue | yes |" in text
    assert "| issue | Cm1 | 5 % | 90 % | 95 % | 0.04 | 0.8 σ |" in text
    assert "the estimators' default noise" in text
    fitted = format_markdown(result | {"noise": {"process_std": [0.0006] * 3 + [1.0, 1.0, 6.0]}})
    assert "process noise fitted to a steady race of the car (x, y, yaw: 0.0006; default 0.02)" in (
        fitted
    )
    plot(result, tmp_path / "adaptation.png")
    assert (tmp_path / "adaptation.png").stat().st_size > 10_000
