"""The real-recording study of online parameters: its table from a result of the saved shape
(the study itself, ~1.5 min, runs in ``crs bench online-real``)."""

from __future__ import annotations

from benchmarks.online_real import format_markdown


def _course(prior: float, end: float) -> dict:
    mark = {"t_s": 0.0, "value": prior, "std": 0.05}
    return {
        "start": mark,
        "middle": {**mark, "value": (prior + end) / 2},
        "end": {"t_s": 31.0, "value": end, "std": 0.02},
        "range": [min(prior, end), max(prior, end)],
        "informed_share": 0.84,
        "prior": prior,
        "prior_std": 0.05,
    }


def test_the_table_shows_each_course_and_both_held_out_predictions():
    cross = {
        "position_rmse_m": {"prior": 0.2312, "identified": 0.2223},
        "position_rmse_at_horizon_m": {"prior": 0.4097, "identified": 0.3954},
        "gyro_rms_rad_s": {"prior": 0.5237, "identified": 0.5283},
        "values": {"Cm1": 0.8972, "gyro_bias": 0.151},
        "starts": 1300,
    }
    result = {
        "estimator": "mhe",
        "online_parameters": ["Cm1", "gyro_bias"],
        "runs": {"run_1": {"parameters": {"gyro_bias": _course(0.0, 0.151)}}},
        "cross": {"run_1 -> run_2": cross},
    }
    text = format_markdown(result)
    assert (
        "| run_1 | gyro_bias | 0 (0.05) | 0 | 0.0755 | 0.151 (0.02) | 0 .. 0.151 | 84 % |" in text
    )
    assert "| run_1 | run_2 | 0.8972, 0.151 | 231.2 → 222.3 mm | 409.7 → 395.4 mm |" in text
