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
