"""Race tracks: the centerline geometry (:mod:`crs_core.track.geometry`) and the CRS track
YAML file with the packaged demo track (:mod:`crs_core.track.yaml_file`).

Laps along a track are counted by :class:`crs_core.analysis.laps.LapCounter`.
"""

from crs_core.track.geometry import Projection, Track
from crs_core.track.yaml_file import DEMO_TRACK_PATH, load_demo_track, read_track

__all__ = ["DEMO_TRACK_PATH", "Projection", "Track", "load_demo_track", "read_track"]
