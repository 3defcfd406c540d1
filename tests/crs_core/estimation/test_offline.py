"""Tests of crs_core.estimation.offline: an estimator over a whole dataset, blind or not."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from crs_core.dataset import Dataset
from crs_core.errors import FieldError
from crs_core.estimation.offline import (
    POSE_X0_STD,
    STATUS_CODES,
    available_sensors,
    estimate_dataset,
    rate_stamps,
    reference_comparison,
)
from sim.scenarios import standard_drive
from tests.crs_core.estimation.conftest import KINDS

DURATION = 6.0


@pytest.fixture(scope="module")
def drive() -> Dataset:
    """6 s of the standard joystick drive (default sensor noise), with stream and truth."""
    return standard_drive(3, DURATION).to_dataset()


@pytest.fixture(scope="module")
def blind_mhe(drive: Dataset):
    return estimate_dataset(drive, "mhe", "lh+imu+we")


@pytest.fixture(scope="module")
def samples_only(drive: Dataset, tmp_path_factory: pytest.TempPathFactory) -> Dataset:
    """The drive as a recording without inputs and without stream: t, y, x and dataset.yaml."""
    folder = tmp_path_factory.mktemp("offline") / "no_inputs"
    replace(drive, u=None, measurements=None, inputs=None, truth_t=None, truth_x=None).save(folder)
    assert not (folder / "u.npy").exists() and not (folder / "stream.npz").exists()
    return Dataset.load(folder)


def position_error(result, dataset: Dataset) -> np.ndarray:
    return np.hypot(result.x[0] - dataset.x[:, 0], result.x[1] - dataset.x[:, 1])


def test_estimates_are_on_the_dataset_time_base(blind_mhe, drive: Dataset):
    """t is dataset.t itself; x and covariance (6, N); one status and reason per sample."""
    n = drive.t.size
    np.testing.assert_array_equal(blind_mhe.t, drive.t)
    assert blind_mhe.x.shape == (6, n) and blind_mhe.covariance_diag.shape == (6, n)
    assert blind_mhe.status.shape == (n,) and blind_mhe.reasons.shape == (n,)
    assert set(blind_mhe.status) <= set(STATUS_CODES)
    assert np.all(np.isfinite(blind_mhe.x)) and np.all(blind_mhe.covariance_diag > 0)
    codes = blind_mhe.status_codes
    np.testing.assert_array_equal(codes, [STATUS_CODES[s] for s in blind_mhe.status])


def test_blind_start_finds_the_car_within_a_second(blind_mhe, drive: Dataset):
    """Lost only while waiting for the Lighthouse; the first fix within 1 s, then never lost."""
    d = blind_mhe.diagnostics
    assert blind_mhe.status[0] == "lost"
    assert blind_mhe.reasons[0] == "waiting for a Lighthouse fix"
    assert d["start"] == "blind"
    assert d["time_to_first_fix_s"] is not None and d["time_to_first_fix_s"] < 1.0
    first = np.flatnonzero(blind_mhe.status != "lost")[0]
    assert np.all(blind_mhe.status[first:] != "lost")
    assert d["status_counts"]["lost"] == first
    assert sum(d["status_counts"].values()) == drive.t.size


def test_blind_mhe_tracks_the_truth(blind_mhe, drive: Dataset):
    """Position error below 1 cm at every sample from 2 s on; the comparison says 'truth'."""
    error = position_error(blind_mhe, drive)
    assert np.max(error[drive.t >= 2.0]) < 0.01
    comparison = reference_comparison(blind_mhe, drive)
    assert comparison["reference"] == "simulation truth"
    assert comparison["rmse"]["position"] < 0.005
    assert comparison["rmse_settled"]["position"] <= comparison["rmse"]["position"] * 1.5


def test_diagnostics_count_what_the_estimator_used(blind_mhe, drive: Dataset):
    """Every sensor of the stream is processed; commands delivered; the counters are plain."""
    d = blind_mhe.diagnostics
    assert set(d["processed"]) == {"imu", "wheel_encoders", "lighthouse/0/1", "lighthouse/0/2"}
    assert d["input_mode"] == "commanded"  # auto: the recording has commands
    assert d["inputs_delivered"] > 0 and d["data"] == "stream.npz, inputs from stream.npz"
    assert d["rate_hz"] == 60.0 and d["reinitializations"] == 0
    assert d["measurements_delivered"] + d["events_after_last_sample"] >= len(drive.measurements)


def test_recording_without_inputs_runs_input_free(samples_only: Dataset):
    """No u.npy, no stream: 'auto' stays input-free on the y.npy samples and still tracks."""
    assert samples_only.u is None and samples_only.measurements is None
    assert available_sensors(samples_only) == "lh+gyro+we"
    result = estimate_dataset(samples_only, "ekf", "auto")
    d = result.diagnostics
    assert d["input_mode"] == "estimated" and d["inputs_delivered"] == 0
    assert d["data"] == "y.npy samples, no inputs recorded"
    assert d["sensors"] == "lh+gyro+we"
    assert d["time_to_first_fix_s"] < 1.0
    error = position_error(result, samples_only)
    assert np.max(error[samples_only.t >= 2.0]) < 0.02
    with pytest.raises(ValueError, match=r"^inputs: 'commanded' needs recorded inputs"):
        estimate_dataset(samples_only, "ekf", "lh", inputs="commanded")


def test_estimated_inputs_withhold_the_commands(drive: Dataset):
    """inputs='estimated' delivers no command, and the Lighthouse alone still finds the car."""
    result = estimate_dataset(drive, "ekf", "lh", inputs="estimated")
    d = result.diagnostics
    assert d["inputs_delivered"] == 0 and d["input_mode"] == "estimated"
    assert d["data"] == "stream.npz, inputs from stream.npz withheld"
    assert set(d["ignored"]) == {"imu", "wheel_encoders"}
    assert np.median(position_error(result, drive)[drive.t >= 2.0]) < 0.005


@pytest.mark.parametrize("size", [3, 6])
def test_given_start_state_is_never_lost(drive: Dataset, size: int):
    """x0 of 3 (pose at rest, loose) or 6 values: no lost sample, the truth followed."""
    x0 = drive.truth_x[0, :size]
    seen = []
    result = estimate_dataset(drive, "ekf", "lh+imu+we", x0=x0, progress=seen.append)
    assert result.diagnostics["status_counts"]["lost"] == 0
    assert result.diagnostics["time_to_first_fix_s"] == pytest.approx(drive.t[0])
    assert result.diagnostics["start"] == pytest.approx(list(x0))
    assert np.max(position_error(result, drive)[drive.t >= 2.0]) < 0.01
    assert seen[-1] == 1.0 and seen == sorted(seen)
    if size == 3:
        assert POSE_X0_STD[0] > 0.05  # loose: the pose of a car placed by hand


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"x0": [1.0, 2.0]}, r"^x0: needs 3 \(x, y, yaw\) or 6"),
        ({"x0": [1.0, np.nan, 0.0]}, r"^x0: .* with NaN or inf"),
        ({"rate_hz": 0.0}, r"^rate_hz: must be finite and > 0"),
        ({"rate_hz": float("inf")}, r"^rate_hz: must be finite and > 0"),
        ({"sensors": "lh+sonar"}, r"^sensors: 'lh\+sonar' must combine"),
        ({"sensors": "pose"}, r"^sensors: the dataset has no data for pose"),
        ({"kind": "ukf"}, r"^estimator: must be 'ekf' or 'mhe'"),
        ({"at": [1.0, 1.0]}, r"^at: stamps must be strictly increasing"),
        (
            {"at": [-1.0, 1.0]},
            r"^at: -1\.000 \.\. 1\.000 s reaches outside the data \(0\.000 \.\. ",
        ),
        ({"at": [1.0, 99.0]}, r"^at: 1\.000 \.\. 99\.000 s reaches outside the data"),
        ({"at": [[1.0, 2.0]]}, r"^at: must be a non-empty 1-D array"),
        ({"at": []}, r"^at: must be a non-empty 1-D array"),
        ({"at": [1.0, np.nan]}, r"^at: holds a stamp that is not a finite number"),
        ({"at": "soon"}, r"^at: must be an array of stamps"),
    ],
)
def test_bad_arguments_are_one_line_errors(drive: Dataset, kwargs: dict, message: str):
    """Invalid x0, rate, sensors or kind: ValueError naming the argument, before any work."""
    arguments = {"kind": "mhe", "sensors": "lh", **kwargs}
    with pytest.raises(FieldError, match=message) as excinfo:
        estimate_dataset(drive, arguments.pop("kind"), arguments.pop("sensors"), **arguments)
    assert "\n" not in str(excinfo.value)
    assert excinfo.value.field == message[1:].split(":")[0]


def test_empty_dataset_is_refused(drive: Dataset, tmp_path: Path):
    """A dataset without samples is a ValueError naming t.npy."""
    empty = Dataset(t=np.zeros(0), u=None, y=np.zeros((0, drive.y.shape[1])))
    with pytest.raises(FieldError, match=r"^dataset: has no samples \(t\.npy is empty\)"):
        estimate_dataset(empty, "ekf", "lh")


REAL = Path(__file__).resolve().parents[4] / "shared" / "data" / "chronos_real"


@pytest.mark.skipif(not REAL.is_dir(), reason="real recordings not available")
@pytest.mark.parametrize("kind", KINDS)
def test_input_free_estimation_on_a_real_recording(kind):
    """Real run 1, blind, Lighthouse + gyro + wheel encoders, commands withheld: no run-away,
    within 2 cm of the car's own on-line estimate (the reference, not ground truth). Before the
    MHE's backtracking went down to 2^-11 it drifted half a metre away here."""
    from crs_core.dataset import Dataset
    from crs_core.estimation.offline import estimate_dataset, reference_comparison

    dataset = Dataset.load(REAL / "fie_mpc_lighthouse_1")
    result = estimate_dataset(dataset, kind, "lh+gyro+we", inputs="estimated")
    comparison = reference_comparison(result, dataset)["rmse_settled"]
    assert comparison["position"] < 0.02, comparison
    assert result.diagnostics["reinitializations"] == 0


def test_estimates_at_other_stamps(drive: Dataset):
    """At the dataset's own stamps the EKF gives what it gives by default; at 100 Hz (between
    the 50 Hz samples) it tracks the truth as closely, and the comparison with the reference
    interpolates the reference to those stamps."""
    default = estimate_dataset(drive, "ekf", "lh+imu+we", x0=drive.x[0])
    same = estimate_dataset(drive, "ekf", "lh+imu+we", x0=drive.x[0], at=drive.t)
    np.testing.assert_array_equal(same.x, default.x)
    stamps = rate_stamps(drive, 100.0)
    assert stamps[0] == drive.t[0] and stamps[-1] <= drive.t[-1]
    np.testing.assert_allclose(np.diff(stamps), 0.01, rtol=0, atol=1e-9)
    fast = estimate_dataset(drive, "ekf", "lh+imu+we", x0=drive.x[0], at=stamps)
    np.testing.assert_array_equal(fast.t, stamps)
    assert fast.x.shape == (6, stamps.size) and fast.diagnostics["samples"] == stamps.size
    truth = np.stack([np.interp(stamps, drive.truth_t, drive.truth_x[:, i]) for i in (0, 1)])
    settled = stamps >= 2.0
    assert np.max(np.hypot(*(fast.x[:2] - truth))[settled]) < 0.01
    ours, theirs = reference_comparison(fast, drive), reference_comparison(default, drive)
    assert ours["samples"] == stamps.size
    assert ours["rmse_settled"]["x"] == pytest.approx(theirs["rmse_settled"]["x"], abs=2e-3)
    with pytest.raises(FieldError, match=r"^output_rate: must be finite and > 0 Hz"):
        rate_stamps(drive, 0.0)


def test_stamps_outside_the_data_are_left_out_and_counted():
    from crs_core.estimation.offline import stamps_within

    inside, outside = stamps_within([0.5, 1.0, 2.0, 3.013], 0.0, 3.0)
    np.testing.assert_array_equal(inside, [0.5, 1.0, 2.0])
    assert outside == 1
    with pytest.raises(FieldError, match=r"^at: 4\.000 \.\. 5\.000 s: no stamp lies inside"):
        stamps_within([4.0, 5.0], 0.0, 3.0)
    with pytest.raises(FieldError, match="strictly increasing"):
        stamps_within([1.0, 1.0], 0.0, 3.0)
