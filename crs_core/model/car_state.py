"""The car state: what every model maps its state to, and what the suite publishes, compares
with a reference and races on (world position m, yaw rad, body velocities m/s, yaw rate rad/s).
Written apart from the model so that code reading estimates needs no CasADi."""

CAR_STATE_NAMES = ("x", "y", "yaw", "vx", "vy", "omega")
CAR_STATE_UNITS = ("m", "m", "rad", "m/s", "m/s", "rad/s")
