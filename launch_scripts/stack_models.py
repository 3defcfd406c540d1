"""Which model each node of a launched stack runs.

A stack has two models: the *stack's* (its estimators' and controllers', ``crs launch
--model``; by default the one its ``--params`` file names under ``model:``, else the dynamic
bicycle) and the *cars'* (the simulated or emulated truth, ``--car-model``; by default the one
their ``--car-params`` file names, else the dynamic bicycle, never the stack's: a researcher's
simple model meets the real, dynamic car). The cars take the stack's parameter file only when it
is a file of their model (its ``model:``, the dynamic bicycle when it names none); otherwise they
run their model's defaults. Specs are passed to the nodes canonical (a model file's path made
absolute, :func:`~crs_core.model.plants.plant_spec`), so that a node started in another folder
loads the same file.
"""

from __future__ import annotations

from pathlib import Path

from crs_core.errors import FieldError

__all__ = ["car_model_and_parameters", "model_spec"]


def model_spec(given: str | None, params_file: Path | str | None, option: str = "--model") -> str:
    """The canonical spec of the model a node with parameter file ``params_file`` runs:
    ``given`` (a spec; None: the file's ``model:``, else ``dynamic``). A spec that does not load
    or contradicts the file is refused in one line naming ``option``."""
    from crs_core.model.plants import load_plant, plant_spec, resolve_model

    try:
        return plant_spec(load_plant(resolve_model(given, params_file), option))
    except FieldError as error:
        if error.field != "--model":  # the file's own model: is malformed: it names the file
            raise
        raise error.renamed(option) from None


def car_model_and_parameters(
    car_model: str | None,
    car_params: Path | None,
    params_file: Path | None,
) -> tuple[str, Path | None]:
    """The simulated or emulated cars' model (canonical spec) and parameter file: ``car_model``
    (None: ``car_params``' model, else ``dynamic``; never the stack's) and ``car_params``, else
    the stack's ``params_file`` when it is a file of that model, else None (the model's
    defaults). Errors name ``--car-model``."""
    model = model_spec(car_model, car_params, "--car-model")
    if car_params is not None:
        return model, car_params
    if params_file is not None and model_spec(None, params_file, "--params") == model:
        return model, params_file
    return model, None
