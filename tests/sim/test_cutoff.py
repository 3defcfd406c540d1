"""The firmware's link watchdog (sim.cutoff), shared by the emulator and the simulator node."""

from __future__ import annotations

import pytest

from crs_core.errors import FieldError
from sim.cutoff import DISCONNECT_THRESHOLD_S, MotorCutoff


def test_starts_cut_and_the_first_command_is_not_counted_as_a_cut() -> None:
    cutoff = MotorCutoff()
    assert cutoff.cut and cutoff.cuts == 0
    assert not cutoff.expired(10.0)  # no command yet: nothing to time out
    assert cutoff.commanded(10.0)  # ends the start's cut
    assert not cutoff.cut and cutoff.cuts == 0


def test_cuts_once_at_the_threshold_after_the_last_command_until_the_next() -> None:
    cutoff = MotorCutoff()
    cutoff.commanded(0.0)
    assert not cutoff.commanded(0.1)  # driving already
    assert not cutoff.expired(0.1 + DISCONNECT_THRESHOLD_S - 0.004)
    assert cutoff.expired(0.1 + DISCONNECT_THRESHOLD_S)  # at 200 ms, not 204
    assert cutoff.cut and cutoff.cuts == 1
    assert not cutoff.expired(5.0)  # cut already: counted once
    assert cutoff.commanded(5.0) and not cutoff.cut
    assert cutoff.expired(5.0 + DISCONNECT_THRESHOLD_S) and cutoff.cuts == 2


@pytest.mark.parametrize("threshold", [0.0, -0.2, float("nan"), float("inf")])
def test_a_threshold_that_is_not_a_positive_time_is_refused(threshold: float) -> None:
    with pytest.raises(FieldError, match="threshold"):
        MotorCutoff(threshold)
