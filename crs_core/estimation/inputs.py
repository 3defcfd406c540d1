"""Inputs optional: an estimator that runs input-free until commands arrive.

Many recordings have no commanded inputs (a car driven by hand, a bag of sensors only). The
input-free model (``CarModel(estimated_inputs=True)``) estimates the applied steering angle and
torque as random-walk states from the sensors; with commands, the commanded model is more
accurate. :class:`InputModeEstimator` holds one estimator of each and starts input-free; at the
first estimate at or after the stamp of the first command (so the switch depends on the data,
not on when they arrived) that is not ``lost`` it hands over to the commanded one: that one restarts
from the current estimate and covariance, with the command active at that time, and receives
every queued event after it. The counters carry over. ``mode`` says which one is active.
"""

from __future__ import annotations

import numpy as np

from crs_core.estimation.base import Diagnostics, Estimate, Estimator
from crs_core.measurements import InputSample, Measurement


class InputModeEstimator(Estimator):
    """``estimated`` until the first command, then ``commanded``.

    Parameters
    ----------
    estimated : Estimator
        On the input-free model.
    commanded : Estimator
        On the commanded model; the same kind, sensors and settings.
    """

    def __init__(self, estimated: Estimator, commanded: Estimator) -> None:
        super().__init__(estimated.sensors)
        self._estimated, self._commanded = estimated, commanded
        self.reset(0.0, np.zeros(6))

    @property
    def active(self) -> Estimator:
        return self._commanded if self.mode == "commanded" else self._estimated

    @property
    def model(self):
        return self.active.model

    @property
    def settings(self):
        return self.active.settings

    @property
    def diagnostics(self) -> Diagnostics:
        return self.active.diagnostics

    @diagnostics.setter
    def diagnostics(self, value: Diagnostics) -> None:  # set by the base class, unused
        pass

    def reset(
        self, t0: float, x0: np.ndarray | None = None, covariance: np.ndarray | None = None
    ) -> None:
        self.mode = "estimated"
        self._commands: list[InputSample] = []  # received while input-free (until handover)
        self._commanded.diagnostics = Diagnostics()
        self._estimated.diagnostics = Diagnostics()
        self._estimated.reset(t0, x0, covariance)

    def add_measurement(self, measurement: Measurement) -> bool:
        return self.active.add_measurement(measurement)

    def add_input(self, sample: InputSample) -> bool:
        if self.mode == "estimated":
            if not isinstance(sample, InputSample):
                raise TypeError("input: expected a crs_core.measurements.InputSample")
            accepted = self._estimated.add_input(sample)
            if accepted:  # a late command neither counts as the first one nor takes effect
                self._commands.append(sample)
            return accepted
        return self._commanded.add_input(sample)

    def accepts(self, sensor: str) -> bool:
        return self.active.accepts(sensor)

    def model_sensors(self) -> list[str]:
        return self.active.model_sensors()

    def late_before(self) -> float:
        return self.active.late_before()

    def estimate(self, t: float) -> Estimate:
        if self.mode == "estimated" and any(c.stamp <= t for c in self._commands):
            last = self._estimated.estimate(t)
            if last.status == "lost":  # hand over a found car, not a blind start
                return last
            self._hand_over(last)
        return self.active.estimate(t)

    def _hand_over(self, last: Estimate) -> None:
        old, new, t = self._estimated, self._commanded, last.stamp
        queued = sorted(old._queue, key=lambda e: (*e[:2], e[3]))  # events after t
        new.diagnostics = old.diagnostics
        new.reset(t, last.x, last.covariance)
        before = [c for c in self._commands if c.stamp <= t]
        if before:
            new.add_input(InputSample(t, max(before, key=lambda c: c.stamp).u))
        for *_, item in queued:
            new.add(item)
        self._commands.clear()
        self.mode = "commanded"
