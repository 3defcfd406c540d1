"""The car model every tool takes: a plant, its sensors and effects in one CasADi definition.

:class:`CarModel` composes a :class:`~crs_core.model.plant.Plant` (the dynamic bicycle by
default, the kinematic one, or a researcher's own) with the Lighthouse geometry, the effects,
the proposed terms and the online parameters, builds the symbolic model once and derives
everything from it: the continuous dynamics, an RK4 step, every sensor output, the car state,
and (lazily) their compiled numeric versions. The simulator, estimators, controllers and
identification all use this one object.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import casadi as ca
import numpy as np

from crs_core.codegen import SX_OPTIONS, NumericFunction, compile_functions
from crs_core.errors import FieldError
from crs_core.integrators import rk4
from crs_core.model import sensors
from crs_core.model.bicycle import DynamicBicycle
from crs_core.model.chronos import (
    base_station_parameters,
    default_base_stations,
    photodiode_parameters,
)
from crs_core.model.effects import EFFECTS, Effect, effect_of_parameter
from crs_core.model.lighthouse import BaseStation
from crs_core.model.online import DEFAULT_REVERSION_S, OnlineParameters
from crs_core.model.plant import (
    CAR_STATE_NAMES,
    ENCODER_PARAMETERS,
    INPUT_NAMES,
    Plant,
    derived_imu,
)
from crs_core.model.plants import load_plant, plant_spec, resolve_model
from crs_core.model.terms import CLOCK_STATE, OUTPUT_TARGETS, STATE_TARGETS, Term, terms_in_file
from crs_core.parameters import ParameterSet
from crs_core.yaml_io import mapping_in_file

#: Largest RK4 substep (s). Measured with :func:`crs_core.model.stability.largest_stable_step`
#: over speeds 0..3 m/s and full steering: the fastest Jacobian eigenvalue is about -380 1/s
#: near v_x = eps, so RK4 is stable up to 6.8 ms; 4 ms keeps a 1.7x margin (and is exactly one
#: substep per 250 Hz sensor sample). One 1/30 s step is stable only above about 0.8 m/s.
MAX_SUBSTEP = 0.004

#: Rows per call of the batched car-state function of a model whose car state is not its state.
CAR_STATES_BATCH = 256
#: States of the input-free model (``estimated_inputs=True``): name, unit.
ESTIMATED_INPUT_STATES = (("steer_estimated", "rad"), ("torque_estimated", "-"))
#: Effects that act on the command or the actuators (undefined without commands).
COMMAND_EFFECTS = (
    "steering_offset",
    "input_delay",
    "steering_lag",
    "motor_lag",
    "steering_gain",
    "torque_deadzone",
)


def effect_names_and_values(
    effects: Iterable[str] | Mapping[str, float | Mapping[str, float] | None],
) -> tuple[tuple[str, ...], dict[str, float]]:
    """Normalise an effect specification to (names, parameter values).

    Accepts ``["steering_lag", ...]`` or ``{"steering_lag": 0.08}`` (the value of its single
    parameter) or ``{"steering_lag": {"tau_steer": 0.08}}`` or ``{"gyro_bias": None}``.
    """
    if isinstance(effects, Mapping):
        items = list(effects.items())
    else:
        items = [(name, None) for name in effects]
    names, values = [], {}
    for name, spec in items:
        if name not in EFFECTS:
            raise KeyError(f"unknown effect {name!r}; known: {', '.join(EFFECTS)}")
        if name in names:
            raise ValueError(f"effect {name!r} given twice")
        names.append(name)
        params = EFFECTS[name].parameters
        if spec is None:
            continue
        if isinstance(spec, Mapping):
            values.update({str(k): float(v) for k, v in spec.items()})
        elif len(params) == 1:
            values[params[0].name] = float(spec)
        else:
            raise ValueError(f"effect {name!r} has several parameters; give a mapping")
    # keep the registry order so the signal chain is the same however effects are listed
    order = tuple(n for n in EFFECTS if n in names)
    return order, values


@dataclass(frozen=True)
class SensorOutput:
    """A sensor channel group of the model: name and channel labels."""

    name: str
    channels: tuple[str, ...]


def effects_in_file(path: str | Path) -> list[str]:
    """The effects whose parameters a parameter YAML names (so that its model can be rebuilt);
    none for a file that cannot be read (the parameter loader says what is wrong with it)."""
    entries = mapping_in_file(path).get("parameters")
    names = set(entries) if isinstance(entries, dict) else set()
    return [e.name for e in EFFECTS.values() if any(p.name in names for p in e.parameters)]


class CarModel:
    """A car's plant with sensors and optional effects.

    Parameters
    ----------
    effects : iterable of str or mapping
        Effects to compose onto the base model (see :func:`effect_names_and_values`).
    n_base_stations : int
        Number of Lighthouse base stations with sensor outputs.
    base_stations : sequence of BaseStation, optional
        Their geometry (any valid rotation, e.g. ``BaseStation.from_rotation(R, p, dt1, dt2)``);
        sets ``n_base_stations``. Default: the recorded station and turned copies of it.
    parameters : ParameterSet, optional
        Values for all model parameters; by default the Chronos identified values, the recorded
        Lighthouse geometry and each effect's default. Effect values given in ``effects`` are
        applied on top.
    estimated_inputs : bool
        The input-free variant for recordings without commands: the applied steering angle
        (rad) and torque (-) are two more states, ``steer_estimated`` and
        ``torque_estimated``, with zero derivative (an estimator models them as random walks),
        and the command ``u`` is ignored. Effects on the command or the actuators
        (``steering_offset``, ``input_delay``, ``steering_lag``, ``motor_lag``) cannot be
        combined with it: without commands they are not defined.
    online_parameters : sequence of str
        Parameters (or ``"grip"``) carried as slowly varying states after all others,
        ``online_<name>``, for an estimator to estimate online (:mod:`crs_core.model.online`).
    online_reversion_s : float
        Their relaxation time to the prior, s.
    terms : sequence of Term
        Additive terms proposed from data (:mod:`crs_core.model.terms`), after every effect;
        their coefficients are parameters (``<name>_c1``, ...).
    model : str or Plant, optional
        The plant (:func:`~crs_core.model.plants.load_plant`: ``dynamic``, the default,
        ``kinematic``, ``FILE.py:CLASS``, or a :class:`~crs_core.model.plant.Plant`).

    Attributes
    ----------
    plant : Plant
        The plant.
    state_names : tuple of str
        The plant's states (the dynamic bicycle's ``x, y, yaw, vx, vy, omega``) followed by
        effect states.
    input_names : tuple of str
        ``steer, torque`` (commanded).
    outputs : dict of str to SensorOutput
        ``imu``, ``gyro``, ``wheel_encoders``, ``pose`` and ``lighthouse/<station>/<plane>``.
    """

    input_names = INPUT_NAMES

    def __init__(
        self,
        effects: Iterable[str] | Mapping[str, float | Mapping[str, float] | None] = (),
        n_base_stations: int = 1,
        parameters: ParameterSet | None = None,
        estimated_inputs: bool = False,
        base_stations: Sequence[BaseStation] | None = None,
        online_parameters: Sequence[str] = (),
        online_reversion_s: float = DEFAULT_REVERSION_S,
        terms: Sequence[Term] = (),
        model: str | Plant | None = None,
    ) -> None:
        self.plant = load_plant(model, "model")
        if self.plant.inputs != INPUT_NAMES:
            raise FieldError(
                "model",
                f"{self.plant.name} takes {self.plant.inputs}; the stack commands "
                f"{', '.join(INPUT_NAMES)}",
            )
        if base_stations is not None:
            n_base_stations = len(base_stations)
        if n_base_stations < 0:
            raise ValueError("n_base_stations must be >= 0")
        names, effect_values = effect_names_and_values(effects)
        self.effects: tuple[Effect, ...] = tuple(EFFECTS[n] for n in names)
        self.estimated_inputs = bool(estimated_inputs)
        if self.estimated_inputs:
            clash = [n for n in names if n in COMMAND_EFFECTS]
            if clash:
                raise FieldError(
                    "estimated_inputs",
                    f"cannot be combined with {', '.join(clash)} (effects on "
                    "the command need commands)",
                )
        self.n_base_stations = n_base_stations
        defaults = (
            self.plant.parameters()
            .merged(photodiode_parameters())
            .merged(
                base_station_parameters(
                    tuple(base_stations)
                    if base_stations is not None
                    else default_base_stations(n_base_stations)
                )
            )
        )
        for effect in self.effects:
            defaults = defaults.merged(ParameterSet(list(effect.parameters)))
        self.terms: tuple[Term, ...] = tuple(terms)
        for term in self.terms:
            if term.target in STATE_TARGETS and term.target not in self.plant.state_names:
                raise FieldError(
                    f"terms.{term.name}.target",
                    f"model {self.plant.name} has no state {term.target}",
                )
            defaults = defaults.merged(ParameterSet(list(term.parameters())))
        if parameters is not None:
            missing = set(defaults.names) - set(parameters.names)
            if missing:
                raise KeyError(f"parameters lack {sorted(missing)}")
            defaults = defaults.updated({n: parameters.value(n) for n in defaults.names})
        self.parameters = defaults.updated(effect_values)
        self.online = OnlineParameters(online_parameters, self.parameters, online_reversion_s)
        extra_states = tuple(st for e in self.effects for st in e.states)
        if self.estimated_inputs:
            extra_states += ESTIMATED_INPUT_STATES
        self.has_clock = any(term.uses_time for term in self.terms)
        if self.has_clock:
            extra_states += (CLOCK_STATE,)
        extra_states += tuple((e.state_name, e.unit) for e in self.online.entries)
        self.state_names = self.plant.state_names + tuple(name for name, _ in extra_states)
        self.state_units = self.plant.state_units + tuple(unit for _, unit in extra_states)
        self.nx, self.nu, self.np = len(self.state_names), 2, len(self.parameters)
        self._build_symbolic()

    def __reduce__(self):
        """Pickle by the constructor arguments (the CasADi graph is rebuilt, not serialised;
        the plant by its spec): a model crosses into worker processes."""
        names = [e.name for e in self.effects]
        arguments = (names, self.n_base_stations, self.parameters, self.estimated_inputs)
        online = (self.online.names, self.online.reversion_s)
        return (CarModel, (*arguments, None, *online, self.terms, plant_spec(self.plant)))

    def _rebuilt(
        self,
        effects: Iterable[str] | Mapping[str, float | Mapping[str, float] | None] | None = None,
        parameters: ParameterSet | None = None,
        online: tuple[Sequence[str], float] | None = None,
        terms: Sequence[Term] | None = None,
    ) -> CarModel:
        """A model of this one's plant, stations and input mode, with what is given changed."""
        online_names, reversion = online or (self.online.names, self.online.reversion_s)
        return CarModel(
            [e.name for e in self.effects] if effects is None else effects,
            self.n_base_stations,
            parameters,
            self.estimated_inputs,
            None,
            online_names,
            reversion,
            self.terms if terms is None else terms,
            self.plant,
        )

    def with_parameters(self, parameters: ParameterSet) -> CarModel:
        """This model's structure (plant, effects, terms, stations, input mode, online
        parameters) with ``parameters``' values."""
        return self._rebuilt(parameters=parameters)

    # --- symbolic model ------------------------------------------------------------------
    def _build_symbolic(self) -> None:
        x = ca.SX.sym("x", self.nx)
        u = ca.SX.sym("u", self.nu)
        p = ca.SX.sym("p", self.np)
        index = {name: i for i, name in enumerate(self.parameters.names)}

        def parameter(name: str) -> ca.SX:
            return p[index[name]]

        # the online parameters' states stand in for the parameters in every expression
        P = self.online.access(x[self.nx - len(self.online) :], parameter)
        self.x_sym, self.u_sym, self.p_sym = x, u, p
        xdot, applied = self._rhs(x, u, P)
        if len(self.online):
            online_states = x[self.nx - len(self.online) :]
            xdot = ca.vertcat(xdot, self.online.derivative(online_states, parameter))
        plant_state = x[: len(self.plant.states)]
        car = self.plant.car_state(plant_state, applied, P)
        if car.numel() != len(CAR_STATE_NAMES):
            raise FieldError(
                "model", f"{self.plant.name}.car_state() must give {len(CAR_STATE_NAMES)} values"
            )
        given = self.plant.sensors(plant_state, applied, P)
        outputs = {"imu": given["imu"] if "imu" in given else derived_imu(car, x, xdot)}
        if "wheel_encoders" in given:
            outputs["wheel_encoders"] = given["wheel_encoders"]
        elif all(n in index for n in ENCODER_PARAMETERS):
            outputs["wheel_encoders"] = sensors.wheel_speeds(car, applied[0], P)
        outputs["pose"] = sensors.pose(car)
        for station in range(self.n_base_stations):
            first, second = sensors.lighthouse(car, station, P)
            outputs[f"lighthouse/{station}/1"] = first
            outputs[f"lighthouse/{station}/2"] = second
        for effect in self.effects:
            outputs = {name: effect.output(name, y, P) for name, y in outputs.items()}
        for term in self.terms:
            if term.target in STATE_TARGETS:
                continue
            sensor, signs, _ = OUTPUT_TARGETS[term.target]
            if sensor not in outputs:
                raise FieldError(
                    f"terms.{term.name}.target", f"model {self.plant.name} has no {sensor}"
                )
            added = term.value(car, applied, P, self._clock(x))
            outputs[sensor] = outputs[sensor] + ca.DM(signs) * added
        outputs["gyro"] = outputs["imu"][2]  # the yaw-rate channel alone, as recorded
        self.output_expressions: dict[str, ca.SX] = outputs
        self.outputs = {name: SensorOutput(name, _channels(name)) for name in outputs}
        self.xdot_expression = xdot
        self.applied_input_expression = applied
        self.car_state_expression = car
        #: The car state is the state's first six entries (the dynamic bicycle, and any plant
        #: whose car_state() gives its states as they are): its numeric form a slice.
        self.car_state_is_state = self.nx >= len(CAR_STATE_NAMES) and all(
            ca.is_equal(car[i], x[i]) for i in range(len(CAR_STATE_NAMES))
        )

    def _rhs(self, x: ca.SX, u: ca.SX, P) -> tuple[ca.SX, ca.SX]:
        """State derivative (without the online parameters') and applied input for augmented
        state ``x`` and command ``u``."""
        for effect in self.effects:
            u = effect.command(u, P)
        derivatives = []
        offset = len(self.plant.states)
        for effect in self.effects:
            z = x[offset : offset + len(effect.states)]
            u, zdot = effect.actuator(z, u, P)
            derivatives.append(zdot)
            offset += len(effect.states)
        if self.estimated_inputs:
            u = x[offset : offset + 2]
            derivatives.append(ca.SX.zeros(2))
        if self.has_clock:
            derivatives.append(ca.SX(1))
        plant_state = x[: len(self.plant.states)]
        base = self.plant.derivative(plant_state, u, P)
        if base.numel() != len(self.plant.states):
            raise FieldError(
                "model",
                f"{self.plant.name}.derivative() gives {base.numel()} values for "
                f"{len(self.plant.states)} states",
            )
        if any(term.target in STATE_TARGETS for term in self.terms):
            car = self.plant.car_state(plant_state, u, P)
            for term in self.terms:
                if term.target in STATE_TARGETS:
                    index = self.plant.state_names.index(term.target)
                    base[index] = base[index] + term.value(car, u, P, self._clock(x))
        return ca.vertcat(base, *derivatives), u

    def _clock(self, x: ca.SX) -> ca.SX | None:
        """The clock state of ``x`` (None without one)."""
        if not self.has_clock:
            return None
        return x[self.state_names.index(CLOCK_STATE[0])]

    def function_of_xup(self, name: str, expression: ca.SX, output: str) -> ca.Function:
        """``name(x, u, p) -> output``: ``expression`` as a function of the model's state,
        input and parameters (named arguments, common subexpressions eliminated)."""
        return ca.Function(
            name,
            [self.x_sym, self.u_sym, self.p_sym],
            [expression],
            ["x", "u", "p"],
            [output],
            SX_OPTIONS,
        )

    @classmethod
    def from_file(
        cls,
        path: str | Path | None,
        effects: Iterable[str] | Mapping[str, float | Mapping[str, float] | None] = (),
        n_base_stations: int = 1,
        model: str | Plant | None = None,
    ) -> CarModel:
        """The model with ``effects`` and the parameter YAML ``path`` applied (None: the Chronos
        defaults; :meth:`~crs_core.parameters.ParameterSet.updated_from_yaml`, whose errors name
        the file). The plant is ``model`` or the one the file names under ``model:``
        (:func:`~crs_core.model.plants.model_in_file`; the two must agree). The effects whose
        parameters the file names are switched on too (:func:`effects_in_file`: a
        ``params.yaml`` of ``crs discrepancy`` carries its effect), and the terms it lists under
        ``terms:`` (:func:`~crs_core.model.terms.terms_in_file`); an effect's own value
        (``steering_lag=0.05``) wins over the file."""
        if path is None:
            return cls(effects, n_base_stations, model=model)
        plant = load_plant(resolve_model(model, path), "model")
        given = dict(effects) if isinstance(effects, Mapping) else dict.fromkeys(effects)
        spec = {**dict.fromkeys(effects_in_file(path)), **given}
        terms = terms_in_file(path)
        built = cls(spec, n_base_stations, terms=terms, model=plant)
        parameters = built.parameters.updated_from_yaml(path)
        return cls(spec, n_base_stations, parameters, terms=terms, model=plant)

    def with_effects_at_zero(self, effects: Iterable[str]) -> CarModel:
        """This model with the registry ``effects`` it lacks switched on, their parameters at 0
        (where every effect is the base model); its own values, input mode and online
        parameters kept. Itself when it has them all."""
        spec: dict[str, Mapping[str, float] | None] = {e.name: None for e in self.effects}
        for name in effects:
            if name not in spec:
                spec[name] = dict.fromkeys((p.name for p in EFFECTS[name].parameters), 0.0)
        if len(spec) == len(self.effects):
            return self
        widened = self._rebuilt(effects=spec, online=((), self.online.reversion_s)).parameters
        parameters = widened.updated({n: self.parameters.value(n) for n in self.parameters.names})
        return self._rebuilt(effects=spec, parameters=parameters)

    def with_online(self, names: Sequence[str], reversion_s: float) -> CarModel:
        """This model with online parameters ``names`` (:mod:`crs_core.model.online`); an
        effect one of them belongs to is switched on, its parameters at 0 (the base model),
        when this model lacks it."""
        owners = [effect_of_parameter(n) for n in names if n not in self.parameters.names]
        base = self.with_effects_at_zero(owner for owner in owners if owner is not None)
        return base._rebuilt(parameters=base.parameters, online=(names, reversion_s))

    @cached_property
    def car_state_function(self) -> ca.Function:
        """``car_state(x, u, p) -> car``: :data:`CAR_STATE_NAMES` of state ``x`` under command
        ``u``."""
        return self.function_of_xup("car_state", self.car_state_expression, "car")

    @cached_property
    def car_state_jacobian_function(self) -> ca.Function:
        """``car_state_jacobian(x, u, p) -> J``: the car state's Jacobian in the state, 6 x nx."""
        jacobian = ca.jacobian(self.car_state_expression, self.x_sym)
        return self.function_of_xup("car_state_jacobian", ca.densify(jacobian), "J")

    @cached_property
    def car_state_batch_function(self) -> ca.Function:
        """:attr:`car_state_function` over :data:`CAR_STATES_BATCH` columns of ``x`` and ``u``
        with one ``p``."""
        return self.car_state_function.map("car_state_batch", "serial", CAR_STATES_BATCH, [2], [])

    @cached_property
    def dynamics_function(self) -> ca.Function:
        """``f(x, u, p) -> xdot``."""
        return self.function_of_xup("f", self.xdot_expression, "xdot")

    def step_function(self, substeps: int = 1, name: str = "rk4") -> ca.Function:
        """``F(x, u, p, dt) -> x_next`` with ``substeps`` RK4 substeps of ``dt / substeps``."""
        dt = ca.SX.sym("dt")
        f = self.dynamics_function

        def rhs(xx: ca.SX, uu: ca.SX) -> ca.SX:
            return f(xx, uu, self.p_sym)

        x_next = rk4(rhs, self.x_sym, self.u_sym, dt, substeps)
        return ca.Function(
            name,
            [self.x_sym, self.u_sym, self.p_sym, dt],
            [x_next],
            ["x", "u", "p", "dt"],
            ["x_next"],
            SX_OPTIONS,
        )

    def output_function(self, sensor: str) -> ca.Function:
        """``h(x, u, p) -> y`` for one sensor."""
        if sensor not in self.output_expressions:
            raise KeyError(f"unknown sensor {sensor!r}; known: {', '.join(self.outputs)}")
        return self.function_of_xup(_c_name("h_" + sensor), self.output_expressions[sensor], "y")

    # --- numbers --------------------------------------------------------------------------
    def input_delay(self, parameters: ParameterSet | None = None) -> float:
        """Transport delay of both inputs (s): the ``input_delay`` effect's value, else 0."""
        if not any(e.name == "input_delay" for e in self.effects):
            return 0.0
        return (parameters or self.parameters).value("input_delay")

    def initial_state(self, car_state: Iterable[float], u: Iterable[float] = (0, 0)):
        """Augmented state from the 6 values of the car state (:data:`CAR_STATE_NAMES`; the
        plant's state nearest to it), effect states at rest under command ``u``."""
        car = [float(v) for v in car_state]
        if len(car) != len(CAR_STATE_NAMES):
            raise ValueError(f"expected {len(CAR_STATE_NAMES)} car states, got {len(car)}")
        command = [float(v) for v in u]
        plant = self.plant.state_from_car(car, command, self.parameters.value)
        return self.augmented_state(plant, command)

    def augmented_state(self, plant_state: Iterable[float], u: Iterable[float] = (0, 0)):
        """Augmented state from the plant's states, effect states at rest under command ``u``."""
        base = [float(v) for v in plant_state]
        if len(base) != len(self.plant.states):
            raise ValueError(f"expected {len(self.plant.states)} plant states, got {len(base)}")
        command = [float(v) for v in u]
        extra = [value for e in self.effects for value in e.initial_states(command)]
        if self.estimated_inputs:
            extra += command
        if self.has_clock:
            extra.append(0.0)
        extra += self.online.initial_values()
        return np.array(base + extra)

    @property
    def tag(self) -> str:
        """Short identifier of the model structure (effects, input mode) for generated code."""
        parts = [e.name for e in self.effects] + (["estinputs"] if self.estimated_inputs else [])
        if len(self.online):
            parts.append("online_" + "_".join(self.online.names))
        if self.terms:
            described = json.dumps([t.to_dict() for t in self.terms], sort_keys=True)
            parts.append("terms_" + hashlib.sha256(described.encode()).hexdigest()[:10])
        if type(self.plant) is not DynamicBicycle:
            parts.insert(0, self.plant.name)
        return "_".join(parts) or "base"

    @cached_property
    def numeric(self) -> NumericModel:
        """Compiled (or VM) numeric functions of this model, built on first use."""
        return NumericModel(self)

    def __repr__(self) -> str:
        names = ", ".join(e.name for e in self.effects) or "none"
        if self.terms:
            names += "; terms: " + ", ".join(t.equation() for t in self.terms)
        inputs = "; inputs estimated" if self.estimated_inputs else ""
        online = f"; online: {', '.join(self.online.names)}" if len(self.online) else ""
        stations = f"stations: {self.n_base_stations}"
        plant = f"model: {self.plant.name}; "
        return f"CarModel({plant}effects: {names}; {stations}{inputs}{online})"


class NumericModel:
    """Numeric evaluation of a :class:`CarModel` with fixed-size, reusable buffers.

    ``step`` integrates over any ``dt`` with RK4 substeps no longer than :data:`MAX_SUBSTEP`.
    """

    def __init__(self, model: CarModel, backend: str | None = None) -> None:
        self.model = model
        sensors_all = ca.vertcat(*model.output_expressions.values())
        functions = [
            model.dynamics_function,
            model.step_function(1, "rk4_step"),
            model.function_of_xup("outputs", sensors_all, "y"),
            model.function_of_xup("applied_input", model.applied_input_expression, "u_applied"),
        ]
        self.functions: dict[str, NumericFunction] = compile_functions(
            functions, _c_name(f"chronos_{model.tag}_{model.n_base_stations}bs"), backend
        )
        if not model.car_state_is_state:
            self.functions.update(
                compile_functions(
                    [
                        model.car_state_function,
                        model.car_state_batch_function,
                        model.car_state_jacobian_function,
                    ],
                    _c_name(f"car_state_{model.tag}_{model.n_base_stations}bs"),
                    backend,
                )
            )
        self.backend = self.functions["f"].backend
        self._slices = {}
        start = 0
        for name, expression in model.output_expressions.items():
            self._slices[name] = slice(start, start + expression.numel())
            start += expression.numel()

    def f(self, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Continuous dynamics ``xdot``."""
        return self.functions["f"](x, u, p)[0]

    def step(self, x: np.ndarray, u: np.ndarray, p: np.ndarray, dt: float) -> np.ndarray:
        """State after ``dt`` s under held command ``u`` (``ceil(dt / MAX_SUBSTEP)`` RK4 steps)."""
        if dt < 0 or not math.isfinite(dt):
            raise ValueError(f"dt must be finite and >= 0, got {dt}")
        n = max(1, math.ceil(dt / MAX_SUBSTEP - 1e-9))
        h = dt / n
        step = self.functions["rk4_step"]
        for _ in range(n):
            x = step(x, u, p, h)[0]
        return x

    def outputs(self, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> dict[str, np.ndarray]:
        """All sensor outputs at state ``x`` under command ``u``, by sensor name."""
        y = self.functions["outputs"](x, u, p)[0]
        return {name: y[s] for name, s in self._slices.items()}

    def applied_input(self, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The input that reaches the car (after offset and actuator lags)."""
        return self.functions["applied_input"](x, u, p)[0]

    def car_state(self, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        """The car state :data:`CAR_STATE_NAMES` at state ``x`` under command ``u``."""
        if self.model.car_state_is_state:
            return np.array(x[: len(CAR_STATE_NAMES)], dtype=float)
        return self.functions["car_state"](x, u, p)[0]

    def car_covariance(
        self, x: np.ndarray, covariance: np.ndarray, u: np.ndarray, p: np.ndarray
    ) -> np.ndarray:
        """The car state's covariance (6 x 6) from the state's (nx x nx) at ``x``, linearised."""
        if self.model.car_state_is_state:
            return np.array(covariance[:6, :6], dtype=float)
        J = self.functions["car_state_jacobian"](x, u, p)[0]
        return J @ covariance @ J.T

    def plant_covariance(
        self, car_covariance: np.ndarray, x: np.ndarray, u: np.ndarray, p: np.ndarray
    ) -> np.ndarray:
        """The plant states' covariance (least squares, linearised at ``x``) that gives the car
        state's ``car_covariance`` (6 x 6): where an estimator restarts from a car state."""
        if self.model.car_state_is_state:
            return np.array(car_covariance, dtype=float)
        n = len(self.model.plant.states)
        G = np.linalg.pinv(self.functions["car_state_jacobian"](x, u, p)[0][:, :n])
        return G @ car_covariance @ G.T

    def car_states(
        self, states: np.ndarray, inputs: np.ndarray, p: np.ndarray | None = None
    ) -> np.ndarray:
        """The car state of each row of ``states`` (N x nx) under the command in the same row of
        ``inputs`` (N x 2), N x 6; ``p`` defaults to the model's parameters."""
        states = np.asarray(states, dtype=float)
        if self.model.car_state_is_state:
            return states[:, : len(CAR_STATE_NAMES)].copy()
        p = self.model.parameters.vector() if p is None else p
        inputs = np.broadcast_to(np.asarray(inputs, dtype=float), (len(states), 2))
        out = np.empty((len(states), len(CAR_STATE_NAMES)))
        batch = self.functions["car_state_batch"]
        for start in range(0, len(states), CAR_STATES_BATCH):
            stop = min(start + CAR_STATES_BATCH, len(states))
            x_block = np.zeros((self.model.nx, CAR_STATES_BATCH))
            u_block = np.zeros((2, CAR_STATES_BATCH))
            x_block[:, : stop - start] = states[start:stop].T
            u_block[:, : stop - start] = inputs[start:stop].T
            values = np.asarray(batch(x_block, u_block, p)[0]).reshape(
                len(CAR_STATE_NAMES), CAR_STATES_BATCH, order="F"
            )
            out[start:stop] = values[:, : stop - start].T
        return out


def _channels(sensor: str) -> tuple[str, ...]:
    if sensor == "imu":
        return ("ax", "ay", "omega")
    if sensor == "gyro":
        return ("omega",)
    if sensor == "wheel_encoders":
        return ("fl", "fr", "rl", "rr")
    if sensor == "pose":
        return ("x", "y", "yaw")
    return tuple(f"diode{k}" for k in range(sensors.N_PHOTODIODES))


def _c_name(name: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in name)
