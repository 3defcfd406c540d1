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
from crs_core.model.plants import load_plant, resolve_model

#: ``--params rough``: the rougher prior of the real recordings' README.
ROUGH = "rough"


def identification_model(
    dataset: Dataset,
    effects: Sequence[tuple[str, str | None, float | None]] | Sequence[str] = (),
    params: Path | str | None = None,
    field: str = "params",
    model: str | None = None,
) -> CarModel:
    """The model ``model`` (a spec; by default the parameter file's, else the dynamic
    bicycle) with the dataset's Lighthouse geometry, effects and a parameter file
    (``"rough"``: :data:`~crs_core.model.chronos.ROUGH_PRIOR`, the values the model has); a
    ``ValueError`` names ``field`` (the command-line option, for example), a bad or
    contradicting ``model`` ``--model``."""
    parsed = [e for e in effects if not isinstance(e, str)]
    spec: dict[str, Any] = (
        effect_spec(parsed) if parsed else {name: None for name in effects if isinstance(name, str)}
    )
    rough = params is not None and str(params) == ROUGH
    dataset.geometry.known_stations()  # its own field, not ``field``, names a missing geometry
    plant = load_plant(resolve_model(model, None if rough else params))
    names = plant.parameters().names
    prior = {name: value for name, value in ROUGH_PRIOR.items() if name in names} if rough else {}
    try:
        return dataset_model(dataset, None if rough else params, spec, prior, plant)
    except (ValueError, KeyError) as error:
        message = error.args[0] if error.args else str(error)
        raise FieldError(field, str(message)) from None
