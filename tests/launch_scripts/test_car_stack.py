"""The car stack's node specs (``crs launch car``)."""

from __future__ import annotations

import argparse

import pytest

from chronos_bridge.impairment import LinkSettings, parse_link


def test_crs_launch_car_passes_the_link_to_each_emulator_with_its_own_seed(tmp_path) -> None:
    from chronos_bridge.emulator_process import add_arguments, options
    from launch_scripts.car_stack import EmulatedLink, car_nodes
    from launch_scripts.sim_stack import StackOptions

    ekf = StackOptions("ekf")
    link = EmulatedLink(both="typical", down="bad,outage=300ms,outage_every=5s", seed=7)
    nodes = car_nodes(2, ekf, tmp_path / "bag", tmp_path, True, link=link)
    emulators = [node for node in nodes if node.name == "emulator"]
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    parsed = [options(parser.parse_args(node.arguments)) for node in emulators]
    assert [p["link_seed"] for p in parsed] == [8, 9]
    expected = parse_link("typical", down="bad,outage=300ms,outage_every=5s")
    assert all(p["link"] == expected for p in parsed)
    default = car_nodes(2, StackOptions("ekf", seed=3), tmp_path / "bag", tmp_path, True)
    parsed = [options(parser.parse_args(n.arguments)) for n in default if n.name == "emulator"]
    clean = LinkSettings()
    assert [(p["link_seed"], p["link"]) for p in parsed] == [(4, clean), (5, clean)]
    with pytest.raises(ValueError, match=r"^--link-up: loss: "):
        car_nodes(1, ekf, tmp_path / "bag", tmp_path, True, link=EmulatedLink(up="loss=2"))
    with pytest.raises(ValueError, match=r"^--link: only for emulated cars"):
        car_nodes(1, ekf, tmp_path, tmp_path, False, ["10.0.0.2"], link=EmulatedLink("bad"))


def test_emulated_cars_are_their_own_truth_or_the_stacks_model(tmp_path) -> None:
    """--car-params / --car-effect reach every emulator (as parsed by the emulator itself);
    without them the emulators are the stack's --params; a real car takes neither."""
    from chronos_bridge.emulator_process import add_arguments, options
    from crs_core.model.effects import parse_effect
    from launch_scripts.car_stack import car_nodes
    from launch_scripts.sim_stack import CarTruth, StackOptions

    stack, truth = tmp_path / "model.yaml", tmp_path / "truth.yaml"
    stack.write_text("parameters:\n  m: 0.25\n")
    truth.write_text("parameters:\n  m: 0.3\n  Df: 0.55\n")
    parser = argparse.ArgumentParser()
    add_arguments(parser)

    def emulated(**kwargs) -> list:
        stack_options = StackOptions("ekf", params_file=stack, **kwargs)
        nodes = car_nodes(2, stack_options, tmp_path / "bag", tmp_path, True)
        return [
            options(parser.parse_args(n.arguments))["model"] for n in nodes if n.name == "emulator"
        ]

    own = emulated(car=CarTruth(truth, (parse_effect("steering_lag=0.06"),)))
    assert [m.parameters.value("m") for m in own] == [0.3, 0.3]
    assert [e.name for e in own[0].effects] == ["steering_lag"]
    assert own[0].parameters.value("tau_steer") == 0.06
    assert [m.parameters.value("m") for m in emulated()] == [0.25, 0.25]
    estimator = next(
        n
        for n in car_nodes(1, StackOptions("ekf", params_file=stack), tmp_path, tmp_path, True)
        if n.name == "estimator"
    )
    assert estimator.parameters["params_file"] == str(stack.resolve())
    with pytest.raises(ValueError, match=r"^--car-params: only for emulated cars"):
        real = StackOptions("ekf", car=CarTruth(truth))
        car_nodes(1, real, tmp_path, tmp_path, False, ["10.0.0.2"])


def test_the_emulated_cars_are_of_their_own_model(tmp_path) -> None:
    """The emulators get the cars' model (``--model``, as the emulator parses it: dynamic by
    default, not the stack's), the estimators and controllers the stack's."""
    from chronos_bridge.emulator_process import add_arguments, options
    from launch_scripts.car_stack import car_nodes
    from launch_scripts.sim_stack import CarTruth, StackOptions

    parser = argparse.ArgumentParser()
    add_arguments(parser)

    def plants(stack_options: StackOptions) -> dict[str, str]:
        nodes = car_nodes(1, stack_options, tmp_path / "bag", tmp_path, True)
        pipeline = ("estimator", "controller")
        out = {n.name: n.parameters["model"] for n in nodes if n.name in pipeline}
        (emulator,) = [n for n in nodes if n.name == "emulator"]
        out["emulator"] = options(parser.parse_args(emulator.arguments))["model"].plant.name
        return out

    assert plants(StackOptions("ekf", model="kinematic")) == {
        "estimator": "kinematic",
        "controller": "kinematic",
        "emulator": "dynamic",
    }
    told = plants(StackOptions("ekf", car=CarTruth(model="kinematic")))
    assert told == {"estimator": "dynamic", "controller": "dynamic", "emulator": "kinematic"}
    with pytest.raises(ValueError, match=r"^--car-params: only for emulated cars"):
        car_nodes(
            1,
            StackOptions("ekf", car=CarTruth(model="kinematic")),
            tmp_path,
            tmp_path,
            False,
            ["10.0.0.2"],
        )
