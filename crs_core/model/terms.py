"""Terms proposed from data: additive corrections in the model's own variables.

A :class:`Term` adds :math:`\\sum_k c_k m_k` to one *target*: the time derivative of a velocity
state (``vx``, ``vy``, ``omega``) or a sensor output (``wheel_speeds``, each of the four wheels
alike; ``wheel_speed_sides``, the right wheels up and the left ones down by as much; ``yaw_rate``,
the gyro), where each monomial :math:`m_k` is a product of the model's
variables (:data:`TERM_VARIABLES`: the velocity states, the applied inputs and ``t``, the time
since the model's state began, which a model with such a term carries as one more state,
``clock``; the empty product is a constant). The coefficients are parameters of group
``term:<name>``, so identification fits them and every tool carries them like an effect's; with
every coefficient at 0 the model is the model without the term (nested, as an effect). The
discrepancy workflow proposes terms (:mod:`crs_core.discrepancy.proposal`) and a parameter YAML
stores them under ``terms:`` (:func:`terms_in_file`), so that ``--params`` rebuilds the model
with them.

A term is a description of what predicted better, not a claim of physics.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import casadi as ca

from crs_core.errors import FieldError
from crs_core.parameters import Parameter
from crs_core.yaml_io import mapping_in_file

#: Variables a monomial may use: where they come from (a car state's or an applied input's index;
#: ``t`` the clock state's value) and unit.
TERM_VARIABLES: dict[str, tuple[str, int, str]] = {
    "vx": ("car", 3, "m/s"),
    "vy": ("car", 4, "m/s"),
    "omega": ("car", 5, "rad/s"),
    "steer": ("input", 0, "rad"),
    "torque": ("input", 1, "-"),
    "t": ("clock", 0, "s"),
}
#: The state a model with a term in ``t`` carries: the time since its state began, s
#: (derivative 1, 0 at the start: in a recording's fit and prediction, the time into it).
CLOCK_STATE = ("clock", "s")
#: Targets: the derivative of the model's state of that name (its unit), and sensor outputs.
STATE_TARGETS: dict[str, str] = {"vx": "m/s^2", "vy": "m/s^2", "omega": "rad/s^2"}
#: Sensor-output targets: the sensor, the sign with which the term adds to each of its channels
#: (``wheel_encoders``: fl, fr, rl, rr), and the unit.
OUTPUT_TARGETS: dict[str, tuple[str, tuple[float, ...], str]] = {
    "wheel_speeds": ("wheel_encoders", (1.0, 1.0, 1.0, 1.0), "rad/s"),
    "wheel_speed_sides": ("wheel_encoders", (-1.0, 1.0, -1.0, 1.0), "rad/s"),
    "yaw_rate": ("imu", (0.0, 0.0, 1.0), "rad/s"),
}
#: Largest magnitude of a coefficient, in multiples of its prior std.
BOUND_IN_STDS = 100.0


@dataclass(frozen=True)
class Term:
    """``target += sum_k c_k * prod(monomials[k])``.

    Attributes
    ----------
    name : str
        Its name, prefix of its coefficients' names (``<name>_c1``, ...); a valid identifier.
    target : str
        A key of :data:`STATE_TARGETS` (the term adds to that state's derivative) or of
        :data:`OUTPUT_TARGETS` (to that sensor output).
    monomials : tuple of tuple of str
        Each a product of :data:`TERM_VARIABLES` names (``()``: the constant 1).
    coefficients : tuple of float
        The coefficients' values (default 0: no term), target unit over the monomial's.
    prior_stds : tuple of float
        The coefficients' prior standard deviations (their scale; bounds are
        :data:`BOUND_IN_STDS` of them).
    """

    name: str
    target: str
    monomials: tuple[tuple[str, ...], ...]
    coefficients: tuple[float, ...] = ()
    prior_stds: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise FieldError("terms.name", f"must be an identifier, got {self.name!r}")
        if self.target not in STATE_TARGETS and self.target not in OUTPUT_TARGETS:
            known = ", ".join([*STATE_TARGETS, *OUTPUT_TARGETS])
            raise FieldError(f"terms.{self.name}.target", f"one of {known}, got {self.target!r}")
        if not self.monomials:
            raise FieldError(f"terms.{self.name}.monomials", "must name at least one monomial")
        for monomial in self.monomials:
            unknown = [v for v in monomial if v not in TERM_VARIABLES]
            if unknown:
                raise FieldError(
                    f"terms.{self.name}.monomials",
                    f"unknown variable {unknown[0]!r} (known: {', '.join(TERM_VARIABLES)})",
                )
        n = len(self.monomials)
        for field_name in ("coefficients", "prior_stds"):
            values = getattr(self, field_name)
            if values and len(values) != n:
                raise FieldError(
                    f"terms.{self.name}.{field_name}", f"must have {n} values, got {len(values)}"
                )
        if not self.coefficients:
            object.__setattr__(self, "coefficients", (0.0,) * n)
        if not self.prior_stds:
            object.__setattr__(self, "prior_stds", (1.0,) * n)
        if not all(math.isfinite(c) for c in self.coefficients):
            raise FieldError(f"terms.{self.name}.coefficients", "must be finite")
        if not all(math.isfinite(s) and s > 0 for s in self.prior_stds):
            raise FieldError(f"terms.{self.name}.prior_stds", "must be finite and > 0")

    @property
    def unit(self) -> str:
        """The target's unit (a derivative's for a state target)."""
        if self.target in STATE_TARGETS:
            return STATE_TARGETS[self.target]
        return OUTPUT_TARGETS[self.target][2]

    def coefficient_names(self) -> tuple[str, ...]:
        """``<name>_c1``, ``<name>_c2``, ..."""
        return tuple(f"{self.name}_c{k + 1}" for k in range(len(self.monomials)))

    def parameters(self) -> tuple[Parameter, ...]:
        """The coefficients as model parameters (group ``term:<name>``)."""
        return tuple(
            Parameter(
                name,
                value,
                _coefficient_unit(self.unit, monomial),
                -BOUND_IN_STDS * std,
                BOUND_IN_STDS * std,
                std,
                f"coefficient of {monomial_text(monomial)} in {self.target_text()}",
                f"term:{self.name}",
            )
            for name, value, std, monomial in zip(
                self.coefficient_names(),
                self.coefficients,
                self.prior_stds,
                self.monomials,
                strict=True,
            )
        )

    def target_text(self) -> str:
        """``d vx/dt`` for a state target, the output's name for an output target."""
        return f"d {self.target}/dt" if self.target in STATE_TARGETS else self.target

    def equation(self, coefficients: Sequence[float] | None = None) -> str:
        """The term in words: ``d vx/dt += -0.21 * torque*vx`` (symbols ``c1``, ... when
        ``coefficients`` is None)."""
        parts = []
        for k, monomial in enumerate(self.monomials):
            value = f"c{k + 1}" if coefficients is None else f"{coefficients[k]:.4g}"
            parts.append(f"{value} * {monomial_text(monomial)}")
        return f"{self.target_text()} += " + " + ".join(parts)

    @property
    def uses_time(self) -> bool:
        """A monomial has ``t`` in it (the model then carries :data:`CLOCK_STATE`)."""
        return any("t" in monomial for monomial in self.monomials)

    def value(self, car: ca.SX, u: ca.SX, parameter: Any, clock: ca.SX | None = None) -> ca.SX:
        """The term's value for car state ``car`` (:data:`~crs_core.model.plant.CAR_STATE_NAMES`),
        applied input ``u``, parameter access ``parameter(name) -> SX`` and the clock state
        (needed when :attr:`uses_time`)."""
        if self.uses_time and clock is None:
            raise ValueError(f"term {self.name!r} uses t: its model needs a clock state")
        values = {"car": car, "input": u, "clock": clock if clock is not None else ca.SX(0)}
        total = ca.SX(0)
        for name, monomial in zip(self.coefficient_names(), self.monomials, strict=True):
            product = ca.SX(1)
            for variable in monomial:
                kind, index, _ = TERM_VARIABLES[variable]
                product = product * values[kind][index]
            total = total + parameter(name) * product
        return total

    def variables(self) -> list[str]:
        """The model variables the term uses, in :data:`TERM_VARIABLES` order."""
        used = {v for monomial in self.monomials for v in monomial}
        return [v for v in TERM_VARIABLES if v in used]

    def to_dict(self) -> dict[str, Any]:
        """The YAML form: the structure and the coefficients' prior stds (their scale, which sets
        their bounds); the values are the parameters'."""
        return {
            "name": self.name,
            "target": self.target,
            "monomials": [monomial_text(m) for m in self.monomials],
            "prior_stds": list(self.prior_stds),
        }


def monomial_text(monomial: Sequence[str]) -> str:
    """``torque*vx``; ``1`` for the constant."""
    return "*".join(monomial) if monomial else "1"


def parse_monomial(text: str) -> tuple[str, ...]:
    """The inverse of :func:`monomial_text` (``"1"`` is the constant)."""
    text = text.strip()
    return () if text == "1" else tuple(part.strip() for part in text.split("*"))


def _coefficient_unit(target_unit: str, monomial: Sequence[str]) -> str:
    units = [TERM_VARIABLES[v][2] for v in monomial if TERM_VARIABLES[v][2] != "-"]
    return f"{target_unit}/({'*'.join(units)})" if units else target_unit


def parse_terms(entries: Any, source: str = "terms") -> tuple[Term, ...]:
    """Terms from their YAML form (a list of ``{name, target, monomials[, prior_stds]}``)."""
    if entries is None:
        return ()
    if not isinstance(entries, list):
        raise FieldError(source, "must be a list of {name, target, monomials, prior_stds}")
    terms = []
    for k, entry in enumerate(entries):
        where = f"{source}[{k}]"
        required = {"name", "target", "monomials"}
        if not isinstance(entry, Mapping) or not required <= set(entry) <= {
            *required,
            "prior_stds",
        }:
            raise FieldError(where, "must have the keys name, target, monomials (and prior_stds)")
        monomials = entry["monomials"]
        if not isinstance(monomials, list) or not all(isinstance(m, str) for m in monomials):
            raise FieldError(f"{where}.monomials", "must be a list of products such as torque*vx")
        stds = entry.get("prior_stds", [])
        if not isinstance(stds, list) or not all(isinstance(v, (int, float)) for v in stds):
            raise FieldError(f"{where}.prior_stds", "must be a list of numbers")
        terms.append(
            Term(
                str(entry["name"]),
                str(entry["target"]),
                tuple(map(parse_monomial, monomials)),
                prior_stds=tuple(float(v) for v in stds),
            )
        )
    names = [t.name for t in terms]
    if len(set(names)) != len(names):
        raise FieldError(source, "term names must be distinct")
    return tuple(terms)


def terms_in_file(path: str | Path) -> tuple[Term, ...]:
    """The terms a parameter YAML names under ``terms:`` (none for a file that cannot be read:
    the parameter loader says what is wrong with it)."""
    return parse_terms(mapping_in_file(path).get("terms"), f"{path}: terms")
