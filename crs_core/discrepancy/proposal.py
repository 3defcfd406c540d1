"""Beyond the registry: propose the missing term from what the fit leaves.

When no registry effect explains the data, the workflow asks what term, written in the model's
own variables, would. For each target of :mod:`crs_core.model.terms` the fit leaves a series:

* a velocity state's derivative (``vx``, ``vy``, ``omega``): the fit's process residual rate
  :math:`w_k / \\Delta t_k` (:func:`~crs_core.identification.validation.process_residuals`),
  what the model's dynamics miss between samples;
* a sensor output: the measurement residual :math:`y_k - h(x_k)` of its channels, each
  multiplied by the sign the term adds with and averaged (``wheel_speeds``: the four wheels'
  mean; ``wheel_speed_sides``: half the right wheels' residual minus the left ones', what a
  common mean cancels; ``yaw_rate``).

Each series is regressed on a library of candidate monomials (:func:`library`: every product of
up to :data:`MAX_DEGREE` of the variables ``vx, vy, omega, steer, torque`` and ``t``, the time
into the recording, ``t`` at most once, the constant included) by sparse regression: forward
stepwise selection, each step refitting every candidate set by least squares and adding the
monomial that explains most of what is left while it adds :data:`MIN_GAIN` of the series'
square sum (about 0: an offset is the constant's to explain), at most :data:`MAX_TERMS`. This is
SINDy's question (a sparse model from a library of candidate functions) asked of residuals
instead of measured
derivatives; it is written here rather than taken from PySINDy because the targets are the
fit's residuals and the terms are refitted inside the FIE with every other parameter, which
PySINDy's derivative-based fit does not do. A target is proposed when its selected monomials
explain at least :data:`MIN_R2` of its series. The workflow then fits each proposed
:class:`~crs_core.model.terms.Term` with the model and tests it on held-out data exactly as a
registry effect (:func:`~crs_core.discrepancy.hypotheses.judge`).

Not in the library: powers of ``t`` (a slow drift is proposed as linear in time: a polynomial in
``t`` fits any wander on the training data and extrapolates wildly), signs and absolute values
(not smooth: the FIE and the estimators need derivatives) and delayed inputs (a delay is the
registry's ``input_delay``, a lag its actuator effects).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np

from crs_core.dataset import Dataset
from crs_core.discrepancy.residuals import CHANNEL_GROUPS
from crs_core.identification.solve import FieResult
from crs_core.identification.validation import process_residuals
from crs_core.model import CarModel
from crs_core.model.terms import (
    OUTPUT_TARGETS,
    TERM_VARIABLES,
    Term,
    monomial_text,
)

#: Highest degree of a library monomial.
MAX_DEGREE = 3
#: Most monomials in one proposed term.
MAX_TERMS = 3
#: A monomial is added while it explains at least this share of the series' variance.
MIN_GAIN = 0.02
#: A target is proposed when its monomials explain at least this share of its series.
MIN_R2 = 0.1
#: The prior std of a proposed coefficient, in multiples of its regression value (weak: the
#: FIE's fit decides).
PRIOR_STD_FACTOR = 10.0
#: Series the proposal regresses: target -> dataset columns of its measurement residual and
#: the sign of each (the term's, :data:`~crs_core.model.terms.OUTPUT_TARGETS`), or None: a state
#: derivative's process residual.
TARGET_SERIES: dict[str, tuple[tuple[int, ...], tuple[float, ...]] | None] = {
    "vx": None,
    "vy": None,
    "omega": None,
    "wheel_speeds": (CHANNEL_GROUPS["wheel_speeds"], OUTPUT_TARGETS["wheel_speeds"][1]),
    "wheel_speed_sides": (CHANNEL_GROUPS["wheel_speeds"], OUTPUT_TARGETS["wheel_speed_sides"][1]),
    "yaw_rate": (CHANNEL_GROUPS["yaw_rate"], (1.0,)),
}


@dataclass
class Proposal:
    """One target's sparse fit.

    Attributes
    ----------
    target : str
        A key of :data:`TARGET_SERIES`.
    monomials : tuple of tuple of str
        The selected monomials, in the order they were added.
    coefficients : tuple of float
        Their least-squares coefficients on the series (target unit over the monomial's).
    r2 : float
        Share of the series' variance they explain.
    r2_path : tuple of float
        :math:`R^2` after each monomial was added.
    samples : int
        Samples of the series.
    """

    target: str
    monomials: tuple[tuple[str, ...], ...]
    coefficients: tuple[float, ...]
    r2: float
    r2_path: tuple[float, ...]
    samples: int

    def term(self, name: str) -> Term:
        """The proposal as a model term at 0 (nested), its coefficients' prior std
        :data:`PRIOR_STD_FACTOR` times their regression values."""
        stds = tuple(max(PRIOR_STD_FACTOR * abs(c), 1e-9) for c in self.coefficients)
        return Term(name, self.target, self.monomials, prior_stds=stds)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready fields (monomials as text)."""
        return {
            "target": self.target,
            "monomials": [monomial_text(m) for m in self.monomials],
            "coefficients": list(self.coefficients),
            "r2": self.r2,
            "r2_path": list(self.r2_path),
            "samples": self.samples,
        }


def library(variables: dict[str, np.ndarray]) -> tuple[list[tuple[str, ...]], np.ndarray]:
    """Every monomial of degree 0..:data:`MAX_DEGREE` of ``variables`` (name -> (N,) values,
    in :data:`~crs_core.model.terms.TERM_VARIABLES` order; ``t`` at most once in each) and its
    values, ``(N, L)``."""
    names = list(variables)
    monomials: list[tuple[str, ...]] = []
    for degree in range(MAX_DEGREE + 1):
        products = itertools.combinations_with_replacement(names, degree)
        monomials += [m for m in products if m.count("t") <= 1]
    n = len(next(iter(variables.values())))
    columns = [np.prod([variables[v] for v in m], axis=0) if m else np.ones(n) for m in monomials]
    return monomials, np.column_stack(columns)


def sparse_fit(
    series: np.ndarray, monomials: list[tuple[str, ...]], theta: np.ndarray, target: str
) -> Proposal:
    """Forward stepwise selection of monomials for ``series`` (finite samples only; see the
    module)."""
    keep = np.isfinite(series) & np.all(np.isfinite(theta), axis=1)
    y, x = series[keep], theta[keep]
    total = float(np.sum(y**2))
    chosen: list[int] = []
    path: list[float] = []
    r2 = 0.0
    usable = [j for j in range(x.shape[1]) if np.any(x[:, j] != 0.0)]
    while total > 0 and len(chosen) < MAX_TERMS:
        best, best_r2 = None, r2
        for j in usable:
            if j in chosen:
                continue
            r2_j = _r2(y, x[:, [*chosen, j]], total)
            if r2_j > best_r2:
                best, best_r2 = j, r2_j
        if best is None or best_r2 - r2 < MIN_GAIN:
            break
        chosen.append(best)
        r2 = best_r2
        path.append(r2)
    coefficients: tuple[float, ...] = ()
    if chosen:
        solution, *_ = np.linalg.lstsq(x[:, chosen], y, rcond=None)
        coefficients = tuple(float(c) for c in solution)
    return Proposal(
        target,
        tuple(monomials[j] for j in chosen),
        coefficients,
        r2,
        tuple(path),
        int(keep.sum()),
    )


def _r2(y: np.ndarray, x: np.ndarray, total: float) -> float:
    """Share of ``y``'s square sum (``total``; about 0, not its mean: an offset is the constant
    monomial's to explain) that the least-squares fit on the columns of ``x`` explains."""
    solution, *_ = np.linalg.lstsq(x, y, rcond=None)
    return 1.0 - float(np.sum((y - x @ solution) ** 2)) / total


def target_series(data: Dataset, model: CarModel, result: FieResult) -> dict[str, np.ndarray]:
    """Per target (:data:`TARGET_SERIES`), what the fit leaves, one value per sample (NaN where
    there is none): process residual rates for the state targets (the last sample has none),
    the signed measurement residual averaged over the measured columns for the output
    targets."""
    states = result.states
    residual_rate = np.full((len(data.t), model.nx), np.nan)
    residual_rate[:-1] = process_residuals(data, model, states) / np.diff(data.t)[:, None]
    measured = data.y - result.outputs
    out = {}
    for target, series in TARGET_SERIES.items():
        if series is None:
            if target in model.state_names:
                out[target] = residual_rate[:, model.state_names.index(target)]
            continue
        columns, signs = series
        block = measured[:, list(columns)] * np.asarray(signs)
        counts = np.sum(np.isfinite(block), axis=1)
        out[target] = np.where(counts > 0, np.nansum(block, axis=1) / np.maximum(counts, 1), np.nan)
    return out


def term_variables(data: Dataset, model: CarModel, states: np.ndarray) -> dict[str, np.ndarray]:
    """The term variables per sample: the car state's velocities at ``states``, the input the model
    applies (after its effects on the command and its actuators) and ``t``, s since the
    recording's start (:attr:`~crs_core.dataset.Dataset.recording_start`)."""
    assert data.u is not None
    applied_input = model.function_of_xup(
        "applied_proposal", model.applied_input_expression, "applied"
    )
    applied = np.asarray(
        applied_input.map(len(data.t))(states.T, data.u.T, model.parameters.vector())
    ).T
    source = {"car": model.numeric.car_states(states, applied), "input": applied}
    out = {}
    for name, (kind, index, _) in TERM_VARIABLES.items():
        out[name] = source[kind][:, index] if kind in source else data.t - data.recording_start
    return out


def propose(data: Dataset, model: CarModel, result: FieResult) -> list[Proposal]:
    """The targets whose sparse fit explains at least :data:`MIN_R2` of what the fit leaves,
    the best explained first."""
    monomials, theta = library(term_variables(data, model, result.states))
    fits = [
        sparse_fit(series, monomials, theta, target)
        for target, series in target_series(data, model, result).items()
    ]
    chosen = [f for f in fits if f.monomials and f.r2 >= MIN_R2]
    return sorted(chosen, key=lambda f: -f.r2)
