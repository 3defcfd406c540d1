"""Which model a tool runs: the built-in plants by name, and a researcher's own by where it is.

A model is named by a *spec*: a built-in name (``dynamic``, ``kinematic``), a file and a class
(``path/to/my_model.py:MyModel``, loaded from that file by path) or an importable module and a
class (``my_package.models:MyModel``, for a model installed as a package). The spec is what a
parameter YAML stores under ``model:`` and what ``--model`` takes, and a plant pickles as its
spec, so a model from a file crosses into worker processes. Nothing here imports a user module
by name: the module comes from the spec given at run time.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import sys
from pathlib import Path

from crs_core.errors import FieldError
from crs_core.model.bicycle import DynamicBicycle
from crs_core.model.kinematic import KinematicBicycle
from crs_core.model.plant import Plant
from crs_core.yaml_io import mapping_in_file

#: The built-in models by name; the first is the default.
BUILT_IN: dict[str, type[Plant]] = {"dynamic": DynamicBicycle, "kinematic": KinematicBicycle}
DEFAULT_MODEL = "dynamic"


def load_plant(spec: str | Plant | None, field: str = "--model") -> Plant:
    """The plant a spec names (the module docstring); a plant is returned as it is, None is the
    default. Errors are one line naming ``field``."""
    if isinstance(spec, Plant):
        try:
            spec.validate()
        except FieldError as error:
            raise FieldError(field, str(error)) from None
        return spec
    text = DEFAULT_MODEL if spec is None else str(spec).strip()
    if text in BUILT_IN:
        plant: Plant = BUILT_IN[text]()
    elif ":" in text:
        plant = _plant_from_location(text, field)
    else:
        known = ", ".join(BUILT_IN)
        raise FieldError(field, f"unknown model {text!r} (built in: {known}; or FILE.py:CLASS)")
    try:
        plant.validate()
    except FieldError as error:
        raise FieldError(field, f"{text}: {error}") from None
    plant.spec = _canonical(text)
    return plant


def plant_spec(plant: Plant) -> str:
    """The spec that loads ``plant`` again (its built-in name, file or module and class)."""
    if plant.spec:
        return plant.spec
    if BUILT_IN.get(plant.name) is type(plant):
        return plant.name
    return f"{type(plant).__module__}:{type(plant).__qualname__}"


def model_in_file(path: str | Path) -> str | None:
    """The model spec a parameter YAML names under ``model:`` (None when it names none or the
    file cannot be read: the parameter loader says what is wrong with it)."""
    value = mapping_in_file(path).get("model")
    if value is None:
        return None
    if not isinstance(value, str) or not value.strip():
        raise FieldError(f"{path}: model", f"must be a model name or FILE.py:CLASS, got {value!r}")
    return value.strip()


def resolve_model(given: str | Plant | None, params_file: str | Path | None) -> str | Plant | None:
    """The model a tool runs: ``--model`` or the parameter file's ``model:``; a ``--model``
    that contradicts the file is refused in one line. None: the default."""
    stored = model_in_file(params_file) if params_file else None
    if given is None:
        return stored
    text = plant_spec(given) if isinstance(given, Plant) else given
    if stored is not None and _canonical(text) != _canonical(stored):
        raise FieldError(
            "--model", f"{text} contradicts {params_file}, whose parameters are of model {stored}"
        )
    return given


def _canonical(spec: str) -> str:
    """A spec with a file's path made absolute: it loads from anywhere, and two ways of
    writing it compare equal."""
    location, _, name = spec.rpartition(":")
    if location.endswith(".py"):
        return f"{Path(location).expanduser().resolve()}:{name}"
    return spec


def _plant_from_location(text: str, field: str) -> Plant:
    location, _, class_name = text.rpartition(":")
    if not location or not class_name.isidentifier():
        raise FieldError(field, f"{text!r} is not FILE.py:CLASS or MODULE:CLASS")
    if location.endswith(".py"):
        path = Path(location).expanduser().resolve()
        if not path.is_file():
            raise FieldError(field, f"{location}: no such file")
        digest = hashlib.sha256(str(path).encode()).hexdigest()[:12]
        module_name = f"crs_user_model_{path.stem}_{digest}"
        module = sys.modules.get(module_name)
        if module is None:
            loader_spec = importlib.util.spec_from_file_location(module_name, path)
            if loader_spec is None or loader_spec.loader is None:
                raise FieldError(field, f"{location}: cannot be loaded as a Python file")
            module = importlib.util.module_from_spec(loader_spec)
            sys.modules[module_name] = module
            try:
                loader_spec.loader.exec_module(module)
            except Exception as error:
                del sys.modules[module_name]
                raise FieldError(field, f"{location}: {type(error).__name__}: {error}") from None
    else:
        try:
            module = importlib.import_module(location)
        except ImportError as error:
            raise FieldError(field, f"{location}: {error}") from None
    cls = getattr(module, class_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Plant)):
        raise FieldError(field, f"{location} has no Plant subclass {class_name}")
    try:
        return cls()
    except Exception as error:
        raise FieldError(field, f"{class_name}(): {type(error).__name__}: {error}") from None
