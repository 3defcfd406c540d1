"""The MPCC's real-time iteration as one compiled call (``MpccSettings(solver="native")``, the
default): it runs on acados's HPIPM build, solves the QP the CasADi iteration solves, reports
the violation the CasADi check computes, races, and falls back with a warning without acados."""

from __future__ import annotations

import numpy as np
import pytest

from crs_core import acados_support
from crs_core.control.mpcc import Mpcc
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
def native(track) -> Mpcc:
    return Mpcc(track)


@pytest.fixture(scope="module")
def reference(track) -> Mpcc:
    """The iteration in CasADi (CasADi's HPIPM): the reference."""
    return Mpcc(track, settings=MpccSettings(solver="hpipm"))


def _problems(reference: Mpcc, track, count: int):
    """The guesses of ``count`` calls of the reference racing from the start on the model."""
    reference.reset()
    x = track.start_state(1.0)
    numeric, p = reference.model.numeric, reference.p
    for _ in range(count):
        u = reference(x)
        yield reference.last_guess
        x = numeric.step(x, u, p, reference.settings.dt)


def test_the_default_solver_is_native_on_acados_hpipm(native: Mpcc) -> None:
    assert native.settings.solver == "native"
    assert native._native is not None and native._rti is None
    assert "acados" in native._native.hpipm_library


def test_it_solves_the_qp_of_the_casadi_iteration(native: Mpcc, reference: Mpcc, track) -> None:
    """Same guess, path linearisation and bounds: the same QP's solution (stage 0's state
    eliminated instead of bounded, the states' never-binding bounds left out), to the two
    HPIPMs' tolerances; the violation it reports is CasADi's check of its plan."""
    rti = reference._rti
    N, nz, nv = reference.problem.N, reference.problem.nz, reference.problem.nv
    first_inputs = []
    for Z, V, refs in _problems(reference, track, 40):
        ours, theirs = native._solve_qp(Z, V, refs), reference._solve_qp(Z, V, refs)
        assert ours.success and theirs.success
        first_inputs.append(np.max(np.abs(ours.V[0, :2] - theirs.V[0, :2])))
        assert np.max(np.abs(ours.Z - theirs.Z)) < 1e-2
        np.testing.assert_array_equal(ours.Z[0], Z[0])
        data = reference.qp_data(Z, V, refs)
        w = np.concatenate((np.hstack((ours.Z[:N], ours.V)).ravel(), ours.Z[N]))
        assert w.size == N * (nz + nv) + nz
        checked = float(rti.violation(w, *data[2:7]))
        assert ours.violation == pytest.approx(checked, abs=1e-9)
        assert ours.iterations > 0
    assert np.median(first_inputs) < 1e-4
    assert max(first_inputs) < 5e-3


def test_its_whole_iteration_is_the_python_iterations(native: Mpcc, track) -> None:
    """One compiled call per SQP iteration (rollout, path, QP, step check) gives the guess,
    path points, plan and contouring error of the Python steps around the same QP: the
    rollout (:meth:`Mpcc._rolled_out`), the path (:meth:`ReferencePath.evaluate`), the step
    check (:meth:`Mpcc._step`) on the model's nonlinear merit."""
    from crs_core.control.mpcc import _FRACTIONS

    arguments = (native._weights, native.p, native._v_lower, native._v_upper, native._half_width)
    nxc, steps = native._nxc, 0
    for Z, V, _ in _problems(native, track, 60):
        z0 = Z[0]
        rolled = native._rolled_out(z0, V)
        refs = native._references(rolled[:, nxc])
        solution = native._native.iterate(rolled, V, refs, *arguments)
        plan = native._step(z0, rolled, V, solution.V)
        step = native._native.sqp(z0, V, *arguments, _FRACTIONS)
        assert step is not None and step.qp.success == solution.success
        np.testing.assert_allclose(step.guess[0], rolled, rtol=0, atol=1e-10)
        np.testing.assert_allclose(step.refs, refs, rtol=0, atol=1e-10)
        np.testing.assert_allclose(step.qp.Z, plan[0], rtol=0, atol=1e-7)
        np.testing.assert_allclose(step.qp.V, plan[1], rtol=0, atol=1e-7)
        contour = float(np.asarray(native.problem.contouring_error(z0, refs[0])).ravel()[0])
        assert step.contour == pytest.approx(contour, abs=1e-12)
        steps += not np.array_equal(plan[1], V)
    assert steps > 40  # the QP's step taken, not the guess kept


def test_a_standing_guess_is_answered_before_the_qp(native: Mpcc, track) -> None:
    from crs_core.control.mpcc import _FRACTIONS

    Z, V, _ = next(_problems(native, track, 1))
    arguments = (native._weights, native.p, native._v_lower, native._v_upper, native._half_width)
    z0 = Z[0].copy()
    z0[3:6] = 0.0
    still = np.zeros_like(V)
    assert native._native.sqp(z0, still, *arguments, _FRACTIONS, standing=0.3) is None
    assert native._native.sqp(z0, still, *arguments, _FRACTIONS) is not None


def test_a_plan_beyond_its_bounds_is_refused(native: Mpcc, track) -> None:
    """An empty input range has no plan within it: the plan is refused on its violation,
    checked in the compiled call, not trusted from the solver's status."""
    Z, V, refs = next(_problems(native, track, 1))
    solved = native._native.iterate(
        Z,
        V,
        refs,
        native._weights,
        native.p,
        native._v_lower,
        native._v_upper,
        native._half_width,
    )
    assert solved.success
    tight = native._v_upper.copy()
    tight[0] = -native.settings.steer_max - 0.1  # an empty steering range: no plan within it
    refused = native._native.iterate(
        Z, V, refs, native._weights, native.p, native._v_lower, tight, native._half_width
    )
    assert not refused.success and refused.violation > 1e-3


def test_the_native_mpcc_races_a_lap(native: Mpcc, track) -> None:
    native.reset()
    result = run_closed_loop(
        Simulator(CarModel(), SensorSuite(), seed=5),
        track,
        lambda t, x: native(x),
        native.stop,
        30.0,
        laps=1,
        max_duration=12.0,
        status_of=lambda: native.status.mode,
    )
    summary = result.summary()
    assert summary["laps"] == 1
    assert summary["boundary_violations"] == 0
    assert summary["controller_modes"] == {"solved": result.t.size}


def test_without_acados_it_warns_and_iterates_in_casadi(track, monkeypatch) -> None:
    def unavailable():
        raise acados_support.AcadosUnavailable("acados is not installed")

    monkeypatch.setattr("crs_core.control.mpcc_native.acados_template", unavailable)
    with pytest.warns(RuntimeWarning, match=r"solver='native'.*not installed.*solver='hpipm'"):
        controller = Mpcc(track)
    assert controller._native is None and controller._rti is not None
    assert np.all(np.isfinite(controller(track.start_state(1.0))))
