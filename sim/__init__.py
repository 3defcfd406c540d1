"""ROS-free simulator of the Chronos car: truth dynamics and sensors at their own rates."""

from sim.sensors import Blackout, SensorSpec, SensorSuite
from sim.simulator import SimulationResult, Simulator

__all__ = ["Blackout", "SensorSpec", "SensorSuite", "SimulationResult", "Simulator"]
