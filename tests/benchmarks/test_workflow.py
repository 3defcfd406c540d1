"""benchmarks.workflow: the emulated car's truth, the parameter comparison and the table, from
hand-made inputs (the day itself runs as ``crs bench workflow``, minutes long)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from benchmarks.workflow import (
    RECOVERED_WITHIN,
    TRUTH_FACTORS,
    format_table,
    parameter_recovery,
    stiffness_errors,
    truth_parameters,
)
from crs_core.identification.problem import DEFAULT_FIT
from crs_core.model import CarModel


def test_the_car_differs_from_the_defaults_by_10_to_20_percent():
    defaults = CarModel().parameters
    for name, value in truth_parameters().items():
        assert 0.1 <= abs(value / defaults.value(name) - 1.0) <= 0.2 + 1e-9, name
    assert set(truth_parameters()) == set(TRUTH_FACTORS) <= set(DEFAULT_FIT)


def _params_file(path: Path, scale: dict[str, float]) -> Path:
    """A params.yaml as crs sysid writes it (entries with value), the truth times ``scale``."""
    defaults, truth = CarModel().parameters, truth_parameters()
    entries = {
        name: {"value": truth.get(name, defaults.value(name)) * scale.get(name, 1.0)}
        for name in DEFAULT_FIT
    }
    path.write_text(yaml.safe_dump({"parameters": entries}))
    return path


def test_parameter_recovery_compares_with_the_truth(tmp_path: Path):
    exact = parameter_recovery(_params_file(tmp_path / "exact.yaml", {}))
    assert exact["recovered"] and exact["worst_changed_error"] == 0.0
    off = parameter_recovery(_params_file(tmp_path / "off.yaml", {"Dr": 1.2, "m": 2.0}))
    assert off["parameters"]["Dr"]["error"] == pytest.approx(0.2)
    assert off["worst_changed_error"] == pytest.approx(0.2) and RECOVERED_WITHIN < 0.2
    assert not off["recovered"] and not off["parameters"]["m"]["changed"]


def test_the_table_shows_before_and_after(tmp_path: Path):
    recovery = parameter_recovery(_params_file(tmp_path / "p.yaml", {"Df": 1.05}))
    race = {
        "laps": 5,
        "mean_flying_lap_s": 7.2,
        "contouring_rms_m": 0.074,
        "contouring_max_m": 0.17,
        "estimation_rmse": {"x": 0.0024, "y": 0.0024, "yaw": 0.037},
        "grip_used": {"front": {"p99": 0.82, "max": 0.857}, "rear": {"p99": 0.6, "max": 0.62}},
    }
    result = {
        "duration_s": 40.0,
        "steps_s": {"race_default_model_s": 52.0, "sysid_s": 7.3},
        "races": {"default_model": race, "identified_model": {**race, "mean_flying_lap_s": 7.0}},
        "prediction_error": {
            "horizon_s": 2.0,
            "default_model": {"position_rmse_m": 0.29},
            "identified_model": {"position_rmse_m": 0.064},
        },
        "peak_slip_rad": {"front": 0.342, "rear": 0.194},
        "sysid": recovery,
        "discrepancy": {
            "named": ["gyro_bias"],
            "hidden": "gyro_bias",
            "parameters": recovery,
            "gap_before_m": 0.13,
            "gap_after_m": 0.056,
        },
    }
    table = format_table(result)
    assert "| mean flying lap | 7.2 s | 7.0 s |" in table
    assert "| open-loop 2 s position RMSE (held out) | 0.290 m | 0.064 m |" in table
    assert (
        "Effect named: gyro_bias (hidden: gyro_bias; gap on its held-out part 0.130 -> 0.056"
        in table
    )
    assert "crs sysid (no effect) Df +5.0 %" in table
    assert "front 0.82 / 0.86, rear 0.60 / 0.62; the tyre curves peak at 0.34 / 0.19 rad" in table
    assert "Steps: race default model 52 s, sysid 7 s" in table


def test_a_peak_and_a_shape_off_along_the_ridge_keep_the_cornering_stiffness(tmp_path: Path):
    """D up 20 % and B down by the same factor: the parameters are off, the axle's slope at zero
    slip (D C B) is not; the front's D alone moves its stiffness by as much."""
    ridge = parameter_recovery(_params_file(tmp_path / "r.yaml", {"Dr": 1.2, "Br": 1 / 1.2}))
    assert ridge["parameters"]["Dr"]["error"] == pytest.approx(0.2)
    assert stiffness_errors(ridge) == pytest.approx({"front": 0.0, "rear": 0.0}, abs=1e-4)
    front = parameter_recovery(_params_file(tmp_path / "f.yaml", {"Df": 1.1}))
    assert stiffness_errors(front) == pytest.approx({"front": 0.1, "rear": 0.0}, abs=1e-4)
