"""The stack against an emulated car behind each Wi-Fi-like link preset (``crs launch car
--emulate --link PRESET``): a short race each, judged on the emulator's truth.

The presets are :mod:`chronos_bridge.impairment`'s: ``typical`` (2 % loss, 4 ms + |N(0, 3 ms)|),
``bad`` (8 % loss in bursts, 15 ms + |N(0, 10 ms)| that reorders, 1 % duplicates) and ``outages``
(300 ms every 5 s). The full matrix (presets x CPU load x cars, 40 s races) is ``crs bench link``.
"""

from __future__ import annotations

import numpy as np
import pytest

from crs_core.track import load_demo_track
from launch_scripts.car_stack import EmulatedLink, run_car_stack
from launch_scripts.link_benchmark import car_figures

pytestmark = pytest.mark.integration

DOMAINS = {"typical": 131, "bad": 132, "outages": 133}
PORTS = {"typical": (21411, 21511), "bad": (21421, 21521), "outages": (21431, 21531)}


def _race(tmp_path, preset: str, duration: float) -> tuple[dict, dict]:
    out = tmp_path / preset
    report = run_car_stack(
        1,
        "mhe",
        duration,
        out,
        True,
        domain_id=DOMAINS[preset],
        ports=PORTS[preset],
        record="estimates",
        link=EmulatedLink(both=preset, seed=7),
    )
    assert report["node_deaths"] == []
    car = report["cars"]["car1"]
    return car, car_figures(car, out, 1, load_demo_track())


def test_typical_wifi_races_clean_laps(tmp_path, warm_codegen) -> None:
    car, figures = _race(tmp_path, "typical", 22.0)
    assert figures["laps"] >= 2, figures
    assert figures["off_track"]["seconds"] == 0.0, figures["off_track"]
    assert figures["motor_cutoffs"] == 0
    assert car["estimation_rmse"]["x"] < 0.01 and car["estimation_rmse"]["y"] < 0.01
    assert car["estimator_reinitializations"] == 0
    link = car["bridge_diagnostics"]
    assert link["counts"]["car_state"] > 3000  # 250 Hz less 2 % loss


def test_bad_wifi_still_races_and_the_bridge_sees_the_disorder(tmp_path, warm_codegen) -> None:
    car, figures = _race(tmp_path, "bad", 22.0)
    assert figures["laps"] >= 1, figures
    assert figures["off_track"]["seconds"] == 0.0, figures["off_track"]
    assert car["estimation_rmse"]["x"] < 0.02 and car["estimation_rmse"]["y"] < 0.02
    diagnostics = car["bridge_diagnostics"]
    assert diagnostics["arrival"]["reordered"] > 100  # datagrams overtaken on the way
    assert diagnostics["counts"]["duplicate"] > 0  # dropped, never converted twice


def test_each_outage_cuts_the_motors_and_the_car_races_again_within_a_second(
    tmp_path, warm_codegen
) -> None:
    car, figures = _race(tmp_path, "outages", 22.0)
    evaluated = [o for o in figures["outages"] if o["evaluated"]]
    assert len(evaluated) >= 2, figures["outages"]
    for outage in evaluated:
        assert outage["motors_cut"], outage  # 300 ms without a reference: the car stops
        assert outage["recovery_s"] is not None and outage["recovery_s"] <= 1.0, outage
    assert figures["off_track"]["seconds"] == 0.0, figures["off_track"]
    assert figures["laps"] >= 1
    assert np.isfinite(car["estimation_rmse"]["x"])
