"""Tests of crs_core.model.chronos: the Chronos defaults and the base-station parameters."""

import math

import numpy as np
import pytest

from crs_core.analysis.angles import wrap_angle
from crs_core.model.chronos import (
    base_station_from_parameters,
    base_station_parameters,
    default_base_stations,
    dynamics_parameters,
)
from crs_core.model.lighthouse import RECORDED_BASE_STATION


def test_chronos_defaults_are_the_identified_values():
    """Defaults equal the values identified for the recorded car (data README)."""
    params = dynamics_parameters()
    assert params.value("m") == 0.242 and params.value("Bf") == 5.19600518
    assert params.value("gamma") == 0.50199235 and params.value("eps") == 0.2
    assert params.value("r") == 0.0175 and params.value("b_car") == 0.12
    assert params["Cm1"].unit == "N" and params["Iz"].unit == "kg m^2"


def test_default_stations_are_the_recorded_one_turned_about_world_z():
    """Station ``i`` of three sits at the recorded station's height and distance from the
    origin, turned by 120 degrees per station, and looks in the direction turned alike."""
    stations = default_base_stations(3)
    recorded = RECORDED_BASE_STATION
    px, py, pz = recorded.position
    for i, station in enumerate(stations):
        turn = 2.0 * math.pi * i / 3
        x, y, z = station.position
        assert z == pytest.approx(pz, abs=1e-12)
        assert math.hypot(x, y) == pytest.approx(math.hypot(px, py), abs=1e-12)
        assert wrap_angle(math.atan2(y, x) - math.atan2(py, px)) == pytest.approx(
            wrap_angle(turn), abs=1e-9
        )
        axis, recorded_axis = station.rotation[:, 2], recorded.rotation[:, 2]
        assert axis[2] == pytest.approx(recorded_axis[2], abs=1e-9)
        assert wrap_angle(
            math.atan2(axis[1], axis[0]) - math.atan2(recorded_axis[1], recorded_axis[0])
        ) == pytest.approx(wrap_angle(turn), abs=1e-9)
        assert (station.dt1, station.dt2) == (recorded.dt1, recorded.dt2)


def test_base_station_parameters_read_back_to_the_stations():
    stations = default_base_stations(2)
    params = base_station_parameters(stations)
    assert list(params)[:9] == [
        "bs0_phi1", "bs0_phi2", "bs0_phi3", "bs0_x", "bs0_y", "bs0_z", "bs0_dt1", "bs0_dt2",
        "bs1_phi1",
    ]  # fmt: skip
    for i, station in enumerate(stations):
        again = base_station_from_parameters(params, i)
        np.testing.assert_allclose(again.rotation, station.rotation, atol=1e-12)
        assert again.position == pytest.approx(station.position, abs=1e-12)
        assert (again.dt1, again.dt2) == (station.dt1, station.dt2)
