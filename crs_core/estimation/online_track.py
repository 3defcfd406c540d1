"""The online parameters of an estimator over a run: value, standard deviation and whether
informed at each estimate, and the ``t, name, value, std`` CSV every tool writes them as."""

from __future__ import annotations

import csv
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from crs_core.estimation.base import OnlineValue

#: The CSV's columns: seconds since the run's origin, the parameter, its value and std.
CSV_COLUMNS = ("t", "name", "value", "std")


@dataclass
class OnlineTrack:
    """Online parameters at N estimates.

    Attributes
    ----------
    names : tuple of str
        The parameters, in the estimation model's order.
    value, std : np.ndarray
        (P, N) each parameter's value and standard deviation, in its unit (NaN where the
        estimate carried none: lost).
    informed : np.ndarray
        (P, N) bool: whether the data informed it there.
    """

    names: tuple[str, ...]
    value: np.ndarray
    std: np.ndarray
    informed: np.ndarray

    @classmethod
    def empty(cls, n: int, names: Sequence[str] = ()) -> OnlineTrack:
        """N estimates of ``names``, all NaN until :meth:`set`."""
        shape = (len(names), n)
        return cls(
            tuple(names), np.full(shape, np.nan), np.full(shape, np.nan), np.zeros(shape, bool)
        )

    def set(self, k: int, parameters: Mapping[str, OnlineValue]) -> None:
        """Estimate ``k``'s values (an :attr:`~crs_core.estimation.base.Estimate.parameters`)."""
        for i, name in enumerate(self.names):
            entry = parameters.get(name)
            if entry is not None:
                self.value[i, k], self.std[i, k] = entry.value, entry.std
                self.informed[i, k] = entry.informed

    def final_summary(self) -> dict[str, dict[str, Any]]:
        """Per parameter its last value with a standard deviation (JSON-ready)."""
        out: dict[str, dict[str, Any]] = {}
        for i, name in enumerate(self.names):
            known = np.flatnonzero(np.isfinite(self.value[i]))
            if known.size:
                k = known[-1]
                out[name] = {
                    "value": float(self.value[i, k]),
                    "std": float(self.std[i, k]),
                    "informed": bool(self.informed[i, k]),
                }
        return out

    def write_csv(
        self,
        path: str | Path,
        t: np.ndarray,
        priors: Mapping[str, tuple[float, float]],
        prior_t: float | None = None,
    ) -> Path:
        """``t, name, value, std``: each parameter's prior (``priors``: value and std by name,
        :attr:`~crs_core.model.online.OnlineParameters.priors`) at ``prior_t`` (default
        ``t[0]``), then one row per parameter per estimate that carried it; ``t`` (the
        estimates' times) in seconds since the run's origin."""
        path = Path(path)
        with path.open("w", newline="") as stream:
            writer = csv.writer(stream)
            writer.writerow(CSV_COLUMNS)
            start = prior_t if prior_t is not None else (float(t[0]) if len(t) else 0.0)
            for name in self.names:
                value, std = priors[name]
                writer.writerow((f"{start:.4f}", name, repr(float(value)), repr(float(std))))
            for k, stamp in enumerate(t):
                for i, name in enumerate(self.names):
                    if np.isfinite(self.value[i, k]):
                        row = (
                            f"{stamp:.4f}",
                            name,
                            repr(float(self.value[i, k])),
                            repr(float(self.std[i, k])),
                        )
                        writer.writerow(row)
        return path
