r"""The Chronos car's onboard low-level controllers (paper, Sec. VI-B), ROS-free, numpy only.

The car takes either ``{delta, T}`` (steering angle, normalised torque) or ``{delta, v_x}``
(steering angle, longitudinal velocity) and runs its controllers at 250 Hz:

* **steering** (:class:`SteeringController`): the angle is estimated from the steering
  potentiometer's voltage through a calibration map :math:`\delta(V_\delta)`
  (:class:`PotentiometerMap`), and a PID drives the steering DC motor (a normalised PWM command
  in :math:`[-1, 1]`);
* **velocity** (:class:`VelocityController`): the longitudinal velocity is estimated from the
  rear wheel speeds, :math:`\hat v_x = r\,(\Omega_{rl} + \Omega_{rr}) / 2` (the wheel-encoder
  model :math:`\Omega = v / r`; the paper prints :math:`/(2 r)`, which is not a velocity), and a
  PID with a model feedforward computes the torque command :math:`T \in [-1, 1]`.

Every setting is a frozen, validated dataclass (the firmware keeps its gains in non-volatile
storage and lets the user change them); an invalid value raises
:class:`~crs_core.errors.FieldError` naming the field.
The default gains were tuned on the Chronos model with the steering actuator of
:mod:`sim.actuators` (step responses: ``tests/crs_core/control/test_low_level.py`` and
``tests/sim/test_onboard.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from crs_core.errors import FieldError, require_positive
from crs_core.settings import Settings, finite, non_negative, positive, within

#: Rate of every onboard controller, Hz (paper Sec. VI-B).
DEFAULT_RATE_HZ = 250.0


def _check(name: str, ok: bool, requirement: str, value: Any) -> None:
    if not ok:
        raise FieldError(name, f"must be {requirement}, got {value!r}")


@dataclass(frozen=True)
class PIDSettings(Settings, floats=True):
    r"""Gains and limits of a discrete PID (units follow the controlled quantity).

    Attributes
    ----------
    kp : float
        Proportional gain, output per unit error (>= 0).
    ki : float
        Integral gain, output per (unit error * s) (>= 0).
    kd : float
        Derivative gain, output per (unit error / s) (>= 0).
    output_min, output_max : float
        Limits of the output (``output_min < output_max``), e.g. ``-1, 1`` for a normalised PWM
        or torque command.
    derivative_time_constant : float
        Time constant (s, >= 0) of the first-order low-pass on the derivative; 0 is the plain
        backward difference.
    integral_limit : float or None
        Bound (output units, > 0) on the magnitude of the integral term; ``None``: the larger
        magnitude of the output limits.
    integration_band : float or None
        The integral only accumulates while :math:`|e_k| \le` ``integration_band`` (error units,
        > 0; a firmware-style threshold that keeps large transients from winding it up);
        ``None``: always.
    rate_hz : float
        Loop rate (Hz, > 0); the sample time is ``1 / rate_hz``.
    """

    kp: float = non_negative()
    ki: float = non_negative(0.0)
    kd: float = non_negative(0.0)
    output_min: float = finite(-1.0)
    output_max: float = finite(1.0)
    derivative_time_constant: float = non_negative(0.0)
    integral_limit: float | None = None
    integration_band: float | None = None
    rate_hz: float = positive(DEFAULT_RATE_HZ)

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("integral_limit", "integration_band"):  # checked: None or a number > 0
            if getattr(self, name) is not None:
                object.__setattr__(self, name, float(getattr(self, name)))

    def _check_relations(self) -> None:
        _check(
            "output_max",
            self.output_max > self.output_min,
            f"> output_min ({self.output_min})",
            self.output_max,
        )
        for name in ("integral_limit", "integration_band"):
            if getattr(self, name) is not None:
                require_positive(self, name)

    @property
    def dt(self) -> float:
        """Sample time, s."""
        return 1.0 / self.rate_hz


class PID:
    r"""Discrete PID with output limits, conditional integration and a filtered derivative.

    At tick :math:`k` with reference :math:`r_k`, measurement :math:`y_k`, feedforward
    :math:`u^{ff}_k` and sample time :math:`\Delta t`:

    .. math::

        e_k &= r_k - y_k, \\
        d_k &= \frac{\tau\, d_{k-1} - (y_k - y_{k-1})}{\tau + \Delta t}
              \quad (d_0 = 0), \\
        v_k &= u^{ff}_k + K_p e_k + I_{k-1} + K_i \Delta t\, e_k + K_d d_k, \\
        I_k &= \begin{cases}
              \operatorname{clip}(I_{k-1} + K_i \Delta t\, e_k, -I_{max}, I_{max}) &
              |e_k| \le e_{band} \text{ and }
              (u_{min} \le v_k \le u_{max}
              \text{ or } e_k \text{ drives } v_k \text{ back inside}), \\
              I_{k-1} & \text{otherwise (anti-windup)},
              \end{cases} \\
        u_k &= \operatorname{clip}(u^{ff}_k + K_p e_k + I_k + K_d d_k, u_{min}, u_{max}).

    The derivative acts on the measurement (no kick on reference steps) through a first-order
    low-pass of time constant :math:`\tau` (backward Euler). The integral is frozen while the
    output is saturated and the error pushes further into the limit (conditional integration)
    and is clamped to :math:`\pm I_{max}`; it also rests while the error is outside the
    integration band :math:`e_{band}` (if set).

    Parameters
    ----------
    settings : PIDSettings
        Gains, limits and rate.
    """

    def __init__(self, settings: PIDSettings) -> None:
        self.settings = settings
        limit = settings.integral_limit
        self._integral_limit = (
            limit if limit is not None else max(abs(settings.output_min), abs(settings.output_max))
        )
        self.reset()

    def reset(self) -> None:
        """Zero the integral and the derivative, forget the previous measurement."""
        self.integral = 0.0
        self.derivative = 0.0
        self.output = 0.0
        self._previous: float | None = None

    def step(self, reference: float, measurement: float, feedforward: float = 0.0) -> float:
        """One tick: the output :math:`u_k` (see the class docstring)."""
        s = self.settings
        error = reference - measurement
        if self._previous is not None:
            tau, dt = s.derivative_time_constant, s.dt
            self.derivative = (tau * self.derivative - (measurement - self._previous)) / (tau + dt)
        self._previous = measurement
        fixed = feedforward + s.kp * error + s.kd * self.derivative
        candidate = self.integral + s.ki * s.dt * error
        trial = fixed + candidate
        saturated_high = trial > s.output_max and error > 0
        saturated_low = trial < s.output_min and error < 0
        band = s.integration_band
        in_band = band is None or abs(error) <= band
        if in_band and not (saturated_high or saturated_low):
            self.integral = float(np.clip(candidate, -self._integral_limit, self._integral_limit))
        self.output = float(np.clip(fixed + self.integral, s.output_min, s.output_max))
        return self.output


@dataclass(frozen=True)
class PotentiometerMap:
    r"""Calibration of the steering potentiometer: voltage (V) to steering angle (rad).

    A piecewise-linear table through the points :math:`(V_i, \delta_i)`, extended linearly
    beyond its ends; strictly monotone in both columns, so it is invertible
    (:meth:`voltage` is the exact inverse of :meth:`angle`). A two-point table is a linear map.

    The defaults are a typical calibration of a 3.3 V rotary potentiometer on the steering
    shaft: 1.65 V straight ahead, about 2.1 V/rad, slightly steeper towards the end stops
    (the linkage), full lock at +-0.35 rad.

    Attributes
    ----------
    voltages : tuple of float
        Calibration voltages, V, strictly monotone (increasing or decreasing).
    angles : tuple of float
        Steering angles at those voltages, rad, strictly increasing.
    """

    voltages: tuple[float, ...] = (0.90, 1.28, 1.65, 2.02, 2.40)
    angles: tuple[float, ...] = (-0.35, -0.175, 0.0, 0.175, 0.35)

    def __post_init__(self) -> None:
        for name in ("voltages", "angles"):
            try:
                values = tuple(float(v) for v in getattr(self, name))
            except (TypeError, ValueError):
                raise FieldError(name, "must be a sequence of numbers") from None
            _check(name, len(values) >= 2, "at least 2 points", len(values))
            _check(name, all(math.isfinite(v) for v in values), "finite", values)
            object.__setattr__(self, name, values)
        _check(
            "angles",
            len(self.angles) == len(self.voltages),
            f"as many points as voltages ({len(self.voltages)})",
            len(self.angles),
        )
        _check("angles", bool(np.all(np.diff(self.angles) > 0)), "strictly increasing", self.angles)
        steps = np.diff(self.voltages)
        _check(
            "voltages",
            bool(np.all(steps > 0) or np.all(steps < 0)),
            "strictly monotone",
            self.voltages,
        )

    def angle(self, voltage: float | np.ndarray) -> float | np.ndarray:
        r"""Steering angle :math:`\delta(V_\delta)`, rad."""
        return _interp_extrapolate(voltage, self.voltages, self.angles)

    def voltage(self, angle: float | np.ndarray) -> float | np.ndarray:
        r"""Potentiometer voltage :math:`V_\delta(\delta)`, V (the inverse map)."""
        return _interp_extrapolate(angle, self.angles, self.voltages)


def _interp_extrapolate(x: Any, xp: tuple[float, ...], fp: tuple[float, ...]) -> Any:
    """Piecewise-linear interpolation through ``(xp, fp)`` (``xp`` monotone), linear beyond."""
    xs, fs = np.asarray(xp), np.asarray(fp)
    if xs[0] > xs[-1]:
        xs, fs = xs[::-1], fs[::-1]
    value = np.asarray(x, dtype=float)
    segment = np.clip(np.searchsorted(xs, value) - 1, 0, xs.size - 2)
    slope = (fs[segment + 1] - fs[segment]) / (xs[segment + 1] - xs[segment])
    result = fs[segment] + slope * (value - xs[segment])
    return float(result) if result.ndim == 0 else result


@dataclass(frozen=True)
class SteeringSettings(Settings, floats=True):
    """Settings of the steering angle loop.

    Attributes
    ----------
    pid : PIDSettings
        Angle (rad) to motor command (normalised PWM, -1..1). Default: ``kp = 5.0`` /rad,
        ``ki = 50.0`` /(rad s), ``kd = 0.1`` s/rad, derivative filter 4 ms, integral term
        within +-0.1 and accumulating only within 0.02 rad of the reference (it only has to
        overcome the linkage's static friction), 250 Hz.
    potentiometer : PotentiometerMap
        Voltage to angle calibration.
    angle_limit : float
        References are clipped to +-``angle_limit`` (rad, > 0), inside the mechanical stops.
    """

    pid: PIDSettings = field(
        default_factory=lambda: PIDSettings(
            kp=5.0,
            ki=50.0,
            kd=0.1,
            derivative_time_constant=0.004,
            integral_limit=0.1,
            integration_band=0.02,
        )
    )
    potentiometer: PotentiometerMap = field(default_factory=PotentiometerMap)
    angle_limit: float = positive(0.34)

    def _check_relations(self) -> None:
        _check("pid", isinstance(self.pid, PIDSettings), "a PIDSettings", self.pid)
        _check(
            "potentiometer",
            isinstance(self.potentiometer, PotentiometerMap),
            "a PotentiometerMap",
            self.potentiometer,
        )


class SteeringController:
    r"""Steering angle PID on the potentiometer's angle estimate.

    .. math::

        \hat\delta_k = \delta(V_{\delta,k}), \qquad
        u^{steer}_k = \mathrm{PID}\big(\operatorname{clip}(\delta^{ref}_k, \pm\delta_{lim}),
        \hat\delta_k\big) \in [-1, 1],

    where :math:`\delta(\cdot)` is the :class:`PotentiometerMap` and the PID is :class:`PID`.

    Parameters
    ----------
    settings : SteeringSettings, optional
        Gains, calibration and reference limit; defaults as documented there.
    """

    def __init__(self, settings: SteeringSettings | None = None) -> None:
        self.settings = settings or SteeringSettings()
        self.pid = PID(self.settings.pid)
        self.angle = 0.0

    def reset(self) -> None:
        """Reset the PID's memory."""
        self.pid.reset()

    def step(self, reference: float, voltage: float) -> float:
        """Motor command (-1..1) for angle ``reference`` (rad) and potentiometer ``voltage`` (V)."""
        limit = self.settings.angle_limit
        self.angle = float(self.settings.potentiometer.angle(voltage))
        return self.pid.step(float(np.clip(reference, -limit, limit)), self.angle)


@dataclass(frozen=True)
class MotorFeedforward(Settings, floats=True):
    r"""Steady-state torque command of the drive model for a velocity :math:`v`.

    From the longitudinal balance of the model (paper Sec. III-A) at constant speed,
    :math:`(C_{m1} - C_{m2} v)\,T = \operatorname{sgn}(v)(C_{d2} v^2 + C_{d0}) + C_{d1} v`:

    .. math::

        T^{ff}(v) = \frac{\operatorname{sgn}(v)(C_{d2} v^2 + C_{d0}) + C_{d1} v}
                         {C_{m1} - C_{m2} v}, \qquad \operatorname{sgn}(0) = 0.

    Defaults: the Chronos identified values (``crs_core.model.chronos``);
    :meth:`from_parameters` takes them from any identified parameter set.

    Attributes
    ----------
    cm1 : float
        Motor force per unit torque command, N (> 0).
    cm2 : float
        Back-EMF loss per unit torque command, N s/m (>= 0).
    cd0, cd1, cd2 : float
        Rolling resistance N, viscous drag N s/m, quadratic drag N s^2/m^2 (>= 0).
    scale : float
        Fraction of the model feedforward applied (0..1; 0 switches it off).
    """

    cm1: float = positive(0.9751147)
    cm2: float = non_negative(0.02578073)
    cd0: float = non_negative(0.02477582)
    cd1: float = non_negative(0.03031928)
    cd2: float = non_negative(0.08473512)
    scale: float = within(1.0, low=0, high=1)

    @classmethod
    def from_parameters(cls, parameters: Any, scale: float = 1.0) -> MotorFeedforward:
        """From a parameter set with ``value(name)`` (e.g. a ``ParameterSet``) of the model."""
        names = ("Cm1", "Cm2", "Cd0", "Cd1", "Cd2")
        values = {n.lower(): parameters.value(n) for n in names}
        return cls(**values, scale=scale)

    def torque(self, v: float) -> float:
        """:math:`\\mathrm{scale} \\cdot T^{ff}(v)` (unclipped)."""
        force = math.copysign(self.cd2 * v * v + self.cd0, v) if v != 0 else 0.0
        force += self.cd1 * v
        gain = max(self.cm1 - self.cm2 * v, 1e-3 * self.cm1)
        return self.scale * force / gain


@dataclass(frozen=True)
class VelocitySettings(Settings, floats=True):
    """Settings of the longitudinal velocity loop.

    Attributes
    ----------
    pid : PIDSettings
        Velocity (m/s) to torque command (-1..1). Default: ``kp = 2.5`` s/m,
        ``ki = 8.0`` 1/m, no derivative, integral term within +-0.5 and accumulating only
        within 0.1 m/s of the reference (the feedforward does the bulk), 250 Hz.
    wheel_radius : float
        Wheel radius r, m (> 0); Chronos: 0.0175.
    feedforward : MotorFeedforward or None
        Steady-state torque for the reference speed; ``None`` for none.
    """

    pid: PIDSettings = field(
        default_factory=lambda: PIDSettings(
            kp=2.5, ki=8.0, integral_limit=0.5, integration_band=0.1
        )
    )
    wheel_radius: float = positive(0.0175)
    feedforward: MotorFeedforward | None = field(default_factory=MotorFeedforward)

    def _check_relations(self) -> None:
        _check("pid", isinstance(self.pid, PIDSettings), "a PIDSettings", self.pid)
        _check(
            "feedforward",
            self.feedforward is None or isinstance(self.feedforward, MotorFeedforward),
            "a MotorFeedforward or None",
            self.feedforward,
        )


def rear_axle_speed(wheel_speeds: np.ndarray, wheel_radius: float) -> float:
    r""":math:`\hat v_x = r(\Omega_{rl} + \Omega_{rr}) / 2` from ``[fl, fr, rl, rr]`` (rad/s)."""
    w = np.asarray(wheel_speeds, dtype=float)
    if w.shape != (4,) or not np.all(np.isfinite(w)):
        raise FieldError("wheel_speeds", f"need 4 finite values [fl, fr, rl, rr], got {w!r}")
    return float(wheel_radius * 0.5 * (w[2] + w[3]))


class VelocityController:
    r"""Longitudinal velocity PID on the rear wheel speeds, with a model feedforward.

    .. math::

        \hat v_{x,k} = r\,\frac{\Omega_{rl,k} + \Omega_{rr,k}}{2}, \qquad
        T_k = \mathrm{PID}\big(v^{ref}_k, \hat v_{x,k};\ u^{ff} = T^{ff}(v^{ref}_k)\big)
        \in [-1, 1],

    with :math:`T^{ff}` the :class:`MotorFeedforward` and the PID :class:`PID` (the feedforward
    counts towards the output limits and the anti-windup).

    Parameters
    ----------
    settings : VelocitySettings, optional
        Gains, wheel radius and feedforward; defaults as documented there.
    """

    def __init__(self, settings: VelocitySettings | None = None) -> None:
        self.settings = settings or VelocitySettings()
        self.pid = PID(self.settings.pid)
        self.speed = 0.0

    def reset(self) -> None:
        """Reset the PID's memory."""
        self.pid.reset()

    def step(self, reference: float, wheel_speeds: np.ndarray) -> float:
        """Torque command (-1..1) for ``reference`` (m/s) and wheel speeds (rad/s)."""
        s = self.settings
        self.speed = rear_axle_speed(wheel_speeds, s.wheel_radius)
        feedforward = s.feedforward.torque(reference) if s.feedforward is not None else 0.0
        return self.pid.step(reference, self.speed, feedforward)
