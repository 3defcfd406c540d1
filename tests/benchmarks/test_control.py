"""The control benchmark's Markdown tables (the docs' figures) from a hand-made result (the
benchmark itself races the MPCC for minutes and is not run here)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from benchmarks import control
from benchmarks.control import format_table

SOLVE = {"median": 3.1, "p95": 4.2, "p99": 5.0, "max": 7.7, "calls": 401}
RESULT = {
    "settings": {"solver": "osqp", "laps": 3, "blackout_s": 1.127},
    "solve_ms": SOLVE,
    "qp_iterations": {"median": 12.0},
    "peer": {
        "name": "IPOPT",
        "solve_ms": {"median": 40.04, "p95": 55.0, "p99": 61.0, "max": 1802.5, "calls": 134},
        "iterations_median": 9.0,
        "converged_fraction": 1.0,
        "first_command_difference_median": 0.00412,
    },
    "speedup_median": 12.9,
    "fallbacks": 0,
    "stops": 1,
    "qp_solvers": [
        {
            "solver": "osqp",
            "solve_ms": SOLVE,
            "qp_iterations_median": None,
            "laps": 2,
            "lap_times_s": [8.123, 8.0],
            "controller_modes": {"solved": 400, "stop": 1},
        },
        {
            "solver": "qrqp",
            "solve_ms": SOLVE,
            "qp_iterations_median": 66.0,
            "laps": 2,
            "lap_times_s": [7.09, 7.1],
            "controller_modes": {"fallback": 160, "solved": 253},
        },
    ],
    "closed_loop": [
        {
            "state": "true",
            "blackout": False,
            "truth": "nominal",
            "laps": 2,
            "lap_times_s": [8.125, 8.0],
            "mean_lap_s": 8.0625,
            "boundary_violations": 0,
            "max_contouring_error_m": 0.03,
            "max_outside_m": -0.052,
            "max_speed_mps": 2.61,
            "mean_speed_mps": 1.58,
            "solve_ms": SOLVE,
        },
        {
            "state": "mhe",
            "blackout": True,
            "truth": "simulator",
            "laps": 0,
            "lap_times_s": [],
            "mean_lap_s": None,
            "boundary_violations": 2,
            "max_contouring_error_m": 0.2,
            "max_outside_m": 0.01,
            "estimation_rmse": {"x": 0.003, "y": 0.004, "position": 0.005},
            "solve_ms": SOLVE,
        },
    ],
    "mhe_vs_true_lap_ratio": 1.0006,
}


def _row(table: str, first_cell: str) -> list[str]:
    (line,) = [line for line in table.splitlines() if line.startswith(f"| {first_cell} |")]
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_the_solver_the_peer_and_the_closed_loop_rows() -> None:
    table = format_table(RESULT)
    assert table.startswith(
        "Solve time: the whole `Mpcc.__call__` over a 3-lap race on the true state (401 calls, "
        "the first, cold one left out; the peer on 134 of the race's problems):"
    )
    assert _row(table, "MPCC, real-time iteration in CasADi + OSQP") == [
        "MPCC, real-time iteration in CasADi + OSQP", "3.1", "4.2", "5", "7.7", "12 (QP)",
    ]  # fmt: skip
    assert _row(table, "peer: IPOPT") == [
        "peer: IPOPT", "40", "55", "61", "1802", "9 (NLP), 100% converged",
    ]  # fmt: skip
    assert "**12.9× faster** (medians); 0 fallbacks, 1 stops in the race." in table
    assert "first command is 0.0041 (median;" in table
    # OSQP does not report its iterations; a failed solve falls back to the shifted plan
    assert _row(table, "OSQP (ADMM, eps 10⁻⁸, polished)")[1:] == [
        "3.1", "5", "(not reported)", "8.12, 8.00", "0 of 401",
    ]  # fmt: skip
    assert _row(table, "qrqp (CasADi active set)")[3:] == [
        "66", "7.09, 7.10", "160 of 413 (fallback: shifted plan)",
    ]  # fmt: skip
    # the closest approach to the edge is minus the largest excursion outside; the position
    # RMSE of the estimate is the run's (planar distance); from 1000 ms on, no exponent
    assert _row(table, "true") == [
        "true", "–", "nominal", "8.12, 8.00", "8.062 s", "0", "0.030 m", "0.052 m", "–",
        "3.1 / 5 ms",
    ]  # fmt: skip
    assert _row(table, "MHE") == [
        "MHE", "1.127 s per lap", "simulator", "–", "–", "2", "0.200 m", "-0.010 m", "5.0 mm",
        "3.1 / 5 ms",
    ]  # fmt: skip
    assert table.endswith(
        "MHE mean lap / true state's (no blackout): 1.0006; the first race: peak speed 2.6 m/s, "
        "mean 1.6 m/s."
    )
    # every table row has as many cells as its header (the escaped | of |lateral| aside)
    blocks = [b for b in table.split("\n\n") if b.startswith("|")]
    assert len(blocks) == 3
    for block in blocks:
        widths = {line.replace("\\|", "").count("|") for line in block.splitlines()}
        assert len(widths) == 1, block


class _Status:
    mode = "solved"
    qp_iterations = 8
    solve_time_s = 0.002


class _FakeMpcc:
    """What control_benchmark asks of an MPCC, without building one."""

    def __init__(self, track, settings=None, output="torque") -> None:
        self.settings = settings
        self.status = _Status()
        self.problem = self.p = self._v_lower = self._v_upper = self._half_width = None
        self._weights = None
        self.last_guess = (np.zeros(3), np.zeros((2, 4)), np.zeros(2))

    def reset(self) -> None:
        pass

    def __call__(self, x) -> np.ndarray:
        return np.zeros(2)

    def _solve_qp(self, Z, V, refs) -> SimpleNamespace:
        return SimpleNamespace(success=True, V=V + 0.01)


class _FakePeer:
    def __init__(self, problem) -> None:
        pass

    def solve(self, Z, V, refs, *settings) -> tuple:
        return None, V, True, 14


class _FakeRti:
    def iterate(self, Z, V, refs, *settings) -> SimpleNamespace:
        return SimpleNamespace(success=True, V=V + 0.001)


class _FakeRacer:
    def __init__(self, mpcc) -> None:
        self.rti = _FakeRti()
        self.solve_times = [0.01, 0.001, 0.001, 0.0015]
        self.call_times = [0.02, 0.0012, 0.0012, 0.0017]
        self.statuses = [0, 0, 0, 0]
        self.qp_iterations = [9, 8, 8, 7]

    def reset(self) -> None:
        pass

    def __call__(self, x) -> np.ndarray:
        self.solve_times.append(0.001)
        return np.zeros(2)

    def stop(self, x=None, reason="") -> np.ndarray:
        return np.zeros(2)


class _FakeRace:
    truth = np.zeros((6, 6))

    def summary(self) -> dict[str, Any]:
        return {
            "laps": 2,
            "lap_times_s": [6.8, 6.5],
            "mean_lap_s": 6.65,
            "boundary_violations": 0,
            "max_outside_m": -0.02,
            "max_contouring_error_m": 0.17,
            "max_speed_mps": 2.6,
            "mean_speed_mps": 1.6,
            "controller_modes": {"solved": 6},
        }

    lateral_error = np.array([0.03, -0.04])


def test_the_benchmark_runs_to_its_table_on_fake_races(monkeypatch: pytest.MonkeyPatch) -> None:
    """The whole of control_benchmark with its MPCC, peer and races replaced: a name clash there
    (a local ``summary`` hiding the statistics function) once failed it after minutes of
    racing."""

    def race(mpcc, track, *, after_call=None, **options) -> tuple[_FakeRace, np.ndarray]:
        for _ in range(6):
            if after_call is not None:
                after_call()
        return _FakeRace(), np.full(6, 0.002)

    monkeypatch.setattr(control, "Mpcc", _FakeMpcc)
    monkeypatch.setattr(control, "IpoptMpcc", _FakePeer)
    monkeypatch.setattr(control, "load_demo_track", lambda: None)
    monkeypatch.setattr(control, "_race", race)
    monkeypatch.setattr(control, "AcadosRacer", _FakeRacer)
    monkeypatch.setattr(control, "run_closed_loop", lambda *args, **options: _FakeRace())
    result = control.control_benchmark(laps=2, peer_every=3)
    assert result["solve_ms"]["median"] == 2.0 and result["qp_iterations"]["median"] == 8
    assert result["peer"]["iterations_median"] == 14 and result["speedup_median"] >= 0
    solvers = [row["solver"] for row in result["qp_solvers"]]
    assert solvers == ["native", "hpipm", "qpoases", "osqp", "qrqp"]
    assert len(result["closed_loop"]) == 6 and result["mhe_vs_true_lap_ratio"] == 1.0
    table = format_table(result)
    assert (
        "| MPCC, real-time iteration in one compiled call (HPIPM) | 2 | 2 | 2 | 2 | 8 (QP) |"
        in table
    )
    # acados: its own race (solve() only), ours with its iteration, the ratios of the medians
    acados = result["peers"]["acados"]
    assert acados["solve_ms"]["median"] == 1.0 and acados["solve_ms"]["calls"] == 3
    assert acados["contouring_error_rms_m"] == pytest.approx(0.0354, abs=1e-4)
    assert acados["first_command_difference_to_ours"]["median"] == pytest.approx(0.009)
    assert result["acados_backend"]["solve_ms"]["median"] == 2.0
    assert result["ratios"] == {"acados/ours": 0.5, "acados/ours_acados_backend": 0.5}
    assert acados["lockstep"]["ours"]["median"] == 2.0 and acados["lockstep"]["ours"]["calls"] == 5
    assert (
        "**acados / ours = 0.5** (medians, timed in lockstep, each on the states of its own race"
        in (table)
    )
    assert "acados's whole call from Python (state, shift, path, data in and out): 1.2 ms" in table
    assert _row(table, "acados SQP-RTI + HPIPM, own race, solve() only")[1:] == [
        "1", "1.45", "1.49", "1.5", "6.80, 6.50", "6.650 s", "35.4 mm", "0.170 m", "0",
    ]  # fmt: skip
