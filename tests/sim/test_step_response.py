"""step_metrics against the closed forms of a first- and a second-order step response."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crs_core.errors import FieldError
from sim.step_response import step_metrics

DT = 1e-5
T = np.arange(0.0, 3.0 + DT / 2, DT)


def test_a_first_order_step_up_and_down() -> None:
    tau = 0.5  # still 0.3 % from the target over the last 0.2 s
    for start, target in ((0.0, 1.0), (0.2, -0.2)):
        y = start + (target - start) * (1.0 - np.exp(-T / tau))
        m = step_metrics(T, y, start, target)
        assert m.rise_time == pytest.approx(tau * math.log(9.0), abs=2 * DT)
        assert m.time_to_90 == pytest.approx(tau * math.log(10.0), abs=2 * DT)
        assert m.overshoot == 0.0
        assert m.settling_time == pytest.approx(tau * math.log(50.0), abs=2 * DT)
        # mean of (target - y) over the last 0.2 s: the integral of the exponential tail
        tail = (target - start) * tau / 0.2 * (math.exp(-2.8 / tau) - math.exp(-3.0 / tau))
        assert m.steady_state_error == pytest.approx(tail, rel=1e-3, abs=1e-15)


def test_a_second_order_step_overshoots_as_the_damping_says() -> None:
    zeta, omega = 0.5, 20.0
    root = math.sqrt(1 - zeta**2)
    decay, omega_d = zeta * omega, omega * root
    y = 1.0 - np.exp(-decay * T) * (np.cos(omega_d * T) + zeta / root * np.sin(omega_d * T))
    m = step_metrics(T, y, 0.0, 1.0)
    assert m.overshoot == pytest.approx(math.exp(-zeta * math.pi / root), rel=1e-4)
    # the envelope exp(-decay t) / root bounds the error; the last time outside 2 % lies
    # before the envelope itself falls to 2 %
    assert m.settling_time <= math.log(1 / (0.02 * root)) / decay
    assert m.settling_time > math.pi / omega_d  # after the first peak
    assert abs(m.steady_state_error) < 1e-12


def test_a_response_that_never_reaches_90_percent_is_refused() -> None:
    with pytest.raises(FieldError) as error:
        step_metrics(T, 0.5 * (1.0 - np.exp(-T / 0.1)), 0.0, 1.0)
    assert error.value.field == "y"
