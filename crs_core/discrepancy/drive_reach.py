"""How far a drive got: the grip and peak slip it reached, the track and the view it kept, and
the σ it is predicted to leave (the figures of ``crs plan-drive``'s ``report.json`` and of
``crs bench plan-drive``).

Grip used is :func:`~crs_core.model.bicycle.grip_used` (|F_y| / D per axle, 1 at the Pacejka
curve's peak); the peak slip fraction is the slip angle over the curve's peak slip
:func:`~crs_core.model.bicycle.peak_slip` (rad / rad). Both are taken where the car is at speed
(:data:`MOVING_SPEED`), with the commands as driven.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from crs_core.discrepancy.drive_design import DriveDesign
from crs_core.model import CarModel
from crs_core.model.bicycle import grip_used, peak_slip, slip_angles
from crs_core.track import Track

#: Forward speed above which grip and slip are taken, m/s (slip angles are defined at speed).
MOVING_SPEED = 0.5


def slip_used(states: np.ndarray, inputs: np.ndarray, model: CarModel) -> np.ndarray:
    """``|alpha| / alpha_peak`` of the front and rear axle (columns) per row of ``states``
    (N x 6) and ``inputs`` (N x 2): 1 at the Pacejka curve's peak slip
    (:func:`~crs_core.model.bicycle.peak_slip`)."""
    value = model.parameters.value

    def constant(name: str) -> ca.SX:
        return ca.SX(value(name))

    x, u = ca.SX.sym("x", 6), ca.SX.sym("u", 2)
    front, rear = slip_angles(x, u, constant)
    peaks = (peak_slip(value("Cf"), value("Bf")), peak_slip(value("Cr"), value("Br")))
    used = ca.vertcat(ca.fabs(front) / peaks[0], ca.fabs(rear) / peaks[1])
    rows = ca.Function("slip_used", [x, u], [used]).map(len(states))
    return np.asarray(rows(np.asarray(states).T, np.asarray(inputs).T)).T


def drive_summary(design: DriveDesign, model: CarModel, track: Track, margin: float) -> dict:
    """JSON-ready figures of a drive: the open parameters' sigma before and after, how much
    of each axle's grip and peak slip it reached (largest, at speed), its largest distance
    from the centreline against the limit, the share of samples the Lighthouse saw, and what
    limited it (``track`` where it comes within 1 cm of the limit, ``lighthouse`` where it
    leaves the view)."""
    samples = design.samples
    moving = samples.x[:, 3] > MOVING_SPEED
    states, inputs = samples.x[moving, :6], samples.u[moving]
    grip = grip_used(states, inputs, model.parameters.value) if moving.any() else np.zeros((1, 2))
    slip = slip_used(states, inputs, model) if moving.any() else np.zeros((1, 2))
    half = float(np.min(track.width)) / 2 - margin
    worst = float(np.max(np.abs(design.lateral_error)))
    limited = []
    if worst >= half - 0.01:
        limited.append("track")
    if not samples.in_view.all():
        limited.append("lighthouse")
    before, after = design.sigma(after=False), design.sigma()
    return {
        "kind": design.drive.kind,
        "duration_s": design.drive.duration_s,
        "sigma": {
            n: {
                "before": before[n],
                "after": after[n],
                "ratio": after[n] / before[n] if before[n] > 0 else None,
            }
            for n in design.open
        },
        "criterion_log_det": design.criterion,
        "penalty": design.penalty,
        "grip_used_max": {"front": float(grip[:, 0].max()), "rear": float(grip[:, 1].max())},
        "peak_slip_fraction_max": {
            "front": float(slip[:, 0].max()),
            "rear": float(slip[:, 1].max()),
        },
        "max_lateral_error_m": worst,
        "lateral_limit_m": half,
        "in_view_fraction": float(np.mean(samples.in_view)),
        "limited_by": limited,
        "evaluations": design.evaluations,
    }
