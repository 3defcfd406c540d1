r"""Parameters an estimator carries as slowly varying states ("online parameters").

A chosen model parameter :math:`\theta` (``Cm1``, an effect's ``gyro_bias``, ...) or the grip
factor :math:`g` (``grip``: both axles' tyre peaks ``Df`` and ``Dr`` scaled together, which
racing data inform through the cornering stiffness where they do not tell ``D`` from ``B``)
becomes one more state of the estimation model, after the effect states, with the dynamics

.. math::

    \dot\theta = -(\theta - \theta_0) / T, \qquad
    \text{process noise } \sigma = \sigma_0 \sqrt{2 / T},

an Ornstein-Uhlenbeck process around the prior :math:`\theta_0` (the parameter's value in the
model's parameter vector; 1 for the grip factor) whose stationary standard deviation is the
prior's :math:`\sigma_0`. Data that inform the parameter move it as fast as the random walk
lets them; a parameter the data do not inform relaxes to its prior with its prior's
uncertainty within a few ``T`` instead of drifting along a flat direction. Everywhere else in
the model (dynamics and sensors) the state takes the parameter's place.

An effect's parameter (a sensor's bias, an offset) is an imperfection that moves slower than
the car's physics (the battery's sag, the tyres' grip): its ``T`` is
:data:`EFFECT_REVERSION_FACTOR` times the model parameters'. Its random walk is then half as
fast, and its estimate's standard deviation, which goes as :math:`T^{-1/4}` in steady state,
about 0.7 times as wide (docs/online.md has the measured figures).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import casadi as ca

from crs_core.errors import FieldError
from crs_core.model.effects import EFFECTS, effect_of_parameter
from crs_core.parameters import ParameterSet

#: The grip factor's name and the tyre peaks it scales.
GRIP = "grip"
GRIP_SCALES = ("Df", "Dr")
#: The grip factor's prior standard deviation (-) and soft bounds.
GRIP_PRIOR_STD = 0.1
GRIP_BOUNDS = (0.3, 1.5)
#: Default relaxation time T of an online parameter to its prior, s.
DEFAULT_REVERSION_S = 120.0
#: An effect's parameter relaxes this many times slower than the model's parameters.
EFFECT_REVERSION_FACTOR = 4.0
#: Prefix of an online parameter's state name (``online_Cm1``).
STATE_PREFIX = "online_"


@dataclass(frozen=True)
class OnlineParameter:
    """One online parameter: its prior, prior standard deviation, unit, soft bounds and
    relaxation time ``reversion_s`` (s)."""

    name: str
    prior: float
    prior_std: float
    unit: str
    lower: float
    upper: float
    reversion_s: float

    @property
    def state_name(self) -> str:
        return STATE_PREFIX + self.name


def _prior_std(name: str, identification_std: float) -> float:
    """An online parameter's prior standard deviation: its identification prior's, except for
    an effect's parameter, whose prior is the effect's nominal size (its value when the effect
    is named without one: 0.05 rad/s for the gyro bias) where that is smaller. The
    identification prior of an effect's parameter spans a quarter of its whole range (0.25
    rad/s for the gyro bias): as a random walk that wide (0.032 rad/s per sqrt(s) at
    T = 120 s) the estimate followed the measurement noise."""
    owner = effect_of_parameter(name)
    if owner is None:
        return identification_std
    nominal = next(abs(p.value) for p in EFFECTS[owner].parameters if p.name == name)
    return min(identification_std, nominal) if nominal > 0 else identification_std


def parse_online_names(text: str) -> tuple[str, ...]:
    """``"Cm1,gyro_bias,grip"`` -> the names, in order, each once (empty items refused)."""
    names = [item.strip() for item in text.split(",")]
    if not text.strip() or any(not name for name in names):
        raise FieldError("online_parameters", f"a comma-separated list of names, got {text!r}")
    duplicates = sorted({name for name in names if names.count(name) > 1})
    if duplicates:
        raise FieldError("online_parameters", f"{', '.join(duplicates)} named twice")
    return tuple(names)


class OnlineParameters:
    """The online parameters of a model, in state order, and how they enter its expressions.

    Parameters
    ----------
    names : sequence of str
        Parameter names of ``parameters`` or ``"grip"``.
    parameters : ParameterSet
        The model's parameters (the priors, units, prior standard deviations and bounds).
    reversion_s : float
        :math:`T` of the model's parameters and the grip factor, s (an effect's parameter:
        :data:`EFFECT_REVERSION_FACTOR` times it).
    """

    def __init__(self, names: Sequence[str], parameters: ParameterSet, reversion_s: float) -> None:
        if not reversion_s > 0 or not math.isfinite(reversion_s):
            raise FieldError(
                "online_reversion_s", f"must be a finite number > 0, got {reversion_s}"
            )
        self.reversion_s = float(reversion_s)
        entries = []
        for name in names:
            if name == GRIP:
                missing = [n for n in GRIP_SCALES if n not in parameters.names]
                if missing:
                    raise FieldError(
                        "online_parameters",
                        f"'grip' scales the tyre peaks {', '.join(GRIP_SCALES)}, which the "
                        "model does not have",
                    )
                entries.append(
                    OnlineParameter(GRIP, 1.0, GRIP_PRIOR_STD, "-", *GRIP_BOUNDS, self.reversion_s)
                )
                continue
            if name not in parameters.names:
                owner = effect_of_parameter(name)
                hint = (
                    f"a parameter of the effect {owner}, which the model does not have"
                    if owner
                    else f"known: {', '.join((*parameters.names, GRIP))}"
                )
                raise FieldError("online_parameters", f"no parameter {name!r} ({hint})")
            p = parameters[name]
            slower = EFFECT_REVERSION_FACTOR if effect_of_parameter(name) else 1.0
            entries.append(
                OnlineParameter(
                    name,
                    p.value,
                    _prior_std(name, p.prior_std),
                    p.unit,
                    *_bounds(name, parameters),
                    self.reversion_s * slower,
                )
            )
        clash = [e.name for e in entries if e.name in GRIP_SCALES]
        if clash and GRIP in names:
            raise FieldError(
                "online_parameters",
                f"{', '.join(clash)} and grip together: grip scales {' and '.join(GRIP_SCALES)}",
            )
        self.entries: tuple[OnlineParameter, ...] = tuple(entries)
        self.names = tuple(e.name for e in entries)
        self.state_names = tuple(e.state_name for e in entries)

    def __len__(self) -> int:
        return len(self.entries)

    @property
    def process_std(self) -> dict[str, float]:
        """Random-walk standard deviation per sqrt(s) of each state, by state name."""
        return {e.state_name: e.prior_std * math.sqrt(2.0 / e.reversion_s) for e in self.entries}

    @property
    def prior_std(self) -> dict[str, float]:
        """Initial (and stationary) standard deviation of each state, by state name."""
        return {e.state_name: e.prior_std for e in self.entries}

    @property
    def priors(self) -> dict[str, tuple[float, float]]:
        """Each parameter's prior value and standard deviation, by parameter name."""
        return {e.name: (e.prior, e.prior_std) for e in self.entries}

    @property
    def bounds(self) -> dict[str, tuple[float, float]]:
        """Soft bounds of each state, by state name."""
        return {e.state_name: (e.lower, e.upper) for e in self.entries}

    def access(self, states: ca.SX, P: Callable[[str], ca.SX]) -> Callable[[str], ca.SX]:
        """The parameter access of the model with these online ``states`` (one per entry) in
        place of the parameters: ``P`` for every other name."""
        index = {name: k for k, name in enumerate(self.names)}
        grip = index.get(GRIP)

        def online_access(name: str) -> ca.SX:
            if name in index:
                return states[index[name]]
            if grip is not None and name in GRIP_SCALES:
                return P(name) * states[grip]
            return P(name)

        return online_access

    def derivative(self, states: ca.SX, P: Callable[[str], ca.SX]) -> ca.SX:
        """:math:`-(\\theta - \\theta_0) / T` per state, the priors read through ``P``."""
        return ca.vertcat(
            *[
                -(states[k] - (1.0 if e.name == GRIP else P(e.name))) / e.reversion_s
                for k, e in enumerate(self.entries)
            ]
        )

    def initial_values(self) -> list[float]:
        """The states at their priors."""
        return [e.prior for e in self.entries]


def _bounds(name: str, parameters: ParameterSet) -> tuple[float, float]:
    """The soft bounds of online parameter ``name``: the grip factor's, else the parameter's."""
    if name == GRIP:
        return GRIP_BOUNDS
    return parameters[name].lower, parameters[name].upper


def model_values(parameters: ParameterSet, online: Mapping[str, float]) -> dict[str, float]:
    """The values of ``parameters`` the online estimates ``online`` (by name) stand for: a
    parameter's own value, and for ``grip`` both tyre peaks scaled from their values in
    ``parameters``; names ``parameters`` lacks (an effect a controller's model does not have)
    are left out."""
    values: dict[str, float] = {}
    for name, value in online.items():
        if name == GRIP:
            for peak in GRIP_SCALES:
                values[peak] = parameters.value(peak) * float(value)
        elif name in parameters.names:
            values[name] = float(value)
    return values


def at_bound(name: str, value: float, parameters: ParameterSet, share: float = 0.02) -> bool:
    """Whether online parameter ``name`` at ``value`` lies within ``share`` of its range of
    its soft bound (:attr:`OnlineParameters.bounds`; a name ``parameters`` lacks: never)."""
    if name != GRIP and name not in parameters.names:
        return False
    lower, upper = _bounds(name, parameters)
    margin = share * (upper - lower)
    return bool(value <= lower + margin or value >= upper - margin)
