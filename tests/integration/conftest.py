"""Fixtures of the integration tests (helpers are in ``stack_probe``)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def warm_codegen() -> None:
    """Compile (or load from ``$CRS_CACHE_DIR``) the model, EKF and MHE code once, before any
    node starts: a cold cache costs each starting node ~10 s and makes them compile at once."""
    from crs_core.estimation import make_estimator
    from crs_core.model import CarModel

    model = CarModel()
    for kind in ("ekf", "mhe"):
        make_estimator(kind, "lh+imu+we", model)  # auto: both input modes
