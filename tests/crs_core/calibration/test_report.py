"""Tests of crs_core.calibration.report: the geometry YAML and the strict JSON summary."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from crs_core.calibration.report import write_geometry, write_json
from crs_core.dataset import Geometry
from crs_core.model.lighthouse import RECORDED_PHOTODIODES
from tests.crs_core.calibration.conftest import STATIONS


def test_the_geometry_file_is_a_dataset_geometry_block(tmp_path: Path):
    path = write_geometry(tmp_path / "geometry.yaml", STATIONS, RECORDED_PHOTODIODES)
    text = path.read_text()
    assert text.startswith("# Lighthouse geometry")
    geometry = Geometry.from_dict(yaml.safe_load(text)["geometry"])
    assert geometry.photodiodes == tuple(RECORDED_PHOTODIODES)
    for read, station in zip(geometry.base_stations, STATIONS, strict=True):
        np.testing.assert_allclose(read.rotation, station.rotation, atol=1e-12)
        assert read.position == station.position
        assert (read.dt1, read.dt2) == (station.dt1, station.dt2)


def test_the_json_summary_is_strict_with_non_finite_numbers_as_null(tmp_path: Path):
    summary = {"rms": np.float64(1.5e-3), "gaps": [np.nan, np.inf, 2.0], "n": np.arange(3)}
    path = write_json(tmp_path / "summary.json", summary)

    def refuse(constant: str) -> None:
        raise AssertionError(f"not strict JSON: {constant}")

    assert json.loads(path.read_text(), parse_constant=refuse) == {
        "rms": 1.5e-3,
        "gaps": [None, None, 2.0],
        "n": [0, 1, 2],
    }


def _static_report(points, fit_tilt: bool = False) -> tuple[dict, str]:
    from crs_core.calibration.evaluation import point_reports, spread_order
    from crs_core.calibration.report import static_markdown, static_summary
    from crs_core.calibration.static import calibrate_static

    calibration = calibrate_static(points, fit_tilt=fit_tilt)
    reports = point_reports(points, calibration.stations, calibration.yaws)
    order = spread_order(np.array([p.position for p in points.points]))
    summary = static_summary(points, calibration, reports, [], order, fit_tilt)
    return summary, static_markdown(summary, "crs calibrate-lighthouse static points.yaml")


def test_the_report_says_which_tilt_offsets_were_fitted_and_which_are_weak():
    """Points without tilt offsets: fitted for every station (none given); the upright station
    behind the track gets the weak-tilt note, the others not. With station 0's tilts given, only
    stations 1 and 2 are fitted."""
    from dataclasses import replace

    from sim.static_points import grid_layout, simulate_static_points
    from tests.crs_core.calibration.conftest import AWAY

    simulated = simulate_static_points(AWAY, *grid_layout(16, seed=1), sweeps=10, seed=2)
    unknown = replace(simulated, tilts=((None, None),) * 3)
    summary, markdown = _static_report(unknown)
    assert [s["tilt_fitted"] for s in summary["stations"]] == [True, True, True]
    assert "tilt offsets fitted (none given)" in markdown
    assert "Station 2: its tilt offsets are weakly determined" in markdown
    assert "Station 0: its tilt" not in markdown and "Station 1: its tilt" not in markdown
    mixed = replace(simulated, tilts=(simulated.tilts[0], (None, None), (None, None)))
    summary, markdown = _static_report(mixed)
    assert [s["tilt_fitted"] for s in summary["stations"]] == [False, True, True]
    assert "tilt offsets fitted for station(s) 1, 2 (not given)" in markdown
    _, markdown = _static_report(simulated)
    assert "tilt offsets given" in markdown and "weakly determined" not in markdown
