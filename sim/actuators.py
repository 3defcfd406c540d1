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
from dataclasses import dataclass, field

import numpy as np

from crs_core.control.low_level import PotentiometerMap
from crs_core.errors import FieldError, require_within
from crs_core.settings import Settings, non_negative, positive, within


@dataclass(frozen=True)
class SteeringActuatorSettings(Settings, floats=True):
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

    no_load_speed: float = positive(7.0)
    time_constant: float = positive(0.025)
    deadband: float = within(0.02, low=0, high=1, high_open=True)
    limit: float = positive(0.35)


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
class PotentiometerSettings(Settings, floats=True):
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
    noise_std: float = non_negative(0.002)
    adc_bits: int = 12  # an integer: checked (and kept as given) in _check_relations
    adc_reference: float = positive(3.3)

    def _check_relations(self) -> None:
        if not isinstance(self.calibration, PotentiometerMap):
            raise FieldError("calibration", f"must be a PotentiometerMap, got {self.calibration!r}")
        if isinstance(self.adc_bits, bool) or not isinstance(self.adc_bits, int | np.integer):
            raise FieldError("adc_bits", f"must be an integer, got {self.adc_bits!r}")
        require_within(self, "adc_bits", 0, 24)

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
