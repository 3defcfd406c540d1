"""acados's real-time iteration of the MPCC's problem (``MpccSettings(solver="acados")``): it
races, it agrees with ours on the same problem, it is built once, and casadi stays the pinned
one with IPOPT beside it."""

from __future__ import annotations

import subprocess
import sys
import time

import casadi as ca
import numpy as np
import pytest

from crs_core import acados_support
from crs_core.control.mpcc import Mpcc
from crs_core.control.mpcc_acados import AcadosRti
from crs_core.control.mpcc_problem import MpccSettings
from crs_core.model import CarModel
from sim.closed_loop import run_closed_loop
from sim.sensors import SensorSuite
from sim.simulator import Simulator

try:
    acados_support.acados_template()
except acados_support.AcadosUnavailable as error:  # pragma: no cover - set-up dependent
    pytest.skip(f"acados unavailable: {error}", allow_module_level=True)


@pytest.fixture(scope="module")
def mpcc(track) -> Mpcc:
    """Our MPCC with acados's iteration (the solver built, or loaded from the cache)."""
    return Mpcc(track, settings=MpccSettings(solver="acados"))


@pytest.fixture(scope="module")
def reference(track) -> Mpcc:
    """Our MPCC with its own iteration in CasADi (CasADi's HPIPM): the reference."""
    return Mpcc(track, settings=MpccSettings(solver="hpipm"))


def test_the_acados_mpcc_races_a_lap_on_the_true_state(mpcc: Mpcc, track) -> None:
    result = run_closed_loop(
        Simulator(CarModel(), SensorSuite(), seed=5),
        track,
        lambda t, x: mpcc(x),
        mpcc.stop,
        30.0,
        laps=1,
        max_duration=12.0,
        status_of=lambda: mpcc.status.mode,
    )
    summary = result.summary()
    assert summary["laps"] == 1
    assert summary["boundary_violations"] == 0
    assert summary["max_contouring_error_m"] < track.width / 2
    assert summary["controller_modes"] == {"solved": result.t.size}
    assert np.all(np.isfinite(result.u))


def test_its_first_command_agrees_with_our_iteration_on_the_same_problem(
    mpcc: Mpcc, reference: Mpcc, track
) -> None:
    """The same guess, path linearisation and bounds: acados's one SQP-RTI iteration and ours
    (CasADi, HPIPM) solve the same QP (measured: 4e-6 median, 1.5e-4 at most over 150
    problems of a race; the two HPIPMs stop at their own tolerances)."""
    reference.reset()
    x = track.start_state(1.0)
    differences = []
    for _ in range(12):
        u = reference(x)
        Z, V, refs = reference.last_guess
        ours = reference._solve_qp(Z, V, refs)
        theirs = mpcc._solve_qp(Z, V, refs)
        assert ours.success and theirs.success and theirs.violation <= 1e-6
        differences.append(np.max(np.abs(ours.V[0, :2] - theirs.V[0, :2])))
        assert np.max(np.abs(ours.Z - theirs.Z)) < 1e-2
        z = np.concatenate((x, [0.0, 0.0, 0.0, 0.0]))
        x = np.asarray(reference.problem.dynamics(z, np.r_[u, 1.0, 0.0], reference.p)).ravel()
        x = x[:6]
    assert max(differences) < 1e-3
    assert np.median(differences) < 1e-4


def test_the_solver_is_built_once_and_loaded_after(
    mpcc: Mpcc, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A second construction loads the compiled library: nothing is generated or built."""
    template = acados_support.acados_template()
    built = acados_support.solver_dir(mpcc._acados.name) / "built"
    library = built.parent / "c_generated_code" / f"libacados_ocp_solver_{mpcc._acados.name}.so"
    stamps = (built.stat().st_mtime_ns, library.stat().st_mtime_ns)

    def refuse(*args, **kwargs):
        raise AssertionError("acados generated or built the solver again")

    monkeypatch.setattr(template.AcadosOcpSolver, "generate", refuse)
    monkeypatch.setattr(template.AcadosOcpSolver, "build", refuse)
    started = time.perf_counter()
    again = AcadosRti(mpcc.problem)
    assert time.perf_counter() - started < 5.0
    assert again.name == mpcc._acados.name
    assert (built.stat().st_mtime_ns, library.stat().st_mtime_ns) == stamps


def test_a_non_finite_guess_never_reaches_acados(mpcc: Mpcc, track) -> None:
    mpcc.reset()
    mpcc(track.start_state(1.0))
    Z, V, refs = mpcc.last_guess
    Z = Z.copy()
    Z[3, 0] = np.nan
    result = mpcc._solve_qp(Z, V, refs)
    assert not result.success and result.status == "non-finite data in Z"


def test_casadi_stays_the_pinned_one_with_ipopt_after_acados_loads(mpcc: Mpcc) -> None:
    """acados's wheel ships a slimmed casadi 3.6.7; installed in its own folder it must not
    shadow the pinned casadi (../shared/specs/acados-from-pypi.md)."""
    assert mpcc._acados is not None  # acados is loaded and a solver built in this process
    assert ca.__version__ == "3.8.2"
    x = ca.SX.sym("x")
    options = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"}
    solver = ca.nlpsol("check", "ipopt", {"x": x, "f": (x - 1) ** 2}, options)
    assert float(solver(x0=0)["x"]) == pytest.approx(1.0, abs=1e-6)


#: acados loaded first, then CasADi's HPIPM solves a QP (a fresh process: the libraries' order).
_HPIPM_AFTER_ACADOS = """
import casadi as ca
from crs_core.acados_support import acados_template
acados_template()
h, a = ca.DM([[2.0]]), ca.DM([[1.0]])
options = {"N": 0, "nx": [1], "nu": [0], "ng": [1]}
qp = ca.conic("qp", "hpipm", {"h": h.sparsity(), "a": a.sparsity()}, options)
print(float(qp(h=h, g=-2.0, a=a, lba=-10, uba=10, lbx=-10, ubx=10)["x"]))
"""


def test_casadis_hpipm_still_solves_in_a_process_that_loaded_acados_first() -> None:
    """Both wheels ship a ``libhpipm.so``; loaded first, acados's took over CasADi's HPIPM
    plugin, whose first solve then crashed the process (segmentation fault)."""
    run = subprocess.run(
        [sys.executable, "-c", _HPIPM_AFTER_ACADOS], capture_output=True, text=True, timeout=60
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert float(run.stdout.split()[-1]) == pytest.approx(1.0, abs=1e-6)


def test_without_acados_the_setting_says_so(track, monkeypatch: pytest.MonkeyPatch) -> None:
    def unavailable():
        raise acados_support.AcadosUnavailable("acados is not installed: ./run.sh setup ...")

    import crs_core.control.mpcc_acados as module

    monkeypatch.setattr(module, "acados_template", unavailable)
    with pytest.raises(acados_support.AcadosUnavailable, match=r"solver='acados'.*run\.sh setup"):
        Mpcc(track, settings=MpccSettings(solver="acados"))
