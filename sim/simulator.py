"""Event-driven simulation of the Chronos car with its sensors at their own rates.

Truth is the :class:`~crs_core.model.CarModel` (optionally with effects) integrated exactly
between events with RK4 substeps of at most :data:`~crs_core.model.MAX_SUBSTEP`. Events are
the application of (delayed) commands and sensor acquisitions. A :class:`SimulationSession`
advances step by step (the real-time simulator node drives one); :meth:`Simulator.run` drives
one with a controller that sees the true base state. Everything random is drawn from
generators seeded by ``(seed, sensor name)``, so a run is reproducible and changing one
sensor's settings does not reshuffle another's noise.

Optionally (``Simulator(..., onboard=OnboardSettings())``, off by default) the car's onboard
250 Hz loop runs in the simulation (:mod:`sim.onboard`): commands are then references for its
steering and velocity PIDs, ``[delta, T]`` (``mode="torque"``) or ``[delta, v_x]``
(``mode="velocity"``), and the car steers with the simulated steering actuator's angle.
"""

from __future__ import annotations

import hashlib
import heapq
from collections.abc import Callable

import numpy as np
from tqdm import tqdm

from crs_core.errors import FieldError
from crs_core.measurements import InputSample, Measurement, lighthouse_sensor
from crs_core.model import CarModel
from sim.drift import DriftSchedule
from sim.onboard import MODES, OnboardLoop, OnboardSettings
from sim.result import SimulationResult
from sim.sensors import SensorSpec, SensorSuite

Controller = Callable[[float, np.ndarray], np.ndarray]

# event kinds, in the order they are handled at equal times
_APPLY, _TICK, _SENSOR = 0, 1, 2


#: Sweep angles beyond this (rad) are out of the base station's view; the host drops them.
LIGHTHOUSE_VIEW_LIMIT = 1.5


def _in_view(sensor: str, values: np.ndarray) -> bool:
    """False for a Lighthouse sweep that cannot reach a photodiode or lies outside the view."""
    if not sensor.startswith("lighthouse"):
        return True
    return bool(np.all(np.isfinite(values)) and np.all(np.abs(values) <= LIGHTHOUSE_VIEW_LIMIT))


def _rng(seed: int, name: str) -> np.random.Generator:
    digest = int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")
    return np.random.default_rng([seed, digest])


class Simulator:
    """Simulate a car model with a sensor suite.

    Parameters
    ----------
    model : CarModel
        Truth model; its parameters (and effects) are the hidden truth.
    sensors : SensorSuite
        Rates and imperfections; ``SensorSuite().ideal()`` for noise-free sensors.
    seed : int
        Seed of every random draw, >= 0.
    onboard : OnboardSettings, optional
        Run the car's onboard low-level loop (steering actuator, steering and velocity PIDs;
        :mod:`sim.onboard`). Default ``None``: commands act on the model directly.
    drift : DriftSchedule, optional
        Changes of the truth over time, counted from the first command the car applies
        (:mod:`sim.drift`); the effects it changes are switched on (at 0) where ``model``
        lacks them.
    """

    def __init__(
        self,
        model: CarModel,
        sensors: SensorSuite | None = None,
        seed: int = 0,
        onboard: OnboardSettings | None = None,
        drift: DriftSchedule | None = None,
    ):
        if onboard is not None and not isinstance(onboard, OnboardSettings):
            raise FieldError("onboard", f"must be an OnboardSettings or None, got {onboard!r}")
        if onboard is not None and model.estimated_inputs:
            raise FieldError("onboard", "the input-free model takes no commands")
        if int(seed) < 0:  # numpy's seeds are not negative
            raise FieldError("seed", f"must be >= 0, got {seed!r}")
        self.model = drift.model_for(model) if drift is not None else model
        self.drift = drift
        self.sensors = sensors or SensorSuite()
        self.seed = int(seed)
        self.onboard = onboard

    def session(self, x0: np.ndarray, keep_history: bool = True) -> SimulationSession:
        """A running simulation from base state ``x0`` (6,) at t = 0, advanced step by step.

        ``keep_history=False`` keeps no truth, input or measurement history (constant memory,
        for a simulator that streams its samples out, such as the ROS node); ``result()`` then
        holds only the current state.
        """
        return SimulationSession(self, x0, keep_history)

    def run(
        self,
        controller: Controller,
        duration: float,
        x0: np.ndarray,
        control_rate_hz: float = 50.0,
        progress: bool = False,
        mode: str = "torque",
    ) -> SimulationResult:
        """Simulate ``duration`` s from base state ``x0`` (6,) under ``controller(t, x) -> u``.

        ``u`` is ``[steer (rad), torque (-)]`` (``mode="velocity"``, with the onboard loop:
        ``[steer (rad), v_x (m/s)]``), held between controller ticks and delayed by the
        model's ``input_delay``; the controller is called with the true base state.
        """
        if not duration > 0:
            raise FieldError("duration", f"must be > 0, got {duration}")
        session = self.session(x0)
        with tqdm(total=duration, unit="sim s", disable=not progress, leave=False) as bar:
            for t in np.arange(0.0, duration, 1.0 / control_rate_hz):
                session.advance(t)
                session.command(controller(t, session.base_state), mode)
                bar.n = t
                bar.refresh()
            session.advance(duration)
        return session.result()


class _SensorClock:
    """Acquisition times of one sensor: a regular grid plus jitter, generated as needed."""

    def __init__(self, spec: SensorSpec, phase: float, rng: np.random.Generator) -> None:
        self.period, self.phase, self.jitter, self.rng = (
            1.0 / spec.rate_hz,
            phase,
            spec.jitter_std_s,
            rng,
        )
        self.k = 0
        self.last = -np.inf

    def next(self) -> float:
        t = self.phase + self.k * self.period
        if self.jitter > 0:
            t += self.rng.normal(0.0, self.jitter)
        self.k += 1
        self.last = max(t, self.last + 1e-9, 0.0)
        return self.last


class SimulationSession:
    """A simulation in progress: issue commands, advance time, collect measurements.

    Events between calls are handled in time order: application of (delayed) commands first,
    then the onboard loop's ticks (if any), then sensor acquisitions. A command takes effect at
    the time it is issued (plus the model's input delay); a sensor sample at exactly that time
    already sees it.
    """

    def __init__(self, simulator: Simulator, x0: np.ndarray, keep_history: bool = True) -> None:
        self.simulator = simulator
        self.keep_history = keep_history
        model, sensors, seed = simulator.model, simulator.sensors, simulator.seed
        self._numeric = model.numeric
        self._p = model.parameters.vector()
        names = model.parameters.names
        schedule = simulator.drift
        #: where each parameter the drift schedule changes sits in the vector, and its start
        self._drift_index = {n: names.index(n) for n in (schedule.parameters if schedule else ())}
        self._drift_start = {n: float(self._p[k]) for n, k in self._drift_index.items()}
        #: When the car applied its first command (the drift's origin), s; None before.
        self.first_command_time: float | None = None
        self._delay = model.input_delay()
        self._x = model.initial_state(np.asarray(x0, dtype=float))
        self._u = np.zeros(2)
        self._now = 0.0
        self._heap: list[tuple[float, int, int, object]] = []
        self._counter = 0
        names = ["imu", "wheel_encoders"] + (["pose"] if sensors.pose is not None else [])
        phases = dict.fromkeys(names, 0.0)
        rate = sensors.lighthouse.rate_hz
        for station in range(model.n_base_stations):
            for plane in (1, 2):
                name = lighthouse_sensor(station, plane)
                names.append(name)
                phases[name] = (plane - 1) * 0.5 / rate + station * 0.13 / rate
        self._clocks = {
            n: _SensorClock(sensors.spec(n), phases[n], _rng(seed, n + "/time")) for n in names
        }
        self._rngs = {n: _rng(seed, n) for n in names}
        self._noise = {n: np.array(sensors.spec(n).noise_std) for n in names}
        self._bias = {
            n: np.array(sensors.spec(n).bias or np.zeros(self._noise[n].size)) for n in names
        }
        for name, clock in self._clocks.items():
            self._push(clock.next(), _SENSOR, name)
        self.truth_t: list[float] = [0.0]
        self.truth_x: list[np.ndarray] = [self.base_state]
        self.inputs: list[InputSample] = []
        self.measurements: list[Measurement] = []
        self.applied_inputs: list[InputSample] = []
        self.reference_modes: list[str] = []
        #: The onboard loop (None unless the simulator has ``onboard`` settings).
        self.onboard: OnboardLoop | None = None
        if simulator.onboard is not None:
            self.onboard = OnboardLoop(
                simulator.onboard,
                self._noise["wheel_encoders"],
                self._bias["wheel_encoders"],
                _rng(seed, "onboard/potentiometer"),
                _rng(seed, "onboard/wheel_encoders"),
            )
            self._push(0.0, _TICK, None)

    @property
    def time(self) -> float:
        """Current simulation time, s."""
        return self._now

    @property
    def base_state(self) -> np.ndarray:
        """True car state ``[x, y, yaw, vx, vy, omega]`` now (the model's state mapped to it)."""
        return self._numeric.car_state(self._x, self._u, self._p)

    @property
    def applied_command(self) -> np.ndarray:
        """The input acting on the car now (after any input delay; with the onboard loop, the
        ``[delta, T]`` it applies)."""
        return self._u.copy()

    def _push(self, t: float, kind: int, payload: object) -> None:
        heapq.heappush(self._heap, (t, kind, self._counter, payload))
        self._counter += 1

    def command(self, u: np.ndarray, mode: str = "torque") -> InputSample:
        """Issue command ``u`` now (validated); returns the logged sample.

        ``mode="torque"``: ``u = [steer (rad), torque (-)]``; ``mode="velocity"`` (needs the
        onboard loop): ``u = [steer (rad), v_x (m/s)]``, a reference for the velocity PID.
        """
        if mode not in MODES:
            raise FieldError("mode", f"must be one of {', '.join(MODES)}, got {mode!r}")
        if mode != "torque" and self.onboard is None:
            raise FieldError(
                "mode",
                f"{mode!r} references need the onboard loop "
                "(Simulator(..., onboard=OnboardSettings()))",
            )
        sample = InputSample(self._now, np.asarray(u, dtype=float))
        if self.keep_history:
            self.inputs.append(sample)
            if self.onboard is not None:
                self.reference_modes.append(mode)
        payload = sample.u if self.onboard is None else (sample.u, mode)
        if self._delay > 0:
            self._push(self._now + self._delay, _APPLY, payload)
        else:
            self._apply(payload)
        return sample

    def _apply(self, payload: object) -> None:
        """A command reaches the car (or, with the onboard loop, its controllers)."""
        if self.first_command_time is None:
            self.first_command_time = self._now
        if self.onboard is None:
            self._u = payload
            return
        self._u = self.onboard.set_reference(*payload)
        self._log_applied()

    def _tick(self) -> None:
        """One step of the onboard loop at the current time; schedules the next one."""
        wheels = self._numeric.outputs(self._x, self._u, self._p)["wheel_encoders"]
        self._u = self.onboard.tick(self._now, wheels)
        self._log_applied()
        self._push(self.onboard.next_tick(), _TICK, None)

    def _log_applied(self) -> None:
        """Log the applied input; one sample per stamp (a tick after an application wins)."""
        if not self.keep_history:
            return
        if self.applied_inputs and self.applied_inputs[-1].stamp == self._now:
            self.applied_inputs.pop()
        self.applied_inputs.append(InputSample(self._now, self._u))

    def advance(self, t: float) -> list[Measurement]:
        """Run every event before ``t`` and integrate to ``t``; returns the new measurements."""
        if t < self._now:
            raise FieldError("t", f"cannot go back in time ({t} < {self._now})")
        new: list[Measurement] = []
        while self._heap and self._heap[0][0] < t:
            event_time, kind, _, payload = heapq.heappop(self._heap)
            self._integrate_to(event_time)
            if kind == _APPLY:
                self._apply(payload)
            elif kind == _TICK:
                self._tick()
            else:
                measurement = self._acquire(payload)
                self._push(self._clocks[payload].next(), _SENSOR, payload)
                if measurement is not None:
                    new.append(measurement)
        self._integrate_to(t)
        new.sort(key=lambda m: (m.stamp, m.sensor))
        if self.keep_history:
            self.measurements.extend(new)
        return new

    @property
    def drifted(self) -> dict[str, float]:
        """The parameters the drift schedule changes, as they are now (empty without one)."""
        return {name: float(self._p[k]) for name, k in self._drift_index.items()}

    def _integrate_to(self, t: float) -> None:
        if t > self._now:
            schedule = self.simulator.drift
            if schedule is not None and self.first_command_time is not None:
                since = self._now - self.first_command_time
                for name, value in schedule.values_at(since, self._drift_start).items():
                    self._p[self._drift_index[name]] = value
            self._x = self._numeric.step(self._x, self._u, self._p, t - self._now)
            self._now = t
            if not self.keep_history:  # only the current state
                self.truth_t.clear()
                self.truth_x.clear()
            self.truth_t.append(t)
            self.truth_x.append(self.base_state)

    def _acquire(self, name: str) -> Measurement | None:
        """One sample of sensor ``name`` now, or None if it is lost."""
        sensors = self.simulator.sensors
        spec, rng = sensors.spec(name), self._rngs[name]
        # draw every sample's randomness, so drop-outs do not shift later noise
        dropped = rng.random() < spec.dropout_probability
        values = self._numeric.outputs(self._x, self._u, self._p)[name]
        values = values + self._bias[name] + self._noise[name] * rng.standard_normal(values.size)
        if dropped or sensors.blacked_out(name, self._now) or not _in_view(name, values):
            return None
        return Measurement(self._now + spec.latency_s, name, values)

    def result(self) -> SimulationResult:
        """Everything so far as a :class:`SimulationResult` (duration = current time)."""
        return SimulationResult(
            model=self.simulator.model,
            sensors=self.simulator.sensors,
            seed=self.simulator.seed,
            duration=self._now,
            truth_t=np.array(self.truth_t),
            truth_x=np.array(self.truth_x),
            inputs=list(self.inputs),
            measurements=sorted(self.measurements, key=lambda m: (m.stamp, m.sensor)),
            extra_meta=(
                {"onboard": self.simulator.onboard.to_dict()} if self.onboard is not None else {}
            ),
            applied_inputs=list(self.applied_inputs),
            reference_modes=list(self.reference_modes),
        )
