"""Controllers that turn a state estimate into a car input ``u = [delta, T]``, and the
supervisor that runs one in real time."""

from crs_core.control.path_following import (
    PathFollower,
    PathFollowerSettings,
    PathFollowerStatus,
)
from crs_core.control.supervisor import (
    Supervisor,
    SupervisorEvent,
    SupervisorSettings,
    SupervisorStep,
)

__all__ = [
    "PathFollower",
    "PathFollowerSettings",
    "PathFollowerStatus",
    "Supervisor",
    "SupervisorEvent",
    "SupervisorSettings",
    "SupervisorStep",
]
