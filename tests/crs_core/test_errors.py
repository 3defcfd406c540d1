"""``FieldError``: the field and the reason travel with the error, not inside its text."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from crs_core.errors import (
    FieldError,
    finite_number,
    parse_finite,
    require_finite,
    require_non_negative,
    require_positive,
    require_within,
)


def test_the_field_and_the_reason_are_attributes_and_make_the_message() -> None:
    error = FieldError("imu.angular_velocity", "contains NaN")
    assert isinstance(error, ValueError)
    assert (error.field, error.reason, str(error)) == (
        "imu.angular_velocity",
        "contains NaN",
        "imu.angular_velocity: contains NaN",
    )
    assert str(error.within("car_state")) == "car_state.imu.angular_velocity: contains NaN"
    assert error.renamed("--x0").field == "--x0" and error.renamed("--x0").reason == "contains NaN"


@dataclass
class _Settings:
    rate_hz: float = 50.0
    lag: float = 0.0
    share: float = 0.5


@pytest.mark.parametrize(
    ("check", "value", "message"),
    [
        (require_finite, math.nan, "rate_hz: must be a finite number, got nan"),
        (require_finite, "50", "rate_hz: must be a finite number, got '50'"),
        (require_finite, True, "rate_hz: must be a finite number, got True"),
        (require_positive, 0.0, "rate_hz: must be a finite number > 0, got 0.0"),
        (require_positive, math.inf, "rate_hz: must be a finite number > 0, got inf"),
        (require_non_negative, -1, "rate_hz: must be a finite number >= 0, got -1"),
        (require_non_negative, None, "rate_hz: must be a finite number >= 0, got None"),
    ],
)
def test_the_shared_checks_name_the_first_bad_field(check, value, message) -> None:
    settings = _Settings(rate_hz=value)
    with pytest.raises(FieldError) as caught:
        check(settings, "share", "rate_hz", "lag")  # rate_hz is the first bad one
    assert (caught.value.field, str(caught.value)) == ("rate_hz", message)
    with pytest.raises(FieldError) as caught:
        check(settings, "rate_hz", prefix="estimator")
    assert caught.value.field == "estimator.rate_hz"


def test_the_shared_checks_pass_good_values() -> None:
    settings = _Settings(rate_hz=np.float32(50.0), lag=np.int64(0))
    require_finite(settings, "rate_hz", "lag", "share")
    require_positive(settings, "rate_hz", "share")
    require_non_negative(settings, "rate_hz", "lag", "share")
    require_within(settings, "share", 0, 1)
    assert finite_number("share", np.float64(0.5)) == 0.5


@pytest.mark.parametrize(
    ("share", "kwargs", "message"),
    [
        (1.5, {}, "share: must be within [0, 1], got 1.5"),
        (0.0, {"low_open": True}, "share: must be within (0, 1], got 0.0"),
        (1.0, {"high_open": True, "unit": "s"}, "share: must be within [0, 1) s, got 1.0"),
        (math.nan, {}, "share: must be within [0, 1], got nan"),
    ],
)
def test_within_names_the_interval(share: float, kwargs: dict, message: str) -> None:
    with pytest.raises(FieldError) as caught:
        require_within(_Settings(share=share), "share", 0, 1, **kwargs)
    assert (caught.value.field, str(caught.value)) == ("share", message)


@pytest.mark.parametrize(
    ("text", "number"),
    [
        *[("1.5", 1.5), (" -2e-3 ", -2e-3), ("0", 0.0)],
        *[("nan", None), ("-inf", None), ("1e999", None), ("", None), ("3 ms", None), ("x", None)],
    ],
)
def test_parse_finite_reads_finite_numbers_only(text: str, number: float | None) -> None:
    assert parse_finite(text) == number
