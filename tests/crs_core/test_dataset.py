"""Tests of crs_core.dataset: save/load round trip, the real recordings, and input validation."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from crs_core.dataset import FORMAT, Y_CHANNELS, Dataset, Geometry
from crs_core.errors import FieldError
from crs_core.measurements import lighthouse_sensor
from crs_core.model import CarModel
from crs_core.model.lighthouse import RECORDED_BASE_STATION, RECORDED_PHOTODIODES
from sim import SensorSpec, SensorSuite, Simulator
from tests.crs_core.conftest import weaving, write_user_recording

REAL_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "chronos_real"
REAL_RUNS = {"fie_mpc_lighthouse_1": 1462, "fie_mpc_lighthouse_2": 1472}


def real_run(name: str) -> Path:
    folder = REAL_DATA / name
    if not folder.is_dir():
        pytest.skip(f"real recordings not found: {folder}")
    return folder


# --- round trip -----------------------------------------------------------------------------------
def test_save_writes_the_documented_files(saved: Path, simulated: Dataset):
    """A simulated dataset folder holds t/u/y/x .npy (recorded orientation), YAML and stream."""
    names = {p.name for p in saved.iterdir()}
    assert names == {"t.npy", "u.npy", "y.npy", "x.npy", "dataset.yaml", "stream.npz"}
    n = simulated.t.size
    assert np.load(saved / "y.npy").shape == (len(Y_CHANNELS), n)
    assert np.load(saved / "x.npy").shape == (6, n)


def test_u_on_disk_is_torque_first(saved: Path, simulated: Dataset):
    """Raw u.npy row 0 is the torque and row 1 the steering, as in the real recordings."""
    raw = np.load(saved / "u.npy")
    assert raw.shape == (2, simulated.t.size)
    np.testing.assert_array_equal(raw[0], simulated.u[:, 1])
    np.testing.assert_array_equal(raw[1], simulated.u[:, 0])
    assert np.all(raw[0] == 0.25)
    assert np.ptp(raw[1]) > 0.1


def test_round_trip_preserves_samples_and_geometry(saved: Path, simulated: Dataset):
    """Loading what was saved gives identical t, u, y (NaN included), x and the same geometry."""
    loaded = Dataset.load(saved)
    for name in ("t", "u", "y", "x"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(simulated, name))
    assert np.isnan(loaded.y[3, 12])
    assert len(loaded.geometry.base_stations) == 1
    for got, want in zip(
        loaded.geometry.base_stations, simulated.geometry.base_stations, strict=True
    ):
        np.testing.assert_allclose(got.angles, want.angles, rtol=0, atol=1e-12)
        assert got.position == want.position
        assert (got.dt1, got.dt2) == (want.dt1, want.dt2)
    assert loaded.geometry.photodiodes == simulated.geometry.photodiodes


def test_round_trip_preserves_metadata(saved: Path, simulated: Dataset):
    """Metadata (source, seed, truth parameters, sensor settings) comes back unchanged."""
    loaded = Dataset.load(saved)
    for key in ("source", "seed", "duration_s", "truth", "sensors"):
        assert loaded.meta[key] == simulated.meta[key]
    assert loaded.meta["format"] == FORMAT
    assert loaded.meta["y_channels"] == list(Y_CHANNELS)
    assert "geometry" not in loaded.meta  # parsed into Dataset.geometry
    assert loaded.meta["sensors"]["lighthouse"]["dropout_probability"] == 0.05


def test_round_trip_preserves_full_stream_inputs_and_truth(saved: Path, simulated: Dataset):
    """The full-rate stream, commanded inputs and dense truth come back value for value."""
    loaded = Dataset.load(saved)
    assert simulated.measurements is not None and loaded.measurements is not None
    assert len(loaded.measurements) == len(simulated.measurements) > 1000
    for got, want in zip(loaded.measurements, simulated.measurements, strict=True):
        assert (got.stamp, got.sensor) == (want.stamp, want.sensor)
        np.testing.assert_array_equal(got.values, want.values)
    assert loaded.inputs is not None and simulated.inputs is not None
    np.testing.assert_array_equal(
        [s.stamp for s in loaded.inputs], [s.stamp for s in simulated.inputs]
    )
    np.testing.assert_array_equal(
        np.stack([s.u for s in loaded.inputs]), np.stack([s.u for s in simulated.inputs])
    )
    np.testing.assert_array_equal(loaded.truth_t, simulated.truth_t)
    np.testing.assert_array_equal(loaded.truth_x, simulated.truth_x)


def test_sample_stream_skips_missing_channels(simulated: Dataset):
    """sample_stream gives 4 measurements per sample, minus groups with a NaN (one here)."""
    stream = simulated.sample_stream()
    assert len(stream) == 4 * simulated.t.size - 1
    gyro = [m for m in stream if m.sensor == "gyro"]
    assert simulated.t[3] not in [m.stamp for m in gyro]
    first = stream[:4]
    assert [m.sensor for m in first] == [
        lighthouse_sensor(0, 1),
        lighthouse_sensor(0, 2),
        "wheel_encoders",
        "gyro",
    ]
    assert all(m.stamp == simulated.t[0] for m in first)
    np.testing.assert_array_equal(first[1].values, simulated.y[0, 4:8])


# --- the real recordings --------------------------------------------------------------------------
@pytest.mark.parametrize(("name", "samples"), sorted(REAL_RUNS.items()))
def test_real_runs_load_in_model_order(name: str, samples: int):
    """The recordings load with their sample counts; u becomes [steer, torque] by name."""
    data = Dataset.load(real_run(name))
    assert data.t.shape == (samples,)
    assert data.u.shape == (samples, 2)
    assert data.y.shape == (samples, len(Y_CHANNELS))
    assert data.x is not None and data.x.shape == (samples, 6)
    steer, torque = data.u[:, 0], data.u[:, 1]
    assert np.all(np.abs(steer) <= 0.34 + 1e-12)
    assert steer.min() < -0.3 and steer.max() > 0.3  # both directions used
    assert np.all((torque >= 0.05) & (torque <= 1.0))
    raw = np.load(real_run(name) / "u.npy")
    np.testing.assert_array_equal(raw[0], torque)
    assert np.all(np.diff(data.t) > 0)
    assert 30.0 < data.t[-1] - data.t[0] < 33.0


@pytest.mark.parametrize("name", sorted(REAL_RUNS))
def test_real_runs_use_recorded_geometry_without_yaml(name: str):
    """Without dataset.yaml the geometry is the recorded base station and photodiodes."""
    folder = real_run(name)
    assert not (folder / "dataset.yaml").exists()
    data = Dataset.load(folder)
    assert data.geometry == Geometry()
    assert data.geometry.base_stations == (RECORDED_BASE_STATION,)
    assert data.geometry.photodiodes == RECORDED_PHOTODIODES
    assert data.meta == {"source": "real"}
    assert data.measurements is None and data.truth_t is None


@pytest.mark.parametrize(("name", "samples"), sorted(REAL_RUNS.items()))
def test_real_sample_stream_has_four_measurements_per_sample(name: str, samples: int):
    """Every real sample yields both planes of station 0, the wheel speeds and the yaw rate."""
    data = Dataset.load(real_run(name))
    stream = data.sample_stream()
    assert len(stream) == 4 * samples
    counts = {
        s: sum(m.sensor == s for m in stream)
        for s in ("lighthouse/0/1", "lighthouse/0/2", "wheel_encoders", "gyro")
    }
    assert counts == dict.fromkeys(counts, samples)
    last = stream[-4:]
    assert all(m.stamp == data.t[-1] for m in last)
    np.testing.assert_array_equal(last[0].values, data.y[-1, 0:4])
    np.testing.assert_array_equal(last[2].values, data.y[-1, 8:12])
    np.testing.assert_array_equal(last[3].values, data.y[-1, 12:13])


# --- malformed inputs -----------------------------------------------------------------------------
def test_missing_folder_is_a_file_not_found_error(tmp_path: Path):
    """Loading a folder that does not exist raises FileNotFoundError naming it."""
    with pytest.raises(FileNotFoundError, match="nowhere"):
        Dataset.load(tmp_path / "nowhere")


@pytest.mark.parametrize("shape", [(3, -1), (-1, 2), (2, -1, 1)])
def test_u_of_wrong_shape_is_rejected(corruptible: Path, shape: tuple[int, ...]):
    """u.npy that is not (2, N) (three rows, model-order transposed, 3-D) names u.npy."""
    n = np.load(corruptible / "t.npy").size
    np.save(corruptible / "u.npy", np.zeros([n if s == -1 else s for s in shape]))
    with pytest.raises(ValueError, match=r"^u\.npy: expected shape \(2, N\)"):
        Dataset.load(corruptible)


def test_u_of_wrong_length_is_rejected(corruptible: Path):
    """u.npy with one sample too many is rejected naming u.npy and both counts."""
    n = np.load(corruptible / "t.npy").size
    np.save(corruptible / "u.npy", np.zeros((2, n + 1)))
    with pytest.raises(ValueError, match=rf"^u\.npy: has {n + 1} samples but t\.npy has {n}"):
        Dataset.load(corruptible)


@pytest.mark.parametrize(
    ("name", "rows", "message"),
    [
        ("y", 12, r"^y\.npy: expected shape \(13, N\)"),
        ("x", 3, r"^x\.npy: expected shape \(6, N\), got \(3, "),
    ],
)
def test_array_with_wrong_rows_is_rejected(corruptible: Path, name: str, rows: int, message: str):
    """y.npy without its 13 rows, or an x.npy of poses only (3 rows), is rejected naming the
    file (and for x.npy the expected shape)."""
    np.save(corruptible / f"{name}.npy", np.load(corruptible / f"{name}.npy")[:rows])
    with pytest.raises(FieldError, match=message) as error:
        Dataset.load(corruptible)
    assert error.value.field == f"{name}.npy"


@pytest.mark.parametrize("kind", ["repeated", "reversed"])
def test_non_increasing_stamps_are_rejected(corruptible: Path, kind: str):
    """A repeated or backwards stamp in t.npy is rejected naming t."""
    t = np.load(corruptible / "t.npy")
    if kind == "repeated":
        t[5] = t[4]
    else:
        t[[4, 5]] = t[[5, 4]]
    np.save(corruptible / "t.npy", t)
    with pytest.raises(ValueError, match=r"^t: stamps must be strictly increasing"):
        Dataset.load(corruptible)


@pytest.mark.parametrize(("file", "row", "field"), [("x", 3, "x"), ("t", None, "t"), ("u", 1, "u")])
def test_nan_outside_y_is_rejected_naming_the_field(corruptible: Path, file, row, field):
    """NaN is allowed only in y (a missing channel): in x, t or u it is rejected by name."""
    array = np.load(corruptible / f"{file}.npy")
    if row is None:
        array[7] = np.nan
    else:
        array[row, 7] = np.nan
    np.save(corruptible / f"{file}.npy", array)
    with pytest.raises(ValueError, match=rf"^{field}: contains non-finite values"):
        Dataset.load(corruptible)


def test_inf_in_y_is_rejected(corruptible: Path):
    """y may hold NaN for missing channels but never inf."""
    y = np.load(corruptible / "y.npy")
    y[2, 4] = np.inf
    np.save(corruptible / "y.npy", y)
    with pytest.raises(ValueError, match=r"^y: contains non-finite values"):
        Dataset.load(corruptible)


def test_malformed_yaml_is_rejected(corruptible: Path):
    """A dataset.yaml that is not a mapping, or has broken geometry, is rejected by name."""
    (corruptible / "dataset.yaml").write_text("- just\n- a list\n")
    with pytest.raises(ValueError, match=r"^dataset\.yaml: expected a mapping"):
        Dataset.load(corruptible)
    (corruptible / "dataset.yaml").write_text(
        yaml.safe_dump({"geometry": {"base_stations": [{"rotation": [[1, 0, 0]]}]}})
    )
    with pytest.raises(ValueError, match=r"^geometry: malformed"):
        Dataset.load(corruptible)


def test_constructor_validates_shapes():
    """Building a Dataset with u in the wrong orientation raises ValueError naming u."""
    t = np.arange(5.0)
    y = np.zeros((5, len(Y_CHANNELS)))
    with pytest.raises(ValueError, match=r"^u: expected shape \(5, 2\), got \(2, 5\)"):
        Dataset(t=t, u=np.zeros((2, 5)), y=y)
    with pytest.raises(ValueError, match=r"^y: expected shape"):
        Dataset(t=t, u=np.zeros((5, 2)), y=y[:, :12])


def test_two_station_geometry_round_trips(tmp_path: Path):
    """A two-station geometry survives save/load (rotation, position, tilt offsets per station)."""
    model = CarModel(n_base_stations=2)
    geometry = Geometry.from_parameters(model.parameters, 2)
    n = 3
    data = Dataset(
        t=np.arange(n) * 0.02,
        u=np.zeros((n, 2)),
        y=np.full((n, len(Y_CHANNELS)), np.nan),
        geometry=geometry,
    )
    loaded = Dataset.load(data.save(tmp_path / "two"))
    assert loaded.x is None and loaded.measurements is None
    assert len(loaded.geometry.base_stations) == 2
    for got, want in zip(loaded.geometry.base_stations, geometry.base_stations, strict=True):
        np.testing.assert_allclose(got.rotation, want.rotation, rtol=0, atol=1e-12)
        np.testing.assert_allclose(got.position, want.position, rtol=0, atol=1e-15)
    second = loaded.geometry.base_stations[1].position
    np.testing.assert_allclose(
        second[:2], -np.array(RECORDED_BASE_STATION.position[:2]), atol=1e-12
    )
    np.testing.assert_allclose(
        loaded.geometry.parameters().vector(), geometry.parameters().vector(), atol=1e-12
    )


def test_saving_over_a_folder_does_not_mix_in_stale_files(saved: Path, tmp_path: Path):
    """Saving a dataset without x or stream over an older one loads without the old x/stream."""
    folder = Path(shutil.copytree(saved, tmp_path / "reused"))
    old = Dataset.load(folder)
    Dataset(t=old.t, u=np.zeros_like(old.u), y=old.y).save(folder)
    loaded = Dataset.load(folder)
    assert loaded.x is None
    assert loaded.measurements is None


def test_stream_order_of_equal_stamps_survives_round_trip(tmp_path: Path):
    """Measurements sharing a stamp (pose and plane 2 at 100 Hz) load in the saved order."""
    sensors = replace(SensorSuite().ideal(), pose=SensorSpec(100.0, (0.0, 0.0, 0.0)))
    result = Simulator(CarModel(), sensors, seed=0).run(weaving, 0.2, np.zeros(6))
    data = result.to_dataset()
    loaded = Dataset.load(data.save(tmp_path / "ties"))
    assert loaded.measurements is not None and data.measurements is not None
    saved_order = [(m.stamp, m.sensor) for m in data.measurements]
    assert len(set(saved_order)) > len({stamp for stamp, _ in saved_order})  # ties exist
    assert [(m.stamp, m.sensor) for m in loaded.measurements] == saved_order


# --- recordings without inputs, and user-written streams ------------------------------------------
def test_dataset_without_inputs_round_trips(saved: Path, tmp_path: Path):
    """u=None saves no u.npy (removing a stale one) and loads back as u=None."""
    folder = Path(shutil.copytree(saved, tmp_path / "no_u"))
    old = Dataset.load(folder)
    Dataset(t=old.t, u=None, y=old.y, x=old.x).save(folder)
    assert not (folder / "u.npy").exists()
    loaded = Dataset.load(folder)
    assert loaded.u is None and loaded.inputs is None
    np.testing.assert_array_equal(loaded.y, old.y)
    np.testing.assert_array_equal(loaded.x, old.x)


def test_recording_with_only_t_and_y_loads(saved: Path, tmp_path: Path):
    """A folder with just t.npy and y.npy (no u, x, yaml, stream) is a dataset without inputs."""
    folder = tmp_path / "bare"
    folder.mkdir()
    for name in ("t.npy", "y.npy"):
        shutil.copy(saved / name, folder / name)
    data = Dataset.load(folder)
    assert data.u is None and data.x is None and data.measurements is None
    assert data.geometry == Geometry() and data.meta == {"source": "real"}
    assert len(data.sample_stream()) == 4 * data.t.size - 1  # the one NaN yaw rate skipped


def test_missing_required_file_names_it(saved: Path, tmp_path: Path):
    """Without t.npy the error names t.npy; a folder that is a file says so."""
    folder = tmp_path / "no_t"
    folder.mkdir()
    shutil.copy(saved / "y.npy", folder / "y.npy")
    with pytest.raises(FileNotFoundError, match=r"^t\.npy: missing in dataset folder"):
        Dataset.load(folder)
    (tmp_path / "file").write_text("")
    with pytest.raises(FileNotFoundError, match=r"is not a folder$"):
        Dataset.load(tmp_path / "file")


def test_corrupt_npy_is_a_one_line_error(corruptible: Path):
    """A u.npy that is not an .npy array is rejected naming u.npy."""
    (corruptible / "u.npy").write_text("torque,steer\n0.1,0.2\n")
    with pytest.raises(ValueError, match=r"^u\.npy: not a readable \.npy array"):
        Dataset.load(corruptible)


def test_user_written_stream_is_read_back(tmp_path: Path):
    """A stream.npz written with plain numpy loads sensor by sensor; save/load keeps it."""
    arrays = write_user_recording(tmp_path / "mine")
    data = Dataset.load(tmp_path / "mine")
    assert data.u is None and data.x is None and data.meta == {"source": "my-lab"}
    assert len(data.geometry.base_stations) == 2
    assert data.geometry.base_stations[1].position == (1.0, -0.5, 2.2)
    np.testing.assert_allclose(
        data.geometry.base_stations[1].rotation[0], [0.0, -1.0, 0.0], atol=1e-12
    )
    assert data.measurements is not None
    stamps = [m.stamp for m in data.measurements]
    assert stamps == sorted(stamps)
    by_sensor: dict[str, list] = {}
    for m in data.measurements:
        by_sensor.setdefault(m.sensor, []).append(m)
    assert {s: len(v) for s, v in by_sensor.items()} == {
        "lighthouse/1/2": 25,
        "gyro": 100,
        "wheel_encoders": 99,  # the NaN row is a missing sample
    }
    lh = by_sensor["lighthouse/1/2"]
    np.testing.assert_array_equal(lh[0].values, arrays["meas:lighthouse__1__2:v"][-1])
    assert lh[0].stamp == arrays["meas:lighthouse__1__2:t"][-1]
    assert data.inputs is not None and len(data.inputs) == 13
    np.testing.assert_array_equal(data.inputs[0].u, [0.2, 0.5])  # steer first in the stream

    again = Dataset.load(data.save(tmp_path / "copy"))
    assert again.u is None and not (tmp_path / "copy" / "u.npy").exists()
    assert [(m.stamp, m.sensor) for m in again.measurements] == [
        (m.stamp, m.sensor) for m in data.measurements
    ]
    for got, want in zip(again.measurements, data.measurements, strict=True):
        np.testing.assert_array_equal(got.values, want.values)
    assert [s.stamp for s in again.inputs] == [s.stamp for s in data.inputs]
    assert again.geometry.base_stations[1].position == (1.0, -0.5, 2.2)


def test_geometry_fields_are_validated_by_name(corruptible: Path):
    """A base station position of two numbers is rejected naming the field."""
    meta = yaml.safe_load((corruptible / "dataset.yaml").read_text())
    meta["geometry"]["base_stations"][0]["position"] = [0.1, 0.2]
    (corruptible / "dataset.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(ValueError, match=r"^geometry\.base_stations\[0\]\.position: expected"):
        Dataset.load(corruptible)


def test_t_one_sample_short_names_the_files_and_counts(corruptible: Path):
    """t.npy one stamp short: the error names the file that disagrees with t.npy and both
    counts (it used to blame u with transposed shapes)."""
    t = np.load(corruptible / "t.npy")
    np.save(corruptible / "t.npy", t[:-1])
    with pytest.raises(
        ValueError, match=rf"y\.npy: has {t.size} samples but t\.npy has {t.size - 1}"
    ):
        Dataset.load(corruptible)


def test_samples_view_keeps_the_stream_inside_and_the_command_in_force():
    from sim.scenarios import simulate_dataset

    dataset = simulate_dataset(4.0, 3)
    part = dataset.samples(50, 120)
    assert len(part.t) == 70 and part.t[0] == dataset.t[50] and part.t[-1] == dataset.t[119]
    np.testing.assert_array_equal(part.y, dataset.y[50:120])
    assert all(part.t[0] <= m.stamp <= part.t[-1] for m in part.measurements)
    assert part.inputs[0].stamp <= part.t[0] < part.inputs[1].stamp
    assert all(s.stamp <= part.t[-1] for s in part.inputs)
    with pytest.raises(ValueError, match="samples"):
        dataset.samples(10, 11)


def test_save_without_metadata_writes_the_recordings_layout(tmp_path):
    from sim.scenarios import simulate_dataset

    dataset = simulate_dataset(2.0, 4)
    folder = dataset.save(tmp_path / "d")
    dataset.save(folder, metadata=False)  # over an earlier full save: nothing stale stays
    assert sorted(p.name for p in folder.iterdir()) == ["t.npy", "u.npy", "x.npy", "y.npy"]
    loaded = Dataset.load(folder)
    assert loaded.meta == {"source": "real"} and loaded.measurements is None
    np.testing.assert_array_equal(loaded.u, dataset.u)
    np.testing.assert_array_equal(loaded.y, dataset.y)


# --- geometry errors name the field ---------------------------------------------------------------


def test_a_dataset_geometry_names_the_bad_field() -> None:
    station = {
        "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
        "position": [0, 0],
        "dt1": 0,
        "dt2": 0,
    }
    with pytest.raises(FieldError) as caught:
        Geometry.from_dict({"base_stations": [station], "photodiodes": [[0, 0]] * 4})
    assert caught.value.field == "geometry.base_stations[0].position"


def test_a_reflected_base_station_rotation_is_named_once() -> None:
    station = {
        "rotation": [[1, 0, 0], [0, 1, 0], [0, 0, -1]],
        "position": [0, 0, 2],
        "dt1": 0,
        "dt2": 0,
    }
    with pytest.raises(FieldError) as caught:
        Geometry.from_dict({"base_stations": [station], "photodiodes": [[0, 0]] * 4})
    assert str(caught.value) == (
        "geometry.base_stations[0].rotation: matrix is a reflection (det < 0)"
    )


def test_a_geometry_from_a_file(tmp_path: Path):
    """A calibration's geometry.yaml and a dataset.yaml give their geometry block; a file
    without one, or not YAML, is an error naming the file."""
    from crs_core.calibration.report import write_geometry
    from crs_core.model.chronos import default_base_stations

    stations = default_base_stations(2)
    written = write_geometry(tmp_path / "geometry.yaml", stations, RECORDED_PHOTODIODES)
    geometry = Geometry.from_file(written)
    assert len(geometry.base_stations) == 2
    np.testing.assert_allclose(geometry.base_stations[1].position, stations[1].position)
    folder = Dataset(np.array([0.0, 1.0]), None, np.zeros((2, 13)), geometry=geometry).save(
        tmp_path / "dataset"
    )
    again = Geometry.from_file(folder / "dataset.yaml")
    np.testing.assert_allclose(again.parameters().vector(), geometry.parameters().vector())
    (tmp_path / "other.yaml").write_text("parameters: {m: 0.2}\n")
    with pytest.raises(FieldError, match=r"other\.yaml: expected a mapping with a 'geometry'"):
        Geometry.from_file(tmp_path / "other.yaml")
    (tmp_path / "bad.yaml").write_text("geometry: [\n")
    with pytest.raises(FieldError, match=r"bad\.yaml: not valid YAML"):
        Geometry.from_file(tmp_path / "bad.yaml")
    with pytest.raises(FieldError, match=r"nowhere\.yaml: cannot read it"):
        Geometry.from_file(tmp_path / "nowhere.yaml")


# --- a geometry of the deck layout alone (stations not calibrated yet) ----------------------------
DECK = [[-0.045, 0.015], [-0.06, 0.015], [-0.045, -0.015], [-0.06, -0.015]]
STATION = {"rotation": np.eye(3).tolist(), "position": [0.0, 0.0, 2.0], "dt1": 0.0, "dt2": 0.0}
NO_STATIONS = (
    "geometry.base_stations: the dataset's geometry gives no base stations: calibrate them "
    "first (crs calibrate-lighthouse)"
)


@pytest.fixture
def deck_only(tmp_path: Path) -> Path:
    """The user recording of the conftest with ``geometry: {photodiodes: ...}`` only."""
    folder = tmp_path / "deck_only"
    write_user_recording(folder)
    meta = yaml.safe_load((folder / "dataset.yaml").read_text())
    meta["geometry"] = {"photodiodes": DECK}
    (folder / "dataset.yaml").write_text(yaml.safe_dump(meta))
    return folder


def test_a_deck_only_geometry_loads_without_stations(deck_only: Path, tmp_path: Path):
    """Stations unknown (None), sweeps of any station kept; saving keeps the block as it was."""
    data = Dataset.load(deck_only)
    assert data.geometry.base_stations is None
    assert data.geometry.photodiodes == tuple(map(tuple, DECK))
    assert data.measurements is not None
    assert {m.sensor for m in data.measurements} >= {"lighthouse/1/2"}
    again = Dataset.load(data.save(tmp_path / "copy"))
    assert again.geometry == data.geometry
    saved = yaml.safe_load((tmp_path / "copy" / "dataset.yaml").read_text())
    assert saved["geometry"] == {"photodiodes": DECK}


def test_a_deck_only_geometry_with_null_stations_loads():
    """``base_stations: null`` (an empty YAML key) is the same as leaving it out."""
    geometry = Geometry.from_dict({"base_stations": None, "photodiodes": DECK})
    assert geometry.base_stations is None


def _estimate(data: Dataset):
    from crs_core.estimation.offline import estimate_dataset

    return estimate_dataset(data, "ekf", "auto")


def _model(data: Dataset):
    from crs_core.estimation.offline import dataset_model

    return dataset_model(data)


def _identification(data: Dataset):
    from crs_core.identification.models import identification_model

    return identification_model(data, [], None, "--params")


def _fixes(data: Dataset):
    from crs_core.identification.reference import position_reference

    return position_reference(replace(data, x=None))


def _replay(data: Dataset):
    from crs_core.analysis.consistency import channel_errors

    return channel_errors(data)


@pytest.mark.parametrize(
    "reader",
    [_model, _estimate, _identification, _fixes, _replay, lambda d: d.geometry.parameters()],
    ids=["dataset_model", "estimate", "identification", "lighthouse fixes", "replay", "params"],
)
def test_readers_that_need_stations_refuse_a_deck_only_geometry(deck_only: Path, reader):
    """Estimators, identification, validation's Lighthouse fixes and the sensor replay stop
    with one line naming geometry.base_stations instead of crashing."""
    data = Dataset.load(deck_only)
    data.x = np.zeros((len(data.t), 6))
    data.u = np.zeros((len(data.t), 2))
    with pytest.raises(FieldError) as caught:
        reader(data)
    assert caught.value.field == "geometry.base_stations"
    assert str(caught.value) == NO_STATIONS


@pytest.mark.parametrize(
    ("block", "field", "message"),
    [
        ({}, "geometry", "gives neither base_stations nor photodiodes"),
        ({"notes": "x"}, "geometry", "gives neither base_stations nor photodiodes"),
        ({"base_stations": None, "photodiodes": None}, "geometry", "gives neither"),
        ({"base_stations": [STATION]}, "geometry.photodiodes", "missing: photodiodes 0..3"),
        ({"base_stations": [], "photodiodes": DECK}, "geometry.base_stations", "needs at least"),
        ({"base_stations": {"a": 1}, "photodiodes": DECK}, "geometry.base_stations", "a list"),
        ({"photodiodes": DECK[:3]}, "geometry.photodiodes", "expected shape (4, 2)"),
    ],
)
def test_a_geometry_without_stations_or_photodiodes_names_the_field(block, field, message):
    with pytest.raises(FieldError) as caught:
        Geometry.from_dict(block)
    assert caught.value.field == field
    assert message in caught.value.reason
    assert "\n" not in str(caught.value)


def test_a_deck_only_dataset_yaml_without_photodiodes_is_refused(deck_only: Path):
    """On disk too: a geometry block with neither key names ``geometry``."""
    meta = yaml.safe_load((deck_only / "dataset.yaml").read_text())
    meta["geometry"] = {}
    (deck_only / "dataset.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(FieldError, match=r"^geometry: gives neither base_stations nor photo"):
        Dataset.load(deck_only)
