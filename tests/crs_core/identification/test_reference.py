"""crs_core.identification.reference: the positions a prediction is compared with."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from crs_core.identification.reference import LIGHTHOUSE_REFERENCE, position_reference


def test_the_reference_states_where_the_dataset_has_them(drive):
    reference = position_reference(drive)
    np.testing.assert_array_equal(reference.xy, drive.x[:, :2])
    assert reference.description == "simulation truth"
    labelled = replace(drive, meta={**drive.meta, "reference": "estimates of car1"})
    assert position_reference(labelled).description == "estimates of car1"


def test_without_them_each_samples_lighthouse_fix(drive):
    """On a simulated drive (about 1 m/s) the fixes lie within 2 cm of the truth (median 8 mm:
    the Lighthouse noise, and the car moving 1 cm between the two planes' sweeps, which one fix
    takes as simultaneous); a sample missing a sweep has none."""
    bare = replace(drive, x=None)
    y = bare.y.copy()
    y[5, 2] = np.nan
    reference = position_reference(replace(bare, y=y))
    assert reference.description == LIGHTHOUSE_REFERENCE
    error = np.linalg.norm(reference.xy - drive.x[:, :2], axis=1)
    assert np.isnan(error[5]) and np.isfinite(np.delete(error, 5)).all()
    assert np.nanmedian(error) < 0.012 and np.nanmax(error) < 0.025


def test_the_fixes_are_computed_once_per_dataset(drive):
    """A copy with other inputs (a delayed-command hypothesis) shares them; other sweeps not."""
    bare = replace(drive, x=None)
    first = position_reference(bare).xy
    assert position_reference(replace(bare, u=bare.u[::-1].copy())).xy is first
    y = bare.y.copy()
    y[0, 0] += 1e-3
    assert position_reference(replace(bare, y=y)).xy is not first
