"""Model extensions ("effects") composed onto the base car model by name.

An effect adds parameters and may act at three places of the signal chain, in this order:

1. on the **command** before the actuators (``steering_offset``, ``steering_gain``,
   ``torque_deadzone``);
2. as an **actuator** with its own states (``steering_lag``, ``motor_lag``);
3. on a **sensor** output (``gyro_bias``, ``wheel_radius_error``, ``gyro_scale``,
   ``lighthouse_offset``).

Effects at the same place compose in registry order, so with both switched on the steering
angle is ``(1 + k) (delta_cmd + delta0)`` and the gyro reads ``(1 + s) (omega + b)`` (a
reparametrisation of the bias).

Every effect is nested in the base model: with its parameters at 0 the model is exactly the base
model (the lags only in the limit of a time constant going to 0). Every hook is a smooth CasADi
expression.

``input_delay`` is a pure transport delay of both inputs. It has no state-space form: the
simulator applies it exactly to the input history, and model users read it from
:meth:`crs_core.model.CarModel.input_delay`.

The registry :data:`EFFECTS` maps names to effect objects; the simulator switches effects on as
hidden truth, identification fits their parameters, the discrepancy workflow searches over them.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import casadi as ca

from crs_core.errors import parse_finite
from crs_core.model.plant import ParameterAccess
from crs_core.parameters import Parameter


@dataclass(frozen=True)
class Effect:
    """Base class: an effect that changes nothing. Subclasses override the hooks they need.

    Attributes
    ----------
    name : str
        Registry key, also the prefix of its parameters' group (``effect:<name>``).
    description : str
        The physical effect in one sentence.
    parameters : tuple of Parameter
        Its parameters; the value is the default used when the effect is switched on without one.
    states : tuple of (name, unit)
        Extra states it appends to the model state.
    """

    name: str
    description: str
    parameters: tuple[Parameter, ...]
    states: tuple[tuple[str, str], ...] = field(default=())

    def command(self, u: ca.SX, P: ParameterAccess) -> ca.SX:
        """Transform the commanded input ``[delta, T]`` before the actuators."""
        return u

    def actuator(self, z: ca.SX, u: ca.SX, P: ParameterAccess) -> tuple[ca.SX, ca.SX]:
        """Return (applied input, time derivative of this effect's states ``z``)."""
        return u, ca.SX(0, 1)

    def initial_states(self, u: list[float]) -> list[float]:
        """Values of this effect's states at rest under command ``u``."""
        return []

    def output(self, sensor: str, y: ca.SX, P: ParameterAccess) -> ca.SX:
        """Transform the output of sensor ``sensor`` (``imu``, ``wheel_encoders``, ...)."""
        return y


def _parameter(
    effect: str, name: str, value: float, unit: str, lower: float, upper: float, description: str
) -> Parameter:
    return Parameter(
        name, value, unit, lower, upper, abs(upper - lower) / 4, description, f"effect:{effect}"
    )


@dataclass(frozen=True)
class SteeringOffset(Effect):
    """Steering trim error: the wheels sit at ``delta_cmd + delta0``."""

    def command(self, u: ca.SX, P: ParameterAccess) -> ca.SX:
        return ca.vertcat(u[0] + P("steering_offset"), u[1])


@dataclass(frozen=True)
class FirstOrderLag(Effect):
    """First-order actuator on input channel ``channel`` with time constant parameter ``tau``."""

    channel: int = 0
    tau: str = ""

    def actuator(self, z: ca.SX, u: ca.SX, P: ParameterAccess) -> tuple[ca.SX, ca.SX]:
        applied = [u[0], u[1]]
        applied[self.channel] = z[0]
        return ca.vertcat(*applied), (u[self.channel] - z[0]) / P(self.tau)

    def initial_states(self, u: list[float]) -> list[float]:
        return [u[self.channel]]


@dataclass(frozen=True)
class GyroBias(Effect):
    """Constant additive bias on the IMU yaw rate."""

    def output(self, sensor: str, y: ca.SX, P: ParameterAccess) -> ca.SX:
        if sensor != "imu":
            return y
        return ca.vertcat(y[0], y[1], y[2] + P("gyro_bias"))


@dataclass(frozen=True)
class WheelRadiusError(Effect):
    """The wheels' true radius is ``r + wheel_radius_error``; encoders read ``v / (r + dr)``."""

    def output(self, sensor: str, y: ca.SX, P: ParameterAccess) -> ca.SX:
        if sensor != "wheel_encoders":
            return y
        return y * P("r") / (P("r") + P("wheel_radius_error"))


@dataclass(frozen=True)
class GyroScale(Effect):
    """Gyroscope scale-factor error: the IMU yaw rate reads ``(1 + gyro_scale_error) omega``."""

    def output(self, sensor: str, y: ca.SX, P: ParameterAccess) -> ca.SX:
        if sensor != "imu":
            return y
        return ca.vertcat(y[0], y[1], (1 + P("gyro_scale_error")) * y[2])


@dataclass(frozen=True)
class SteeringGain(Effect):
    """Servo linkage calibration error: the wheels sit at ``(1 + steering_gain_error) delta``."""

    def command(self, u: ca.SX, P: ParameterAccess) -> ca.SX:
        return ca.vertcat((1 + P("steering_gain_error")) * u[0], u[1])


#: Keeps the dead band's ``tanh`` argument finite at ``torque_deadzone = 0`` (bounds >= 0).
DEADZONE_EPS = 1e-6


@dataclass(frozen=True)
class TorqueDeadzone(Effect):
    """Motor/ESC dead band of half-width ``T0``, smoothed: ``T - T0 tanh(T / (T0 + eps))``.

    About 0 for ``|T| << T0``, about ``T - T0 sign(T)`` for ``|T| >> T0``, exactly ``T`` at
    ``T0 = 0``; smooth in ``T`` and ``T0`` (``T0`` is bounded below by 0, so the denominator
    stays >= ``eps``).
    """

    def command(self, u: ca.SX, P: ParameterAccess) -> ca.SX:
        t0 = P("torque_deadzone")
        return ca.vertcat(u[0], u[1] - t0 * ca.tanh(u[1] / (t0 + DEADZONE_EPS)))


@dataclass(frozen=True)
class LighthouseOffset(Effect):
    """Constant sweep-timing offset per light plane: every angle of plane k reads ``+ offset_k``.

    Acts on the sensors ``lighthouse/<station>/1`` and ``lighthouse/<station>/2`` of all stations.
    """

    def output(self, sensor: str, y: ca.SX, P: ParameterAccess) -> ca.SX:
        kind, _, plane = sensor.rpartition("/")
        if not kind.startswith("lighthouse/") or plane not in ("1", "2"):
            return y
        return y + P(f"lh_plane{plane}_offset")


EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        SteeringOffset(
            "steering_offset",
            "steering trim error: applied angle = command + delta0",
            (
                _parameter(
                    "steering_offset",
                    "steering_offset",
                    0.02,
                    "rad",
                    -0.2,
                    0.2,
                    "steering offset delta0",
                ),
            ),
        ),
        Effect(
            "input_delay",
            "transport delay of both inputs (radio link, firmware loop)",
            (_parameter("input_delay", "input_delay", 0.03, "s", 0.0, 0.2, "input delay d"),),
        ),
        FirstOrderLag(
            "steering_lag",
            "steering servo as a first-order lag",
            (
                _parameter(
                    "steering_lag",
                    "tau_steer",
                    0.05,
                    "s",
                    0.005,
                    0.5,
                    "steering servo time constant",
                ),
            ),
            states=(("steer_applied", "rad"),),
            channel=0,
            tau="tau_steer",
        ),
        FirstOrderLag(
            "motor_lag",
            "motor torque builds up as a first-order lag",
            (
                _parameter(
                    "motor_lag", "tau_motor", 0.05, "s", 0.005, 0.5, "motor torque time constant"
                ),
            ),
            states=(("torque_applied", "-"),),
            channel=1,
            tau="tau_motor",
        ),
        GyroBias(
            "gyro_bias",
            "constant yaw-rate bias of the IMU gyroscope",
            (_parameter("gyro_bias", "gyro_bias", 0.05, "rad/s", -0.5, 0.5, "gyro bias"),),
        ),
        WheelRadiusError(
            "wheel_radius_error",
            "the wheels' true radius differs from the nominal r",
            (
                _parameter(
                    "wheel_radius_error",
                    "wheel_radius_error",
                    0.001,
                    "m",
                    -0.005,
                    0.005,
                    "true minus nominal wheel radius",
                ),
            ),
        ),
        GyroScale(
            "gyro_scale",
            "scale-factor error of the IMU gyroscope: yaw rate reads (1 + s) omega",
            (
                _parameter(
                    "gyro_scale",
                    "gyro_scale_error",
                    0.05,
                    "-",
                    -0.3,
                    0.3,
                    "gyro scale-factor error s",
                ),
            ),
        ),
        SteeringGain(
            "steering_gain",
            "servo linkage calibration error: applied angle = (1 + k) command",
            (
                _parameter(
                    "steering_gain",
                    "steering_gain_error",
                    0.1,
                    "-",
                    -0.5,
                    0.5,
                    "steering gain error k",
                ),
            ),
        ),
        TorqueDeadzone(
            "torque_deadzone",
            "motor/ESC dead band: small torque commands do not reach the motor",
            (
                _parameter(
                    "torque_deadzone",
                    "torque_deadzone",
                    0.05,
                    "-",
                    0.0,
                    0.3,
                    "dead-band half-width T0 (normalised torque command)",
                ),
            ),
        ),
        LighthouseOffset(
            "lighthouse_offset",
            "constant sweep-timing offset of each light plane in the receiver's angle conversion",
            tuple(
                _parameter(
                    "lighthouse_offset",
                    f"lh_plane{plane}_offset",
                    0.003,
                    "rad",
                    -0.05,
                    0.05,
                    f"angle offset of light plane {plane} (all stations)",
                )
                for plane in (1, 2)
            ),
        ),
    )
}


def effect_of_parameter(name: str) -> str | None:
    """The registry effect parameter ``name`` belongs to (None: no effect's)."""
    for effect in EFFECTS.values():
        if any(p.name == name for p in effect.parameters):
            return effect.name
    return None


def parse_effect(text: str) -> tuple[str, str | None, float | None]:
    """``NAME``, ``NAME=VALUE`` or ``NAME.PARAM=VALUE`` -> (effect, parameter, value).

    ``NAME=VALUE`` sets the effect's first parameter. ``ValueError`` (naming the text) for an
    unknown effect or parameter or a value that is not a finite number.
    """
    name, _, value = text.strip().partition("=")
    effect, _, parameter = name.partition(".")
    if effect not in EFFECTS:
        raise ValueError(f"unknown effect {effect!r}; known: {', '.join(EFFECTS)}")
    names = [p.name for p in EFFECTS[effect].parameters]
    if parameter and parameter not in names:
        raise ValueError(f"effect {effect!r} has no parameter {parameter!r}; it has {names}")
    if not value:
        return effect, None, None
    number = parse_finite(value)
    if number is None:
        raise ValueError(f"effect {effect!r}: {value!r} is not a finite number")
    return effect, parameter or names[0], number


def effect_text(effect: tuple[str, str | None, float | None]) -> str:
    """A parsed effect (:func:`parse_effect`) as the text it reads from: ``NAME``,
    ``NAME.PARAM=VALUE`` (``repr`` of the value: it reads back exactly)."""
    name, parameter, value = effect
    if parameter is None or value is None:
        return name
    return f"{name}.{parameter}={value!r}"


def effect_spec(
    effects: Iterable[tuple[str, str | None, float | None]],
) -> dict[str, dict[str, float] | None]:
    """Parsed effects (:func:`parse_effect`) -> the ``effects`` mapping of ``CarModel``."""
    spec: dict[str, dict[str, float] | None] = {}
    for effect, parameter, value in effects:
        entry = spec.setdefault(effect, None)
        if parameter is not None and value is not None:
            spec[effect] = {**(entry or {}), parameter: value}
    return spec
