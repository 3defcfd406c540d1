"""A bag as a dataset: the bag of a simulated run (written here as the stack records one: batches
of sensor readings, commands, applied inputs, truth, estimates, a second car) gives the dataset
the simulator writes of the same run; bad bags get one error naming what is wrong."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from crs_core.dataset import Dataset, Geometry
from crs_core.errors import FieldError
from crs_core.model import CarModel
from ros4crs import conversions
from ros4crs.bag_dataset import BagDatasetWarning, dataset_from_bag, is_bag, load_recording
from sim import SimulationResult
from tests.ros4crs.bag_builders import (
    DURATION,
    T0,
    simulated_run,
    stack_messages,
    two_car_bag,
    write_bag,
)


@pytest.fixture(scope="module")
def run() -> SimulationResult:
    return simulated_run()


@pytest.fixture(scope="module")
def bag(run: SimulationResult, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return two_car_bag(run, tmp_path_factory.mktemp("stack") / "bag")


def test_the_bag_of_a_run_gives_the_simulators_dataset_of_it(run: SimulationResult, bag: Path):
    expected = run.to_dataset()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing left out
        data = dataset_from_bag(bag, "car1")
    np.testing.assert_allclose(data.t - T0, expected.t, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(np.isnan(data.y), np.isnan(expected.y))
    np.testing.assert_allclose(data.y[:, :8], expected.y[:, :8], rtol=0, atol=1e-12)
    # interpolated at stamps 1.76e9 s on the bag's clock: float64 resolves 0.24 us there, which
    # moves a 4 ms interpolation weight by 6e-5 (of wheel speed steps of a few rad/s)
    np.testing.assert_allclose(data.y[:, 8:], expected.y[:, 8:], rtol=0, atol=1e-3)
    np.testing.assert_allclose(data.u, expected.u, rtol=0, atol=1e-12)
    # the truth, every 5th point of the run's (and the last), interpolated: within its curvature
    np.testing.assert_allclose(data.x, expected.x, rtol=0, atol=2e-4)
    within = [m for m in run.measurements if expected.t[0] <= m.stamp <= expected.t[-1]]
    assert len(data.measurements) == len(within)  # the stream of the samples' span
    assert data.meta["source"] == "simulated" and data.meta["car"] == "car1"
    assert data.meta["inputs"] == "/car1/input"
    assert "simulation truth" in data.meta["reference"]


def test_a_dataset_from_a_bag_saves_and_loads(bag: Path, tmp_path: Path):
    data = dataset_from_bag(bag, "car1")
    loaded = Dataset.load(data.save(tmp_path / "dataset"))
    np.testing.assert_array_equal(loaded.t, data.t)
    np.testing.assert_array_equal(loaded.u, data.u)
    assert len(loaded.measurements) == len(data.measurements)
    assert loaded.truth_t is not None and loaded.meta["car"] == "car1"


def test_the_car_must_be_named_where_the_bag_holds_several(bag: Path):
    with pytest.raises(FieldError, match=r"^car: the bag holds several cars \(car1, car2\)"):
        dataset_from_bag(bag)
    with pytest.raises(FieldError, match=r"^car: no sensor readings of 'car3' .*car1, car2"):
        dataset_from_bag(bag, "car3")


def test_without_truth_the_estimates_are_the_reference_and_the_samples_are_cut_to_them(
    run: SimulationResult, tmp_path: Path
):
    messages = stack_messages(run, truth=False, estimates=True)
    messages = [m for m in messages if m[0] != "/car1/estimate/state" or m[2] > T0 + 0.5]
    bag = write_bag(tmp_path / "bag", sorted(messages, key=lambda m: m[2]))
    with pytest.warns(BagDatasetWarning, match="within the reference states' span"):
        data = dataset_from_bag(bag)  # one car: no name needed
    assert data.t[0] >= T0 + 0.48 and data.meta["source"] == "bag"
    assert "on-line estimates" in data.meta["reference"] and "not truth" in data.meta["reference"]
    assert data.truth_t is None
    with pytest.raises(FieldError, match=r"^reference: truth: the bag has no ground_truth"):
        dataset_from_bag(bag, reference="truth")
    assert dataset_from_bag(bag, reference="none").x is None


def test_applied_inputs_are_preferred_and_a_bag_without_inputs_warns(
    run: SimulationResult, tmp_path: Path
):
    messages = [m for m in stack_messages(run) if not m[0].endswith("/input")]
    bare = write_bag(tmp_path / "bare", messages)
    with pytest.warns(BagDatasetWarning, match="no torque-mode inputs on /car1/input"):
        assert dataset_from_bag(bare).u is None
    applied = [
        ("/car1/input/applied", conversions.car_input_msg([0.05, 0.2], T0 + t), T0 + t)
        for t in np.arange(0.0, DURATION, 0.01)
    ]
    with_applied = write_bag(tmp_path / "applied", sorted(messages + applied, key=lambda m: m[2]))
    data = dataset_from_bag(with_applied)
    assert data.meta["inputs"] == "/car1/input/applied"
    np.testing.assert_array_equal(data.u, np.tile([0.05, 0.2], (data.t.size, 1)))


def test_an_mcap_file_and_a_given_geometry(bag: Path, tmp_path: Path):
    single = tmp_path / "run.mcap"
    shutil.copy(next(bag.glob("*.mcap")), single)
    geometry = Geometry.from_parameters(CarModel().parameters, 1)
    data = dataset_from_bag(single, "/car2/", geometry=geometry)
    assert data.meta["car"] == "car2" and data.geometry is geometry
    assert data.x is None  # car2 has neither truth nor estimates


def test_bags_without_what_a_dataset_needs(run: SimulationResult, tmp_path: Path):
    no_sensors = write_bag(
        tmp_path / "no_sensors", [m for m in stack_messages(run) if "sensors" not in m[0]]
    )
    with pytest.raises(FieldError, match=r"^bag: holds no sensor readings"):
        dataset_from_bag(no_sensors)
    wheels_only = [
        (topic, msg, t) for topic, msg, t in stack_messages(run) if topic != "/car1/sensors/batch"
    ]
    wheels_only.append(
        (
            "/car1/sensors/wheel_speeds",
            conversions.measurement_to_msg(
                run.measurements[0].__class__(T0, "wheel_encoders", [1.0] * 4)
            ),
            T0,
        )
    )
    with pytest.raises(FieldError, match=r"^bag: no Lighthouse sweep pair of station 0"):
        dataset_from_bag(write_bag(tmp_path / "wheels", wheels_only))
    with pytest.raises(FieldError, match=r"^inputs: must be one of"):
        dataset_from_bag(tmp_path / "wheels", inputs="sent")


def test_a_recording_is_a_dataset_folder_or_a_bag(bag: Path, tmp_path: Path):
    folder = dataset_from_bag(bag, "car1").save(tmp_path / "dataset")
    single = tmp_path / "run.mcap"
    shutil.copy(next(bag.glob("*.mcap")), single)
    (tmp_path / "empty").mkdir()
    assert is_bag(bag) and is_bag(single) and is_bag(tmp_path)  # a folder with an .mcap file
    assert not is_bag(folder) and not is_bag(tmp_path / "empty")
    from_folder = load_recording(folder)
    from_bag = load_recording(bag, "car1")
    np.testing.assert_array_equal(from_folder.t, from_bag.t)
    assert load_recording(single, "car2").meta["car"] == "car2"
    with pytest.raises(FieldError, match=r"^car: .* is a dataset folder \(one car\), not a bag"):
        load_recording(folder, "car1")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_recording(tmp_path / "nowhere")


def test_a_cut_off_bag_gives_what_it_holds_with_a_warning(bag: Path, tmp_path: Path):
    """A recorder killed mid-run: the bag is read up to its last complete message (a
    BagDamagedWarning says what was lost) and the dataset holds the samples of that part."""
    from ros4crs.bag_repair import BagDamagedWarning

    whole = dataset_from_bag(bag, "car1")
    (mcap,) = bag.glob("*.mcap")
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(mcap.read_bytes()[: int(0.6 * mcap.stat().st_size)])
    with pytest.warns(BagDamagedWarning):
        part = dataset_from_bag(cut, "car1", reference="none")
    assert 10 < part.t.size < whole.t.size
    np.testing.assert_array_equal(part.t, whole.t[: part.t.size])
