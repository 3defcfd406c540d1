"""The car stack's node specs (``crs launch car``)."""

from __future__ import annotations

import argparse

import pytest

from chronos_bridge.impairment import LinkSettings, parse_link


def test_crs_launch_car_passes_the_link_to_each_emulator_with_its_own_seed(tmp_path) -> None:
    from chronos_bridge.emulator_process import add_arguments, options
    from launch_scripts.car_stack import EmulatedLink, car_nodes

    link = EmulatedLink(both="typical", down="bad,outage=300ms,outage_every=5s", seed=7)
    nodes = car_nodes(2, "ekf", tmp_path / "bag", tmp_path, True, link=link)
    emulators = [node for node in nodes if node.name == "emulator"]
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    parsed = [options(parser.parse_args(node.arguments)) for node in emulators]
    assert [p["link_seed"] for p in parsed] == [8, 9]
    expected = parse_link("typical", down="bad,outage=300ms,outage_every=5s")
    assert all(p["link"] == expected for p in parsed)
    default = car_nodes(2, "ekf", tmp_path / "bag", tmp_path, True, seed=3)
    parsed = [options(parser.parse_args(n.arguments)) for n in default if n.name == "emulator"]
    clean = LinkSettings()
    assert [(p["link_seed"], p["link"]) for p in parsed] == [(4, clean), (5, clean)]
    with pytest.raises(ValueError, match=r"^--link-up: loss: "):
        car_nodes(1, "ekf", tmp_path / "bag", tmp_path, True, link=EmulatedLink(up="loss=2"))
    with pytest.raises(ValueError, match=r"^--link: only for emulated cars"):
        car_nodes(1, "ekf", tmp_path, tmp_path, False, ["10.0.0.2"], link=EmulatedLink("bad"))
