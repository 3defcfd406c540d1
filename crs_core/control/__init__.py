"""Controllers that turn a state estimate into a car input ``u = [delta, T]``."""

from crs_core.control.path_following import (
    PathFollower,
    PathFollowerSettings,
    PathFollowerStatus,
)

__all__ = ["PathFollower", "PathFollowerSettings", "PathFollowerStatus"]
