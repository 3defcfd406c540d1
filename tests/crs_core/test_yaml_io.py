"""load_yaml reads what yaml.safe_load reads, and refuses what it refuses."""

from __future__ import annotations

import pytest
import yaml

from crs_core.track.yaml_file import DEMO_TRACK_PATH
from crs_core.yaml_io import load_yaml


def test_the_demo_track_reads_as_the_safe_loader_reads_it() -> None:
    text = DEMO_TRACK_PATH.read_text()
    assert load_yaml(text) == yaml.safe_load(text)


def test_a_python_object_tag_is_refused() -> None:
    with pytest.raises(yaml.YAMLError):
        load_yaml("!!python/object/apply:os.system ['true']")


def test_invalid_yaml_raises_the_yaml_error() -> None:
    with pytest.raises(yaml.YAMLError):
        load_yaml("a: [1, 2")
