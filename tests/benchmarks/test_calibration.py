"""The calibration benchmark's docs table, from a hand-written result (the studies themselves
simulate and fit for minutes and are not run here)."""

from __future__ import annotations

from benchmarks.calibration import format_markdown


def _rows(scale: float) -> list[dict[str, float]]:
    """Rows n = 4, 6, 8 with errors growing with ``scale`` (m)."""
    return [
        {
            "n": n,
            "all_mean_m": scale * (10 - n) * 1e-3,
            "all_max_m": 0.0,
            "fitted_mean_m": 0.0,
            "fitted_max_m": 0.0,
            "station_position_error_m": scale * n * 1e-3,
        }
        for n in (4, 6, 8)
    ]


RESULT = {
    "static": [
        {"sweeps_per_point": 1, "position_std_m": 0.0, "seeds": 5, "rows": _rows(1.0)},
        {"sweeps_per_point": 20, "position_std_m": 0.002, "seeds": 5, "rows": _rows(0.5)},
    ],
    "moving": [
        {
            "seed": seed,
            "duration_s": 20.0,
            "fit_photodiodes": photodiodes,
            "offset_true_s": 0.02,
            "offset_error_s": (4e-5 if photodiodes else 2e-5) * (seed + 1),
            "station_position_error_m": 1e-4 * (seed + 1),
        }
        for seed in range(2)
        for photodiodes in (False, True)
    ],
}


def test_the_static_table_shows_the_mean_error_at_4_6_and_all_points_in_mm() -> None:
    lines = format_markdown(RESULT).splitlines()
    assert lines[0] == (
        "Static: 8 points, mean over 5 seeds; mean reprojected position error over all 8 points "
        "(mm) when fitted on the first n:"
    )
    assert lines[2] == (
        "| setting | 4 points | 6 points | 8 points | station position error at 6 points |"
    )
    assert "| 1 sweep per point, exact known positions | 6.00 | 4.00 | 2.00 | 6.0 mm |" in lines
    assert (
        "| 20 sweeps per point, known positions off by 2 mm (std) | 3.00 | 2.00 | 1.00 | 3.0 mm |"
        in lines
    )


def test_the_moving_line_gives_the_worst_seed_with_and_without_photodiodes() -> None:
    last = format_markdown(RESULT).splitlines()[-1]
    assert last == (
        "Moving: 20 s of simulated driving with a 20 ms clock offset, worst of 2 seeds; station "
        "and offset: offset error 0.04 ms, station position error 0.2 mm; with the photodiodes "
        "fitted too: offset error 0.08 ms, station position error 0.2 mm."
    )
