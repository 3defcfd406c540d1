"""The tuning study of the online gyro bias: its noise settings and its table from a result of
the saved shape (the study itself, a race and ~2.5 min of offline estimation, runs in
``crs bench online-tuning``)."""

from __future__ import annotations

import pytest

from benchmarks.online_tuning import VARIANTS, Variant, format_markdown, variant_noise
from crs_core.estimation import MheSettings
from crs_core.estimation.noise import EstimatorNoise


def test_a_variant_changes_the_pose_and_wheel_noise_only_and_the_first_is_the_default():
    default = EstimatorNoise()
    first = next(iter(VARIANTS.values()))
    assert first.pose_std == pytest.approx(default.process_std[:3])
    assert first.wheel_std == default.wheel_std
    assert first.reversion_s == MheSettings().online_reversion_s
    tight = variant_noise(Variant((0.002, 0.002, 0.002), 10.0, 120.0))
    assert tight.process_std[:3] == (0.002, 0.002, 0.002) and tight.wheel_std == 10.0
    assert tight.process_std[3:] == default.process_std[3:]
    assert tight.lighthouse_std == default.lighthouse_std and tight.imu_std == default.imu_std


def test_the_table_has_a_row_per_setting_with_the_parameters_and_both_real_runs():
    def parameter(within: float, std: float) -> dict:
        return {"within_tolerance": within, "inside_2sigma": 0.976, "final": {"std": std}}

    real = {
        "lighthouse_residual_rad": {"median": 0.00042, "p95": 0.0016},
        "from_onboard_mm": {"x": 3.1, "y": 3.7},
    }
    row = {
        "variant": "default",
        "pose_process_std": [0.02, 0.02, 0.02],
        "wheel_std": 2.5,
        "online_reversion_s": 120.0,
        "race": {
            "parameters": {"gyro_bias": parameter(0.828, 0.00867)},
            "rmse": {"x_mm": 0.9, "y_mm": 1.11, "yaw_mrad": 7.61},
        },
        "real": {"run_1": real, "run_2": real},
    }
    result = {
        "schedule": "issue",
        "duration_s": 120.0,
        "online_parameters": ["Cm1", "gyro_bias"],
        "rows": [row],
    }
    text = format_markdown(result)
    assert (
        "| variant | x, y, yaw process noise | wheels | T | Cm1: within / ±2σ / final σ |" in text
    )
    assert (
        "| default | 0.02 / 0.02 / 0.02 | 2.5 rad/s | 120 s | – | 83 / 98 % / 0.00867 | "
        "0.90 / 1.11 mm / 7.6 mrad | 0.42 / 1.6 mrad, 3.1 / 3.7 mm | "
        "0.42 / 1.6 mrad, 3.1 / 3.7 mm |" in text
    )
