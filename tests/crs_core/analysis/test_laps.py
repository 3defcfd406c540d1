"""Tests of crs_core.analysis.laps: progress, laps and lap times from arc lengths."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.analysis.laps import LapCounter
from crs_core.errors import FieldError


def test_lap_counter_start_off_the_line() -> None:
    length = 11.568  # m, the demo track's lap
    counter = LapCounter(length)
    speed, s0 = 1.0, 3.0  # m/s, m: the first partial lap is 8.568 m long
    stamps = np.arange(0.0, 40.0, 0.02)
    for t in stamps:
        counter.update(float(t), (s0 + speed * t) % length)
    assert counter.progress == pytest.approx(s0 + speed * stamps[-1])
    # Line crossings at t = 8.568, 20.136, 31.704 s: two full laps after the partial one.
    assert counter.crossing_stamps == pytest.approx([8.568, 20.136, 31.704], abs=1e-9)
    assert counter.laps_completed == 2
    assert counter.lap_times == pytest.approx([length / speed] * 2, abs=1e-9)


def test_lap_counter_start_on_the_line_and_reversing() -> None:
    length = 10.0
    counter = LapCounter(length)
    counter.update(0.0, 0.0)
    for stamp in (4.0, 8.0, 9.0):  # steps shorter than half a lap
        counter.update(stamp, stamp)
    counter.update(10.0, 1.0)  # crossed the line at t = 9.5
    assert counter.laps_completed == 1
    assert counter.lap_times == pytest.approx([9.5])
    counter.update(11.0, 9.5)  # backwards over the line
    counter.update(12.0, 1.5)  # and forwards again: not a new lap
    assert counter.laps_completed == 1
    assert counter.progress == pytest.approx(11.5)
    with pytest.raises(FieldError, match="stamp") as error:
        counter.update(11.0, 2.0)
    assert error.value.field == "stamp"
    counter.reset()
    assert counter.laps_completed == 0
    assert counter.progress == 0.0


@pytest.mark.parametrize("length", [0.0, -1.0, float("nan"), float("inf")])
def test_a_lap_length_that_is_not_positive_and_finite_is_refused(length: float) -> None:
    with pytest.raises(FieldError, match="length") as error:
        LapCounter(length)
    assert error.value.field == "length"
