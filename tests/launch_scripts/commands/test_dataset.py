"""``crs dataset``: a bag as a dataset folder, through the command line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from crs_core.dataset import Dataset
from ros4crs.bag_dataset import dataset_from_bag
from tests.ros4crs.bag_builders import simulated_run, two_car_bag


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return two_car_bag(simulated_run(), tmp_path_factory.mktemp("dataset") / "bag")


def test_the_folder_holds_what_the_conversion_gives(bag: Path, tmp_path: Path, crs):
    out = tmp_path / "car1"
    code, printed, warned = crs(["dataset", str(bag), "--car", "car1", "--out", str(out)])
    assert code == 0, warned
    assert printed.startswith("dataset: ") and "reference simulation truth" in printed
    assert "stream: imu " in printed and f"wrote {out}/" in printed
    loaded, direct = Dataset.load(out), dataset_from_bag(bag, "car1")
    np.testing.assert_array_equal(loaded.t, direct.t)
    np.testing.assert_array_equal(loaded.u, direct.u)
    assert len(loaded.measurements) == len(direct.measurements)
    assert loaded.meta["car"] == "car1" and loaded.meta["inputs"] == "/car1/input"
    code, printed, _ = crs(
        [
            "dataset",
            str(bag),
            "--car",
            "car1",
            "--reference",
            "none",
            "--out",
            str(out),
            "--overwrite",
        ]
    )
    assert code == 0 and "reference none" in printed and not (out / "x.npy").exists()


def test_refusals(bag: Path, tmp_path: Path, crs_refuses):
    out = str(tmp_path / "out")
    assert "--car: the bag holds several cars (car1, car2)" in crs_refuses(
        ["dataset", str(bag), "--out", out]
    )
    folder = tmp_path / "folder"
    folder.mkdir()
    assert "BAG: " in crs_refuses(["dataset", str(folder), "--out", out])
    assert not (tmp_path / "out").exists()
