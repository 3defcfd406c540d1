"""Lighthouse base-station calibration (paper Sec. IV-A, VII-B).

* :mod:`~crs_core.calibration.points`: the static points file (``POINTS_FILE``) and its checks.
* :mod:`~crs_core.calibration.static`: stations from sweeps at known static poses.
* :mod:`~crs_core.calibration.moving`: stations, clock offset and photodiodes from a recording
  with a motion-capture pose reference.
* :mod:`~crs_core.calibration.solver`, :mod:`~crs_core.calibration.sweep_model`: the shared
  least-squares engine on the model's sweep-angle expressions.
* :mod:`~crs_core.calibration.evaluation`, :mod:`~crs_core.calibration.report`,
  :mod:`~crs_core.calibration.plots`: residuals, reprojected positions, mean/max vs n, outputs.

Command line: ``crs calibrate-lighthouse`` (:mod:`launch_scripts.commands.calibration`).
"""

from crs_core.calibration.moving import MovingCalibration, calibrate_moving
from crs_core.calibration.points import CalibrationPoint, CalibrationPoints, load_points
from crs_core.calibration.static import StaticCalibration, calibrate_static

__all__ = [
    "CalibrationPoint",
    "CalibrationPoints",
    "MovingCalibration",
    "StaticCalibration",
    "calibrate_moving",
    "calibrate_static",
    "load_points",
]
