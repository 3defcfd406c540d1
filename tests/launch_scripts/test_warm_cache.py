"""warm_compile_cache builds a stack's functions once per process and what they depend on."""

from __future__ import annotations

import yaml

from launch_scripts.warm_cache import warm_compile_cache


def test_a_second_call_for_the_same_stack_builds_nothing(tmp_path, capsys) -> None:
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump({"parameters": {"Cm1": 0.3}}))
    assert warm_compile_cache("ekf", "path", "torque", params) > 0
    assert warm_compile_cache("ekf", "path", "torque", params) == 0.0
    assert "warmed earlier in this process" in capsys.readouterr().out
    # other parameter values in the same file: built again (the cache decides what compiles)
    params.write_text(yaml.safe_dump({"parameters": {"Cm1": 0.31}}))
    assert warm_compile_cache("ekf", "path", "torque", params) > 0
    assert (
        warm_compile_cache("ekf", "path", "torque", params, car_effects=(("gyro_bias", None, 0.1),))
        > 0
    )


def test_it_builds_the_models_the_stack_runs(monkeypatch, capsys) -> None:
    """The estimator's (and controller's) model is the stack's ``model``, the simulated car's
    its ``car_model``; each pair of models is a stack of its own."""
    import chronos_bridge.emulator
    import crs_core.estimation

    built: list[tuple[str, str]] = []
    monkeypatch.setattr(
        crs_core.estimation,
        "make_estimator",
        lambda kind, sensors, model, settings: built.append(("estimator", model.plant.name)),
    )
    monkeypatch.setattr(
        chronos_bridge.emulator,
        "CarEmulator",
        lambda model: built.append(("car", model.plant.name)),
    )
    warm_compile_cache("ekf", "path", "torque", model="kinematic", label="[a]")
    assert built == [("estimator", "kinematic"), ("car", "dynamic")]
    built.clear()
    warm_compile_cache("ekf", "path", "torque", model="kinematic", car_model="kinematic")
    assert built == [("estimator", "kinematic"), ("car", "kinematic")]
    capsys.readouterr()
