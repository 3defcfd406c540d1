"""Tests of crs_core.estimation.inputs: the auto input mode."""

import numpy as np

from crs_core.estimation import (
    make_estimator,
)
from tests.crs_core.estimation.conftest import _position_error, _run


def test_auto_mode_hands_over_to_the_commanded_model(drive):
    """``auto`` starts input-free and switches once commands arrive, without a jump."""
    estimator = make_estimator("mhe", "lh+imu+we")
    queries = np.arange(1, 300) / 60.0
    xs, statuses = _run(estimator, drive, queries)
    assert estimator.mode == "commanded"
    assert estimator.model.estimated_inputs is False
    assert _position_error(drive, queries, xs)[queries > 1.0].max() < 0.01
    assert statuses[-1] == "ok"
