"""A recording on the command line: a dataset folder or a bag, errors naming the option, what a
bag's conversion assumed or left out one warning line each."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from crs_core.calibration.report import write_geometry
from crs_core.errors import FieldError
from crs_core.model.chronos import default_base_stations
from crs_core.model.lighthouse import RECORDED_PHOTODIODES
from launch_scripts.recording import add_bag_options, load_recording
from tests.ros4crs.bag_builders import simulated_run, two_car_bag


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return two_car_bag(simulated_run(), tmp_path_factory.mktemp("recording") / "bag")


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_bag_options(parser)
    return parser.parse_args(list(argv))


def test_a_bag_with_its_car_and_geometry(bag: Path, tmp_path: Path, capsys):
    geometry = write_geometry(
        tmp_path / "geometry.yaml", default_base_stations(2), RECORDED_PHOTODIODES
    )
    dataset = load_recording(bag, _args("--car", "car2", "--geometry", str(geometry)))
    assert dataset.meta["car"] == "car2" and len(dataset.geometry.base_stations) == 2
    assert capsys.readouterr().err == ""  # nothing assumed, nothing left out
    load_recording(bag, _args("--car", "car1"))
    warned = capsys.readouterr().err.splitlines()
    assert warned == [
        "warning: DATASET: a bag without --geometry: the real recordings' Lighthouse geometry"
    ]


def test_a_dataset_folder_as_before(bag: Path, tmp_path: Path):
    folder = load_recording(bag, _args("--car", "car1")).save(tmp_path / "dataset")
    again = load_recording(folder, _args())
    assert again.t.size > 50 and np.all(np.diff(again.t) > 0)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ((), r"^--car: the bag holds several cars \(car1, car2\): name one$"),
        (("--car", "car9"), r"^--car: no sensor readings of 'car9' in the bag"),
        (("--geometry", "nowhere.yaml"), r"^--geometry: nowhere\.yaml: cannot read it"),
    ],
)
def test_errors_name_the_option(bag: Path, argv: tuple[str, ...], message: str):
    with pytest.raises(FieldError, match=message):
        load_recording(bag, _args(*argv))


def test_a_missing_recording_names_the_argument(tmp_path: Path):
    with pytest.raises(FieldError, match=r"^TRAIN: dataset folder .* does not exist"):
        load_recording(tmp_path / "nowhere", _args(), "TRAIN")
