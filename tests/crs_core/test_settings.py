"""Declared bounds: the field constructors, ``check_bounds`` and the ``Settings`` base."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest

from crs_core.errors import FieldError
from crs_core.settings import (
    Bound,
    Settings,
    bound_of,
    check_bounds,
    finite,
    non_negative,
    positive,
    within,
)


def _refused(build: Callable[[], object]) -> str:
    """The message of the FieldError ``build()`` raises."""
    with pytest.raises(FieldError) as caught:
        build()
    return str(caught.value)


@dataclass(frozen=True)
class _Timing(Settings):
    rate_hz: float = positive(60.0)
    lag: float = non_negative(0.02)
    share: float = within(0.5, low=0, high=1, high_open=True, unit="s")
    offset: float = finite(-1.0)
    label: str = "free"  # no bound: never checked


@dataclass(frozen=True)
class _Battery(Settings, prefix="battery"):
    empty_voltage: float = positive(6.8)
    full_voltage: float = positive(8.4)

    def _check_relations(self) -> None:
        if not self.empty_voltage < self.full_voltage:
            raise FieldError("battery.empty_voltage", "must be < full_voltage")


@dataclass(frozen=True)
class _BigBattery(_Battery):
    capacity_ah: float = positive(3.0)
    cells: int = 2

    def _check_relations(self) -> None:
        super()._check_relations()
        if self.cells < 1:
            raise FieldError("battery.cells", "must be >= 1")


def test_the_defaults_are_the_declared_ones_and_pass() -> None:
    settings = _Timing()
    assert (settings.rate_hz, settings.lag, settings.share, settings.offset) == (
        60.0,
        0.02,
        0.5,
        -1.0,
    )
    assert [f.default for f in dataclasses.fields(_Timing)][:4] == [60.0, 0.02, 0.5, -1.0]


@pytest.mark.parametrize(
    "values",
    [
        {"rate_hz": 1e-12},
        {"lag": 0.0},
        {"lag": 0},
        {"share": 0.0},
        {"share": 0.999999},
        {"offset": -1e300},
        {"rate_hz": np.float32(50.0), "lag": np.int64(0)},
        {"label": math.nan},  # not bounded
    ],
)
def test_values_on_the_edges_are_accepted(values: dict[str, object]) -> None:
    _Timing(**values)  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"rate_hz": 0.0}, "rate_hz: must be a finite number > 0, got 0.0"),
        ({"rate_hz": -1}, "rate_hz: must be a finite number > 0, got -1"),
        ({"rate_hz": math.inf}, "rate_hz: must be a finite number > 0, got inf"),
        ({"rate_hz": True}, "rate_hz: must be a finite number > 0, got True"),
        ({"rate_hz": "60"}, "rate_hz: must be a finite number > 0, got '60'"),
        ({"lag": -1e-9}, "lag: must be a finite number >= 0, got -1e-09"),
        ({"lag": math.nan}, "lag: must be a finite number >= 0, got nan"),
        ({"lag": None}, "lag: must be a finite number >= 0, got None"),
        ({"share": 1.0}, "share: must be within [0, 1) s, got 1.0"),
        ({"share": -0.1}, "share: must be within [0, 1) s, got -0.1"),
        ({"share": False}, "share: must be within [0, 1) s, got False"),
        ({"offset": -math.inf}, "offset: must be a finite number, got -inf"),
        ({"offset": math.nan}, "offset: must be a finite number, got nan"),
        ({"offset": True}, "offset: must be a finite number, got True"),
        # the first bad field in field order
        ({"share": 2.0, "lag": -1.0}, "lag: must be a finite number >= 0, got -1.0"),
    ],
)
def test_a_bad_value_is_refused_naming_its_field(values: dict[str, object], message: str) -> None:
    with pytest.raises(FieldError) as caught:
        _Timing(**values)  # type: ignore[arg-type]
    assert str(caught.value) == message
    assert caught.value.field == message.split(":")[0]


def test_open_and_closed_ends_of_within() -> None:
    @dataclass
    class Share(Settings):
        closed: float = within(0.0, low=0, high=1)
        open_low: float = within(1.0, low=0, high=1, low_open=True)

    Share(closed=1.0, open_low=1.0)
    assert _refused(lambda: Share(open_low=0.0)) == "open_low: must be within (0, 1], got 0.0"
    assert _refused(lambda: Share(closed=1.5)) == "closed: must be within [0, 1], got 1.5"


def test_a_field_without_a_default_stays_required() -> None:
    @dataclass(frozen=True)
    class Sensor(Settings):
        rate_hz: float = positive()
        noise: tuple[float, ...] = ()

    assert Sensor(250.0).rate_hz == 250.0
    with pytest.raises(TypeError):
        Sensor()  # type: ignore[call-arg]
    assert _refused(lambda: Sensor(0.0)) == "rate_hz: must be a finite number > 0, got 0.0"


def test_the_prefix_names_the_dotted_path_and_is_inherited() -> None:
    assert (
        _refused(lambda: _Battery(full_voltage=-8.4))
        == "battery.full_voltage: must be a finite number > 0, got -8.4"
    )
    assert (
        _refused(lambda: _BigBattery(capacity_ah=0))
        == "battery.capacity_ah: must be a finite number > 0, got 0"
    )


def test_the_relations_run_after_the_bounds_and_are_inherited() -> None:
    assert (
        _refused(lambda: _Battery(empty_voltage=9.0))
        == "battery.empty_voltage: must be < full_voltage"
    )
    assert (
        _refused(lambda: _BigBattery(empty_voltage=9.0))
        == "battery.empty_voltage: must be < full_voltage"
    )
    assert _refused(lambda: _BigBattery(cells=0)) == "battery.cells: must be >= 1"
    # a bound is checked first: a NaN never reaches the comparison
    assert (
        _refused(lambda: _Battery(empty_voltage=math.nan))
        == "battery.empty_voltage: must be a finite number > 0, got nan"
    )


def test_inheritance_checks_the_bases_fields_too() -> None:
    assert [f.name for f in dataclasses.fields(_BigBattery)][:3] == [
        "empty_voltage",
        "full_voltage",
        "capacity_ah",
    ]
    assert (
        _refused(lambda: _BigBattery(empty_voltage=-1.0))
        == "battery.empty_voltage: must be a finite number > 0, got -1.0"
    )


def test_frozen_settings_are_checked_again_by_replace() -> None:
    settings = _Timing()
    assert dataclasses.replace(settings, lag=0.5).lag == 0.5
    assert (
        _refused(lambda: dataclasses.replace(settings, lag=-0.5))
        == "lag: must be a finite number >= 0, got -0.5"
    )
    with pytest.raises(dataclasses.FrozenInstanceError):
        settings.lag = 1.0  # type: ignore[misc]
    assert (
        _refused(lambda: dataclasses.replace(_BigBattery(), full_voltage=6.0))
        == "battery.empty_voltage: must be < full_voltage"
    )


def test_mutable_settings_are_checked_again_by_validate() -> None:
    @dataclass
    class Tuning(Settings):
        gain: float = non_negative(1.0)

    tuning = Tuning()
    tuning.gain = -2.0
    assert _refused(lambda: tuning.validate()) == "gain: must be a finite number >= 0, got -2.0"


def test_floats_stores_the_checked_bounded_fields_as_float_and_is_inherited() -> None:
    @dataclass(frozen=True)
    class Gains(Settings, floats=True):
        kp: float = non_negative(1)
        rate_hz: float = positive(250)
        steps: int = 3  # no bound: kept as given

    @dataclass(frozen=True)
    class MoreGains(Gains):
        kd: float = finite(0)

    gains = MoreGains(kp=2, rate_hz=np.float32(100.0))
    assert [type(v) for v in (gains.kp, gains.rate_hz, gains.kd, gains.steps)] == [
        float,
        float,
        float,
        int,
    ]
    assert (gains.kp, gains.rate_hz) == (2.0, 100.0)
    assert type(dataclasses.replace(gains, kd=1).kd) is float
    assert _refused(lambda: Gains(kp=True)) == "kp: must be a finite number >= 0, got True"
    assert type(_Timing(lag=1).lag) is int  # without floats=True: stored as given


def test_check_bounds_takes_any_dataclass_and_a_prefix() -> None:
    @dataclass
    class Plain:
        lag: float = non_negative(0.0)

    check_bounds(Plain())
    assert (
        _refused(lambda: check_bounds(Plain(lag=-1.0), "estimator"))
        == "estimator.lag: must be a finite number >= 0, got -1.0"
    )
    with pytest.raises(TypeError):
        check_bounds(object())


def test_the_bound_is_in_the_field_metadata() -> None:
    bounds = {f.name: bound_of(f) for f in dataclasses.fields(_Timing)}
    assert bounds == {
        "rate_hz": Bound("positive", low=0.0, low_open=True),
        "lag": Bound("non_negative", low=0.0),
        "share": Bound("within", 0, 1, high_open=True, unit="s"),
        "offset": Bound("finite"),
        "label": None,
    }


def test_a_bound_words_its_requirement_as_its_error_does() -> None:
    bounds = [bound_of(f) for f in dataclasses.fields(_Timing)][:4]
    assert [bound.requirement() for bound in bounds if bound is not None] == [
        "a finite number > 0",
        "a finite number >= 0",
        "within [0, 1) s",
        "a finite number",
    ]


def test_a_malformed_bound_is_a_programming_error() -> None:
    with pytest.raises(ValueError, match="kind"):
        Bound("odd")
    with pytest.raises(ValueError, match="low: must be below high"):
        within(0.5, low=1, high=0)
