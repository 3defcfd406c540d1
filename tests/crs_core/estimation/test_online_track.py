"""The online parameters' track: what an estimate carried, the final summary, the CSV."""

from __future__ import annotations

import csv

import numpy as np

from crs_core.estimation.base import OnlineValue
from crs_core.estimation.online_track import CSV_COLUMNS, OnlineTrack


def test_a_track_keeps_what_each_estimate_carried_and_writes_priors_first(tmp_path):
    track = OnlineTrack.empty(3, ("Cm1", "grip"))
    track.set(0, {"Cm1": OnlineValue(0.9, 0.05, True), "grip": OnlineValue(1.0, 0.1, False)})
    track.set(2, {"Cm1": OnlineValue(0.8, 0.04, True), "grip": OnlineValue(0.9, 0.05, True)})
    # estimate 1 was lost: nothing carried, NaN kept, no CSV row
    assert np.isnan(track.value[:, 1]).all()
    assert track.final_summary() == {
        "Cm1": {"value": 0.8, "std": 0.04, "informed": True},
        "grip": {"value": 0.9, "std": 0.05, "informed": True},
    }
    path = track.write_csv(
        tmp_path / "p.csv", np.array([0.5, 0.6, 0.7]), {"Cm1": (1.0, 0.1), "grip": (1.0, 0.1)}
    )
    rows = list(csv.reader(path.open()))
    assert tuple(rows[0]) == CSV_COLUMNS
    assert rows[1:3] == [["0.5000", "Cm1", "1.0", "0.1"], ["0.5000", "grip", "1.0", "0.1"]]
    assert [r[:2] for r in rows[3:]] == [
        ["0.5000", "Cm1"],
        ["0.5000", "grip"],
        ["0.7000", "Cm1"],
        ["0.7000", "grip"],
    ]
    assert float(rows[-1][2]) == 0.9


def test_an_empty_track_has_no_names_and_no_summary():
    track = OnlineTrack.empty(4)
    assert track.names == () and track.value.shape == (0, 4) and track.final_summary() == {}
