"""Race tracks: the centerline geometry (:mod:`crs_core.track.geometry`) and the CRS track
YAML file with the packaged demo track (:mod:`crs_core.track.yaml_file`), and the
minimum-curvature line within its borders (:mod:`crs_core.track.racing_line`).

Laps along a track are counted by :class:`crs_core.analysis.laps.LapCounter`.
"""

from crs_core.track.geometry import Projection, Track
from crs_core.track.racing_line import RacingLine, minimum_curvature_line
from crs_core.track.yaml_file import DEMO_TRACK_PATH, load_demo_track, read_track

__all__ = [
    "DEMO_TRACK_PATH",
    "Projection",
    "RacingLine",
    "Track",
    "load_demo_track",
    "minimum_curvature_line",
    "read_track",
]
