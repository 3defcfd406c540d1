r"""The simulated car's steering actuator and its potentiometer.

The steering of the Chronos car is a small DC gear motor driving the steering linkage, with a
rotary potentiometer on the shaft for position feedback (paper Sec. VI-B and the hardware
section). Reflected to the steering angle :math:`\theta` (rad), the motor with its gear is

.. math::

    J \ddot\theta = K\, u_{eff} - b\, \dot\theta, \qquad
    u_{eff} = \operatorname{sgn}(u) \max(|u| - u_0, 0),

with :math:`u \in [-1, 1]` the normalised motor voltage (PWM duty), :math:`u_0` the command the
linkage's static friction swallows, and mechanical end stops at :math:`\pm\theta_{max}` (an
inelastic stop: the angle is held and the rate zeroed). It is written with the two figures a
motor data sheet and a stopwatch give: the no-load speed :math:`\omega_0 = K / b` (steering
rad/s at full voltage) and the mechanical time constant :math:`\tau = J / b` (s), so
:math:`\ddot\theta = (\omega_0 u_{eff} - \dot\theta) / \tau`. Over a tick with a held command
it is integrated exactly.

The potentiometer reads :math:`V = V_\delta(\theta) + n`, :math:`n \sim \mathcal N(0,
\sigma_V^2)`, quantised by the ADC, with :math:`V_\delta` the inverse of the firmware's
calibration map (:class:`~crs_core.control.low_level.PotentiometerMap`); a miscalibrated car
is a potentiometer whose map differs from the controller's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from crs_core.control.low_level import PotentiometerMap
from crs_core.errors import FieldError, finite_number


def _positive(name: str, value: float, allow_zero: bool = False) -> float:
    number = finite_number(name, value)
    if not (number >= 0 if allow_zero else number > 0):
        raise FieldError(
            name, f"must be finite and {'>= 0' if allow_zero else '> 0'}, got {value!r}"
        )
    return number


@dataclass(frozen=True)
class SteeringActuatorSettings:
    """Physical parameters of the steering motor, gear and linkage (reflected to the angle).

    The defaults give a servo of a 1:28 car: 7 rad/s no-load (full voltage swings 0.3 rad in
    about 45 ms once up to speed), 25 ms mechanical time constant, 2 % of full voltage lost to
    static friction, end stops at +-0.35 rad. Under the default steering PID a 0.3 rad step
    rises (10-90 %) in 0.08 s, is at 90 % after 0.10 s and within 2 % after 0.16 s, with about
    1 % overshoot (``python -m sim.step_response``).

    Attributes
    ----------
    no_load_speed : float
        :math:`\\omega_0 = K / b`, steering angle rate at full voltage and no load, rad/s (> 0).
    time_constant : float
        :math:`\\tau = J / b`, mechanical time constant, s (> 0).
    deadband : float
        :math:`u_0`, normalised command lost to static friction (0 <= u_0 < 1).
    limit : float
        :math:`\\theta_{max}`, mechanical end stop, rad (> 0).
    """

    no_load_speed: float = 7.0
    time_constant: float = 0.025
    deadband: float = 0.02
    limit: float = 0.35

    def __post_init__(self) -> None:
        for f in fields(self):
            value = _positive(f.name, getattr(self, f.name), allow_zero=f.name == "deadband")
            object.__setattr__(self, f.name, value)
        if self.deadband >= 1:
            raise FieldError("deadband", f"must be < 1, got {self.deadband!r}")


class SteeringActuator:
    r"""State (angle, rate) of the steering motor, advanced exactly under a held command.

    With :math:`\omega_\infty = \omega_0 u_{eff}` held over :math:`\Delta t`:
    :math:`\dot\theta(\Delta t) = \omega_\infty + (\dot\theta_0 - \omega_\infty) e^{-\Delta t/\tau}`
    and :math:`\theta(\Delta t) = \theta_0 + \omega_\infty \Delta t +
    (\dot\theta_0 - \omega_\infty)\,\tau\,(1 - e^{-\Delta t/\tau})`, then the end stops.
    """

    def __init__(self, settings: SteeringActuatorSettings | None = None, angle: float = 0.0):
        self.settings = settings or SteeringActuatorSettings()
        limit = self.settings.limit
        self.angle = float(np.clip(angle, -limit, limit))
        self.rate = 0.0

    def advance(self, dt: float, command: float) -> float:
        """Advance ``dt`` s under motor command ``command`` (clipped to -1..1); the new angle."""
        if not (dt >= 0 and math.isfinite(dt)):
            raise FieldError("dt", f"must be finite and >= 0, got {dt!r}")
        if dt == 0:
            return self.angle
        s = self.settings
        u = float(np.clip(command, -1.0, 1.0))
        effective = math.copysign(max(abs(u) - s.deadband, 0.0), u)
        final = s.no_load_speed * effective
        decay = math.exp(-dt / s.time_constant)
        angle = self.angle + final * dt + (self.rate - final) * s.time_constant * (1 - decay)
        rate = final + (self.rate - final) * decay
        if abs(angle) >= s.limit:
            angle, rate = math.copysign(s.limit, angle), 0.0
        self.angle, self.rate = angle, rate
        return angle


@dataclass(frozen=True)
class PotentiometerSettings:
    """The steering potentiometer as the ADC sees it.

    Attributes
    ----------
    calibration : PotentiometerMap
        The true angle-voltage relation of the car's potentiometer (default: the firmware's
        default map, i.e. a perfectly calibrated car).
    noise_std : float
        Standard deviation of the voltage noise, V (>= 0); default 2 mV (about 1 mrad).
    adc_bits : int
        ADC resolution, bits (0: no quantisation); default 12.
    adc_reference : float
        ADC full-scale voltage, V (> 0); default 3.3.
    """

    calibration: PotentiometerMap = field(default_factory=PotentiometerMap)
    noise_std: float = 0.002
    adc_bits: int = 12
    adc_reference: float = 3.3

    def __post_init__(self) -> None:
        if not isinstance(self.calibration, PotentiometerMap):
            raise FieldError("calibration", f"must be a PotentiometerMap, got {self.calibration!r}")
        object.__setattr__(self, "noise_std", _positive("noise_std", self.noise_std, True))
        object.__setattr__(self, "adc_reference", _positive("adc_reference", self.adc_reference))
        if isinstance(self.adc_bits, bool) or not isinstance(self.adc_bits, int | np.integer):
            raise FieldError("adc_bits", f"must be an integer, got {self.adc_bits!r}")
        if not 0 <= self.adc_bits <= 24:
            raise FieldError("adc_bits", f"must be within 0..24, got {self.adc_bits!r}")

    def ideal(self) -> PotentiometerSettings:
        """The same potentiometer without noise or quantisation."""
        return PotentiometerSettings(self.calibration, 0.0, 0, self.adc_reference)

    def read(self, angle: float, rng: np.random.Generator | None = None) -> float:
        """Voltage for steering ``angle`` (rad): map, noise (needs ``rng``), ADC."""
        voltage = float(self.calibration.voltage(angle))
        if self.noise_std > 0:
            if rng is None:
                raise FieldError("rng", "a noisy potentiometer needs a random generator")
            voltage += self.noise_std * rng.standard_normal()
        if self.adc_bits:
            lsb = self.adc_reference / (2**self.adc_bits - 1)
            voltage = min(max(round(voltage / lsb), 0), 2**self.adc_bits - 1) * lsb
        return voltage
