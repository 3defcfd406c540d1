"""The model an identification starts from: the dataset's geometry, effects, a parameter file.

Shared by ``crs sysid``, ``crs validate``, ``crs discrepancy`` and the identification benchmark.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from crs_core.dataset import Dataset
from crs_core.errors import FieldError
from crs_core.estimation.offline import dataset_model
from crs_core.model import CarModel
from crs_core.model.chronos import ROUGH_PRIOR
from crs_core.model.effects import effect_spec

#: ``--params rough``: the rougher prior of the real recordings' README.
ROUGH = "rough"


def identification_model(
    dataset: Dataset,
    effects: Sequence[tuple[str, str | None, float | None]] | Sequence[str] = (),
    params: Path | str | None = None,
    field: str = "params",
) -> CarModel:
    """The model with the dataset's Lighthouse geometry, effects and a parameter file
    (``"rough"``: :data:`~crs_core.model.chronos.ROUGH_PRIOR`); a ``ValueError`` names
    ``field`` (the command-line option, for example)."""
    parsed = [e for e in effects if not isinstance(e, str)]
    spec: dict[str, Any] = (
        effect_spec(parsed) if parsed else {name: None for name in effects if isinstance(name, str)}
    )
    rough = params is not None and str(params) == ROUGH
    dataset.geometry.known_stations()  # its own field, not ``field``, names a missing geometry
    try:
        return dataset_model(dataset, None if rough else params, spec, ROUGH_PRIOR if rough else {})
    except (ValueError, KeyError) as error:
        message = error.args[0] if error.args else str(error)
        raise FieldError(field, str(message)) from None
