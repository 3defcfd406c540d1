"""A simulated recording for moving Lighthouse calibration: sweeps plus motion-capture poses.

The car follows the demo track under the path follower (as ``crs sim``); the simulator records
the Lighthouse sweeps and the motion-capture ``pose`` sensor. The two clocks differ by
``clock_offset`` s: ``pose`` stamps are ``t_car + clock_offset``, i.e. the pose stamped
``t_lh + clock_offset`` is where the car was at the sweep stamped ``t_lh`` (a positive offset
is a pose latency, a negative one a Lighthouse latency, both through
:attr:`sim.sensors.SensorSpec.latency_s`). With ``lighthouse_only`` the dataset keeps nothing
else: no inputs (no ``u.npy``), NaN wheel-speed and yaw-rate rows, a stream of Lighthouse and
pose samples only, like a recording made with the Lighthouse deck and motion capture alone.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from crs_core.control.path_following import PathFollower, PathFollowerSettings
from crs_core.dataset import Dataset
from crs_core.model import CarModel
from crs_core.model.lighthouse import BaseStation
from crs_core.track import load_demo_track
from sim.sensors import SensorSpec, SensorSuite
from sim.simulator import Simulator

#: Motion-capture noise: 0.5 mm per axis, 2 mrad yaw, at 100 Hz.
MOCAP = SensorSpec(100.0, (5e-4, 5e-4, 2e-3))


def simulate_mocap_recording(
    duration: float = 20.0,
    clock_offset: float = 0.02,
    stations: list[BaseStation] | None = None,
    seed: int = 0,
    speed: float = 1.0,
    mocap: SensorSpec = MOCAP,
    sensors: SensorSuite | None = None,
    lighthouse_only: bool = True,
) -> Dataset:
    """Simulate the recording (module docstring); the truth geometry is in ``dataset.geometry``.

    Parameters
    ----------
    duration : simulated time, s.
    clock_offset : motion-capture clock minus car clock, s.
    stations : the true base stations (default: the recorded one).
    seed : noise seed.
    speed : reference speed of the path follower, m/s.
    mocap : rate and noise of the motion-capture poses (its latency is set from the offset).
    sensors : the other sensors (default ``SensorSuite()``: 1 mrad Lighthouse noise, 5 %
        drop-outs).
    lighthouse_only : strip inputs, IMU and encoders (module docstring).
    """
    sensors = sensors or SensorSuite()
    if clock_offset >= 0:
        sensors = replace(sensors, pose=replace(mocap, latency_s=float(clock_offset)))
    else:
        sensors = replace(
            sensors,
            pose=replace(mocap, latency_s=0.0),
            lighthouse=replace(sensors.lighthouse, latency_s=-float(clock_offset)),
        )
    model = CarModel(base_stations=stations) if stations else CarModel()
    track = load_demo_track()
    wheelbase = model.parameters.value("lf") + model.parameters.value("lr")
    controller = PathFollower(track, wheelbase, PathFollowerSettings(v_ref=speed))
    x0 = track.start_state()
    result = Simulator(model, sensors, seed=seed).run(controller, duration, x0)
    result.extra_meta["clock_offset_s"] = float(clock_offset)
    dataset = result.to_dataset()
    if lighthouse_only:
        dataset.u = None
        dataset.y[:, 8:] = np.nan
        dataset.inputs = None
        dataset.measurements = [
            m for m in dataset.measurements if m.sensor == "pose" or m.sensor.startswith("lighth")
        ]
        dataset.meta["content"] = "lighthouse sweeps and motion-capture poses only"
    return dataset
