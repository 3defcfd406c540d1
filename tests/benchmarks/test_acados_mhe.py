"""The acados MHE peer (benchmarks.acados_mhe) and the casadi hazard of the acados wheel.

The peer solves our MHE's own problem, so beyond converging from the standard wrong start
(standard drive, seed 1, 4 s, ``lh+imu+we``, 60 Hz, RMSE after 2 s, the bounds of the other
peers) its estimates must be ours: one real-time iteration equals our Gauss-Newton step, its
marginalization ours, and over the run the two agree once the start is behind them. Its solver
is generated and compiled once (the first construction on a cold cache took 10-17 s).
"""

from __future__ import annotations

import copy

import numpy as np
import pytest

pytest.importorskip("acados")

from benchmarks.acados_mhe import AcadosMhe, StepTimedMhe
from crs_core.acados_support import acados_template
from crs_core.estimation.mhe import MheSettings, MovingHorizonEstimator
from crs_core.model import CarModel
from sim.replay import replay, rmse, start_state, stream_events
from sim.scenarios import standard_drive

SENSORS = "lh+imu+we"
RATE_HZ = 60.0


@pytest.fixture(scope="module")
def peer() -> AcadosMhe:
    return AcadosMhe(CarModel(), SENSORS)


@pytest.fixture(scope="module")
def drive():
    return standard_drive(seed=1, duration=4.0)


def test_casadi_is_the_pinned_one_and_ipopt_loads_after_importing_acados():
    """The wheel ships a slimmed casadi 3.6.7 that must not replace ours (spec: the hazard)."""
    acados_template()
    import casadi as ca

    assert ca.__version__ == "3.8.2"
    x = ca.SX.sym("x")
    options = {"ipopt.print_level": 0, "print_time": False}
    solver = ca.nlpsol("s", "ipopt", {"x": x, "f": (x - 1) ** 2}, options)
    assert float(solver(x0=0)["x"]) == pytest.approx(1.0)


def test_the_solver_is_built_once(peer):
    """A second construction loads the compiled library instead of generating it again."""
    library = next(peer.solver_folder.rglob("libacados_ocp_solver_*.so"))
    stamp = library.stat().st_mtime_ns
    again = AcadosMhe(CarModel(), SENSORS)
    assert not again.built
    assert again.solver_folder == peer.solver_folder
    assert library.stat().st_mtime_ns == stamp
    assert peer.solver_folder.name.startswith("mhe_base_1bs_imu_lh_we_N40_60hz_")


def test_one_rti_step_and_the_marginalization_are_ours(peer):
    """From the same window and a defect-free noise guess, acados's step is our Gauss-Newton
    step and its marginalization (from its QP) ours (from our blocks).

    Measured: the steps agree to 2e-14 (the step moves nodes by 3 cm), the arrival means to
    2e-16 and the arrival information to 5e-16 relative.
    """
    drive = standard_drive(seed=1, duration=1.4)
    events = stream_events(drive)
    peer.reset(0.0, start_state(drive))
    grid = np.arange(1, 80) / RATE_HZ  # the window fills at node 40 and slides
    k = 0
    for t in grid[:-1]:
        while events[k][0] <= t:
            peer.add(events[k][1])
            k += 1
        peer.estimate(t)
    while events[k][0] <= grid[-1]:
        peer.add(events[k][1])
        k += 1
    peer._solver_step = lambda: None  # the new node's window, not yet solved
    peer.estimate(grid[-1])
    del peer._solver_step
    X, M = peer._X, peer.settings.horizon
    assert peer._active == M + 1
    peer._W = np.column_stack(
        [X[:, j + 1] - peer._predict(X[:, j], peer._U[:, j], peer._p, peer._DT[0, j])[0]
         for j in range(M)]
    )  # fmt: skip
    window = ("_X", "_W", "_arrival", "_arrival_information", "_last_blocks")
    saved = copy.deepcopy({key: vars(peer)[key] for key in window})
    peer._solver_step()
    acados_x, acados_qp = peer._X.copy(), peer._qp
    vars(peer).update(copy.deepcopy(saved))
    MovingHorizonEstimator._gauss_newton_step(peer)
    assert np.max(np.abs(peer._X - saved["_X"])) > 1e-3  # a real step
    np.testing.assert_allclose(acados_x, peer._X, rtol=0, atol=1e-10)
    MovingHorizonEstimator._marginalize_first_node(peer)
    ours = peer._arrival.copy(), peer._arrival_information.copy()
    peer._qp = acados_qp
    peer._marginalize()
    np.testing.assert_allclose(peer._arrival, ours[0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(peer._arrival_information, ours[1], rtol=1e-10)


def test_the_c_helper_reads_what_acados_reads(peer):
    """The helper's reads give what acados's own getters give (the QP's Q and R from their
    lower half, which HPIPM fills)."""
    nx, M = peer.model.nx, peer.settings.horizon
    X, W = np.zeros((M + 1, nx)), np.zeros((M, nx))
    peer._helper.read(X, W)
    np.testing.assert_array_equal(X[7], peer.solver.get(7, "x"))
    np.testing.assert_array_equal(W[39], peer.solver.get(39, "u"))
    A, Q, R, q, r, b = peer._helper.qp_stage(3)
    for field, ours in (("A", A), ("Q", Q), ("R", R)):
        np.testing.assert_array_equal(np.tril(ours), np.tril(peer.solver.get_from_qp_in(3, field)))
    for field, ours in (("q", q), ("r", r), ("b", b)):
        np.testing.assert_array_equal(ours, peer.solver.get_from_qp_in(3, field).ravel())
    np.testing.assert_array_equal(Q, Q.T)


@pytest.mark.slow
def test_acados_mhe_converges_and_agrees_with_ours(drive):
    """acados's MHE settles from the wrong start, with ours' estimates.

    Measured: RMSE x 0.71 mm, y 0.70 mm, yaw 7.1 mrad (bounds 20 mm and 0.1 rad), ours on the
    commanded model the same to 4 digits; after 2 s the two agree to 2e-9; no fallback.
    """
    peer = AcadosMhe(CarModel(), SENSORS)
    ours = StepTimedMhe(CarModel(), SENSORS, MheSettings())
    x0 = start_state(drive)
    run = replay(peer, drive, RATE_HZ, x0)
    run_ours = replay(ours, drive, RATE_HZ, x0)
    error = rmse(run, drive)
    assert error["x"] < 0.02 and error["y"] < 0.02 and error["yaw"] < 0.1, error
    assert peer.diagnostics.fallbacks == 0
    settled = run.stamps >= 2.0
    np.testing.assert_allclose(
        run.estimates[settled], run_ours.estimates[settled], rtol=0, atol=1e-6
    )
    n = len(run.stamps)
    assert len(peer.solve_times_s) == len(peer.step_times_s) == len(ours.step_times_s) == n
    assert all(0 < s <= step for s, step in zip(peer.solve_times_s, peer.step_times_s, strict=True))
