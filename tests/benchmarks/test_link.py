"""The link benchmark's metrics, targets, table and free ports (no stack is started here)."""

from __future__ import annotations

import json
import math
import socket
from typing import Any

import numpy as np
import pytest

from benchmarks.link import (
    driving_references,
    format_table,
    free_ports,
    outage_recovery,
    outage_windows,
    summarise,
)
from crs_core.track import Track
from sim.closed_loop import CAR_LENGTH, CAR_WIDTH, off_track

WIDTH = 0.46
RADIUS = 1.0
STRAIGHT = 2.0


def stadium() -> Track:
    """Counter-clockwise stadium: the straight y = -1 (x from 0 to 2), a half circle of radius
    1 about (2, 0), the straight y = 1 back, a half circle about (0, 0); 0.46 m wide."""
    length = 2 * STRAIGHT + 2 * math.pi * RADIUS
    s = np.arange(0.0, length - 1e-9, 0.005)
    x, y, heading, curvature = (np.zeros_like(s) for _ in range(4))
    arc = math.pi * RADIUS
    for k, sk in enumerate(s):
        if sk < STRAIGHT:
            x[k], y[k], heading[k] = sk, -RADIUS, 0.0
        elif sk < STRAIGHT + arc:
            a = -math.pi / 2 + (sk - STRAIGHT) / RADIUS
            x[k], y[k], heading[k] = STRAIGHT + RADIUS * math.cos(a), RADIUS * math.sin(a), a
            heading[k] += math.pi / 2
            curvature[k] = 1 / RADIUS
        elif sk < 2 * STRAIGHT + arc:
            x[k], y[k], heading[k] = STRAIGHT - (sk - STRAIGHT - arc), RADIUS, math.pi
        else:
            a = math.pi / 2 + (sk - 2 * STRAIGHT - arc) / RADIUS
            x[k], y[k], heading[k] = RADIUS * math.cos(a), RADIUS * math.sin(a), a + math.pi / 2
            curvature[k] = 1 / RADIUS
    return Track(x, y, heading, s, curvature, length, WIDTH, 0.0, -RADIUS, 0.0)


@pytest.fixture(scope="module")
def track() -> Track:
    return stadium()


def test_off_track_on_a_straight(track: Track):
    """On the straight, 0.25 m right of the centreline for 1.5 s: the footprint's outer side
    is 0.25 + W/2 - 0.23 = 0.055 m outside for exactly those samples; 0.19 m stays inside."""
    t = np.arange(0.0, 6.0, 0.01)
    lateral = np.where((t >= 2.0 - 1e-9) & (t < 3.5 - 1e-9), -0.25, 0.0)
    lateral[(t >= 4.0) & (t < 5.0)] = -0.19
    x = np.column_stack([0.3 + 0.2 * t, -RADIUS + lateral, np.zeros_like(t)])
    result = off_track(t, x, track)
    assert result["seconds"] == pytest.approx(1.5, abs=1e-6)
    assert result["max_outside_m"] == pytest.approx(0.25 + CAR_WIDTH / 2 - WIDTH / 2, abs=1e-4)
    assert result["episodes"] == 1


def test_off_track_in_a_corner_counts_the_front_corner(track: Track):
    """On the half circle about (2, 0), tangent, 0.194 m outward: the centre and the sides are
    inside (0.194 + W/2 = 0.229 < 0.23), but the outer front and rear corners reach
    sqrt((1.229)^2 + (L/2)^2) - 1 - 0.23 = 0.46 mm outside. 0.9 s of it."""
    t = np.arange(0.0, 3.0, 0.01)
    angle = -1.0 + 0.6 * t  # rad on the circle, within the half circle (-pi/2, pi/2)
    offset = np.where((t >= 1.0 - 1e-9) & (t < 1.9 - 1e-9), 0.194, 0.0)
    r = RADIUS + offset
    x = np.column_stack([STRAIGHT + r * np.cos(angle), r * np.sin(angle), angle + math.pi / 2])
    result = off_track(t, x, track)
    expected = math.hypot(RADIUS + 0.194 + CAR_WIDTH / 2, CAR_LENGTH / 2) - RADIUS - WIDTH / 2
    assert result["max_outside_m"] == pytest.approx(expected, abs=1e-4)
    assert result["seconds"] == pytest.approx(0.9, abs=1e-6)
    assert off_track(t[:90], x[:90], track) == {
        "seconds": 0.0,
        "max_outside_m": 0.0,
        "episodes": 0,
    }


def test_outage_windows_merge_both_directions():
    log = {
        "link_up_outage_start_t": np.array([5.0, 10.0]),
        "link_up_outage_end_t": np.array([5.3, 10.3]),
        "link_down_outage_start_t": np.array([5.1, 20.0]),
        "link_down_outage_end_t": np.array([5.4, 20.3]),
    }
    np.testing.assert_allclose(outage_windows(log), [[5.0, 5.4], [10.0, 10.3], [20.0, 20.3]])
    assert outage_windows({}).shape == (0, 2)


def test_driving_references_follow_the_newest_input_before_the_send_stamp():
    input_t = np.array([0.0, 1.0, 2.0])
    input_u = np.array([[0.1, 0.5], [0.0, 0.0], [0.2, 0.3]])
    sent = np.array([0.5, 1.5, 2.5, np.nan, -1.0])
    assert driving_references(sent, input_t, input_u).tolist() == [True, False, True, True, True]
    assert driving_references(sent, np.zeros(0), np.zeros((0, 2))).all()


def synthetic_outage() -> dict[str, Any]:
    """Racing at 2 m/s from 2 s; the link out [5.0, 5.3): motors cut at 5.2, the car coasts
    down to 0.2 m/s; references come back at 5.3 but are stop commands until 5.6; the car
    accelerates from 5.8 and passes 0.5 m/s at 5.85 s. A window at [1, 1.3) before it raced, and
    one at [9.5, 9.8) after which no reference arrives before the run ends at 10 s."""
    t = np.arange(0.0, 10.0, 0.004)
    speed = np.interp(t, [0, 1.9, 2.0, 5.2, 5.7, 5.8, 6.1, 10], [0, 0, 2, 2, 0.2, 0.2, 2, 2])
    read = np.arange(2.0, 10.0, 1 / 30)
    read = read[~((read > 4.98) & (read < 5.31)) & (read < 9.5)]
    driving = ~((read >= 5.3) & (read < 5.6))
    windows = np.array([[1.0, 1.3], [5.0, 5.3], [9.5, 9.8]])
    return {"t": t, "speed": speed, "read": read, "driving": driving, "windows": windows}


def test_outage_recovery_on_a_synthetic_speed_trace():
    case = synthetic_outage()
    pause = np.array([5.2])
    result = outage_recovery(
        case["windows"], case["t"], case["speed"], pause, case["read"], case["driving"]
    )
    before, outage, late = result
    assert not before["racing_before"] and not before["evaluated"]
    assert outage["racing_before"] and outage["motors_cut"] and outage["evaluated"]
    assert outage["recovery_s"] == pytest.approx(5.85 - 5.3, abs=0.005)
    assert late["racing_before"] and not late["motors_cut"]
    assert late["recovery_s"] is None and not late["evaluated"]  # 10 s < 9.8 + 1 s
    # without knowing the stop commands the coasting car still does not count: its speed does
    # not stay above 0.5 m/s
    coasting = outage_recovery(case["windows"][1:2], case["t"], case["speed"], pause, case["read"])
    assert coasting[0]["recovery_s"] == pytest.approx(5.85 - 5.3, abs=0.005)


def test_a_car_that_coasts_after_the_return_and_stops_is_not_racing_again():
    t = np.arange(0.0, 8.0, 0.004)
    speed = np.interp(t, [0, 1, 5.0, 6.0, 8.0], [2, 2, 2, 0.0, 0.0])  # rolls to a stand
    read = np.arange(1.0, 8.0, 1 / 30)
    result = outage_recovery(np.array([[4.7, 5.0]]), t, speed, np.array([4.9]), read)
    assert result[0]["racing_before"] and result[0]["recovery_s"] is None


def car(**changes: Any) -> dict[str, Any]:
    figures = {
        "laps": 5,
        "lap_times_s": [8.0, 7.0, 7.0, 7.0, 7.0],
        "mean_lap_s": 7.0,
        "off_track": {"seconds": 0.0, "max_outside_m": 0.0, "episodes": 0},
        "motor_cutoffs": 0,
        "rmse": {"x": 0.004, "y": 0.005, "yaw": 0.012},
        "qp_failure_seconds": 0,
        "reinitializations": 0,
        "latency_ms": {"median": 31.0, "p95": 42.5},
        "outages": [],
    }
    return {**figures, **changes}


def row(preset: str, load: int = 1, cars: int = 1, **changes: Any) -> dict[str, Any]:
    return {
        "preset": preset,
        "load": load,
        "cars": cars,
        "folder": f"/tmp/{preset}",
        "per_car": {f"car{i}": car(**changes) for i in range(1, cars + 1)},
        "cpu_percent_running": {"car1/estimator": 40.0, "car1/controller": 35.5},
        "node_deaths": [],
    }


def window(cut: bool, recovery: float | None, evaluated: bool = True) -> dict[str, Any]:
    return {
        "start": 5.0,
        "end": 5.3,
        "racing_before": True,
        "motors_cut": cut,
        "recovery_s": recovery,
        "evaluated": evaluated,
    }


def test_targets_per_preset():
    slow = [8.0, 7.4, 7.4, 7.4]  # flying laps 7.4 s: 5.7 % slower than 7.0 s
    rows = [
        row("clean"),
        row("typical"),
        row("typical", lap_times_s=slow),
        row("typical", load=2, motor_cutoffs=1),
        row("typical", cars=2),  # no clean run with 2 cars
        row("bad", laps=2),
        row("bad", off_track={"seconds": 0.3, "max_outside_m": 0.01, "episodes": 1}),
        row("outages", outages=[window(True, 0.4), window(True, 0.9)]),
        row("outages", outages=[window(True, 1.2)]),
        row("outages", outages=[window(False, 0.4), window(False, None, evaluated=False)]),
        row("outages", outages=[window(False, None, evaluated=False)]),
    ]
    summarise(rows)
    verdicts = [r["targets"].get("all") for r in rows]
    assert rows[0]["targets"] == {}
    assert verdicts[1:] == [True, False, False, None, False, False, True, False, False, None]
    assert rows[2]["lap_time_ratio"] == pytest.approx(7.4 / 7.0, abs=1e-3)
    assert rows[2]["targets"]["lap_within_5pct_of_clean"] is False
    assert rows[3]["targets"]["no_motor_cutoffs"] is False
    assert [r["issue_target"] for r in rows[:5]] == [False, True, True, False, True]


def test_format_table_is_markdown_one_row_per_run():
    rows = [
        row("clean", load=0, cars=2),
        row("outages", load=0, cars=2, outages=[window(True, 0.4), window(True, 0.9)]),
    ]
    summarise(rows)
    result = {"duration_s": 40.0, "estimator": "mhe", "controller": "mpcc", "seed": 0}
    text = format_table({**result, "runs": rows})
    lines = text.splitlines()
    assert lines[0].startswith("| preset | busy loops | cars | laps |")
    assert set(lines[1].replace("|", "")) == {"-"}
    header = [c.strip() for c in lines[0].strip("|").split("|")]
    cells = [c.strip() for c in lines[3].strip("|").split("|")]
    assert len(cells) == len(header)
    assert cells[:4] == ["outages", "0", "2", "5/5"]
    assert cells[header.index("lap / clean")] == "1.000"
    assert cells[header.index("RMSE x/y [mm] / yaw [mrad]")] == "4/5/12"
    assert cells[header.index("sensor→command med/p95 [ms]")] == "31/42"
    assert cells[header.index("outages: cut, max return→racing")] == "4/4 cut, max 0.90 s"
    assert cells[-1] == "met"
    assert "40 s races, MHE + MPCC, seed 0" in text
    json.dumps({**result, "runs": rows})  # JSON-ready


def test_free_ports_skips_ports_in_use():
    host, emulator = free_ports(2)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", emulator + 1))
        other = free_ports(2)
    assert other != (host, emulator) and other[0] - host == other[1] - emulator
    assert (other[0] - host) % 200 == 0
