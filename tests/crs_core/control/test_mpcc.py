"""MPCC: its QP's constraints, safe commands from bad starts, fallbacks."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from crs_core.control.mpcc import Mpcc
from crs_core.control.mpcc_problem import QP_ARGUMENTS, MpccSettings


@pytest.fixture(scope="module")
def mpcc(track) -> Mpcc:
    """The MPCC with its iteration in CasADi, whose QP data these tests read."""
    return Mpcc(track, settings=MpccSettings(solver="hpipm"))


def _start(track, speed: float = 1.0) -> np.ndarray:
    return track.start_state(speed)


def _within_limits(u: np.ndarray, settings: MpccSettings) -> bool:
    return (
        bool(np.all(np.isfinite(u)))
        and abs(u[0]) <= settings.steer_max + 1e-9
        and settings.torque_min - 1e-9 <= u[1] <= settings.torque_max + 1e-9
    )


def test_the_qp_solution_satisfies_the_constraints_it_is_accepted_with(mpcc: Mpcc, track) -> None:
    """Checked independently of the solver: the linearised dynamics, the input bounds and the
    boundary rows, stage by stage, from the stage functions."""
    mpcc.reset()
    x = _start(track, 1.2)
    mpcc(x)
    for _ in range(3):
        x = np.asarray(
            mpcc.problem.dynamics(
                np.concatenate((x, [0, 0, 0, 0])), np.r_[mpcc._command, 1.0, 0.0], mpcc.p
            )
        ).ravel()[:6]
        mpcc(x)
    Z, V, refs = mpcc.last_guess
    solution = mpcc._solve_qp(Z, V, refs)
    assert solution.success and solution.violation <= 1e-6
    problem, s = mpcc.problem, mpcc.settings
    stage = problem.stage_linearization()
    for k in range(problem.N):
        A, B, c, _, _, C, e0 = (
            np.asarray(o) for o in stage(Z[k], V[k], refs[k], s.weights(), mpcc.p)
        )
        predicted = A @ solution.Z[k] + B @ solution.V[k] + c.ravel()
        assert np.max(np.abs(predicted - solution.Z[k + 1])) < 1e-5
        steer, torque, progress_speed, slack = solution.V[k]
        assert abs(steer) <= s.steer_max + 1e-6
        assert s.torque_min - 1e-6 <= torque <= s.torque_max + 1e-6
        assert -1e-6 <= progress_speed <= s.progress_speed_max + 1e-6
        assert slack >= -1e-6
        if k >= 1:
            contour = float(C.ravel() @ solution.Z[k] + e0.ravel()[0])
            assert abs(contour) <= mpcc._half_width + slack + 1e-5
    assert solution.Z[0] == pytest.approx(Z[0])


def test_a_solution_that_breaks_its_constraints_is_not_accepted(mpcc: Mpcc, track) -> None:
    mpcc.reset()
    mpcc(_start(track))
    Z, V, refs = mpcc.last_guess
    data = mpcc.qp_data(Z, V, refs)
    solved = mpcc._rti.solver(**dict(zip(QP_ARGUMENTS, data, strict=True)))["x"]
    assert float(mpcc._rti.violation(solved, *data[2:7])) <= 1e-6
    broken = np.asarray(solved).ravel().copy()
    broken[mpcc.problem.nz] = 1.0  # stage 0's steering: 1 rad, beyond the 0.34 rad bound
    # beyond the bound by 0.66 rad, and the dynamics rows break too
    assert float(mpcc._rti.violation(broken, *data[2:7])) >= 1.0 - 0.34 - 1e-9


# --- commands from bad starts -----------------------------------------------------------------
@pytest.mark.parametrize(
    "case",
    ["standstill", "off the track", "backwards", "sliding sideways", "far away"],
)
def test_an_infeasible_or_odd_start_gives_a_safe_finite_command(mpcc: Mpcc, track, case: str):
    x = _start(track, 0.0)
    if case == "off the track":
        x[1] -= 0.6  # 0.6 m outside the right edge
    elif case == "backwards":
        x[2] += math.pi
        x[3] = 0.5
    elif case == "sliding sideways":
        x[3:] = [1.5, 1.0, 6.0]
    elif case == "far away":
        x[:2] = [25.0, -40.0]
    mpcc.reset()
    for _ in range(5):
        u = mpcc(x)
        assert _within_limits(u, mpcc.settings), (case, u, mpcc.status)
    assert mpcc.status.mode in ("solved", "fallback", "stop")


def test_a_nan_state_stops_the_car(mpcc: Mpcc, track) -> None:
    mpcc.reset()
    mpcc(_start(track, 1.0))
    x = _start(track, 1.0)
    x[4] = math.nan
    u = mpcc(x)
    assert mpcc.status.mode == "stop" and "finite" in mpcc.status.reason
    assert u == pytest.approx([0.0, 0.0])
    braking = mpcc.stop(_start(track, 1.5))
    assert braking[0] == 0.0 and braking[1] < 0.0


def test_failed_solves_serve_the_shifted_plan_then_stop(track) -> None:
    controller = Mpcc(track, settings=MpccSettings(max_failures=2))
    x = _start(track, 1.0)
    controller(x)
    _, plan_V = controller.plan
    real_iteration = controller._sqp_iteration

    def failing(z0, Z, V):
        step = real_iteration(z0, Z, V)
        Z, V = step.guess
        refused = dataclasses.replace(step.qp, Z=Z, V=V, success=False, status="test")
        return dataclasses.replace(step, qp=refused)

    controller._sqp_iteration = failing  # type: ignore[method-assign]
    u = controller(x)
    assert controller.status.mode == "fallback"
    assert u == pytest.approx(plan_V[1, :2])  # the previous plan's next input
    controller(x)
    assert controller.status.mode == "fallback" and controller.status.failures == 2
    u = controller(x)
    assert controller.status.mode == "stop" and "3 failed" in controller.status.reason
    assert _within_limits(u, controller.settings)
    controller._sqp_iteration = real_iteration  # type: ignore[method-assign]
    controller(x)
    assert controller.status.mode == "solved"


def test_velocity_output_gives_the_planned_speed(track) -> None:
    controller = Mpcc(track, output="velocity")
    u = controller(_start(track, 1.0))
    Z, _ = controller.plan
    assert u[0] == pytest.approx(controller._command[0])
    assert u[1] == pytest.approx(Z[controller._velocity_stage, 3])
    assert u[1] > 1.0  # it accelerates from 1 m/s on the start straight
    with pytest.raises(ValueError, match="output"):
        Mpcc(track, output="position")


def test_the_progress_reference_is_the_centreline_at_the_plans_progress(track) -> None:
    controller = Mpcc(track)
    assert controller.progress_reference is None  # no plan yet
    controller(_start(track, 1.0))
    Z, _ = controller.plan
    reference = controller.progress_reference
    assert reference.shape == (len(Z), 2)
    for (x, y), s in zip(reference, Z[:, controller.model.nx], strict=True):
        on = track.project(x, y)  # on the centreline, at the stage's progress
        assert abs(on.lateral_error) < 1e-6 and on.s == pytest.approx(s % track.length, abs=1e-6)
    # the plan's positions follow it within the track
    assert np.max(np.hypot(*(Z[:, :2] - reference).T)) < track.width / 2


def test_a_short_stop_keeps_the_plan_shifted_in_time_and_a_long_one_forgets_it(track) -> None:
    """Stops with ``keep_plan`` (a late estimate) shift the plan a stage per call, as the calls
    would have, and hold its steering with no torque; the next call starts from it (no cold
    start); once the stops have used up half the horizon, the plan is forgotten."""
    controller = Mpcc(track)
    x = _start(track, 1.0)
    controller(x)
    Z, V = controller.plan
    for k in range(3):  # the plan's steering held, no torque
        assert np.array_equal(controller.stop(None, "late", keep_plan=True), [V[k + 1, 0], 0.0])
    assert controller.status.mode == "stop"
    kept_Z, kept_V = controller.plan
    np.testing.assert_array_equal(kept_V[:-3], V[3:])
    np.testing.assert_array_equal(kept_Z[:-3], Z[3:])
    controller(Z[4, :6])  # the car where the plan put it four periods on
    assert controller.status.mode == "solved"
    assert controller.last_guess[1][0] == pytest.approx(V[4])  # warm: the plan one stage on
    half = controller.problem.N // 2
    for _ in range(half):
        controller.stop(None, "late", keep_plan=True)
    assert controller.plan is not None
    controller.stop(None, "late", keep_plan=True)
    assert controller.plan is None  # half the horizon gone: a cold start next
    controller(x)
    controller.stop(None, "stopped")
    assert controller.plan is None


@pytest.mark.parametrize(
    "case, offset, speed_limit",
    [
        # before the plans were rolled out on the model, these planned 774, 61 and 156 m/s
        # (or rad/s), and linearising there next put NaN into the QP's bounds
        ("2 m/s under a 0.5 m/s cap", [0, 0, 0, 2.0, 0, 0], 0.5),
        ("a noisy estimate at rest", [0, 0, 0, 0.02, 0.05, 0.3], None),
        ("4 m/s, 0.2 rad off the heading", [0, 0, 0.2, 4.0, 0, 0], None),
    ],
)
@pytest.mark.parametrize("output", ["torque", "velocity"])
def test_plans_stay_where_a_car_can_be_after_a_poor_guess(
    track, case: str, offset: list[float], speed_limit: float | None, output: str
) -> None:
    """One closed loop of 1 s on the model from a state far from the last plan: every QP's
    data are finite, every plan is one the model can drive (a plan rolled out on it: at
    worst a slide or a spin, 15 rad/s when a 0.5 m/s cap meets a car at 2 m/s, which is why
    the supervisor ramps the cap; before, plans of 60-1800 m/s) and every command within its
    limits."""
    controller = Mpcc(track, settings=MpccSettings(solver="hpipm"), output=output)
    model, p = controller.model, controller.p
    checked: list[bool] = []
    qp_data = controller.qp_data

    def finite_data(Z, V, refs):
        data = qp_data(Z, V, refs)
        checked.append(all(np.all(np.isfinite(d.nonzeros())) for d in data))
        return data

    controller.qp_data = finite_data
    x = _start(track, 0.0) + np.array(offset)
    s = controller.settings
    for _ in range(30):
        u = controller(x, speed_limit)
        assert np.all(np.isfinite(u)) and abs(u[0]) <= s.steer_max
        if output == "velocity":
            assert 0.0 <= u[1] <= s.velocity_max
            torque = controller.plan[1][0, 1] if controller.plan is not None else 0.0
        else:
            assert s.torque_min <= u[1] <= s.torque_max
            torque = u[1]
        plan = controller.plan
        if plan is not None:
            speeds = np.abs(plan[0][:, 3:6]).max(axis=0)
            assert np.all(speeds <= 25.0), (case, speeds)
        x = np.asarray(model.numeric.step(x, np.array([u[0], torque]), p, s.dt)).ravel()
    assert checked and all(checked)


def test_a_late_call_carries_the_plan_on_by_the_time_that_passed(track) -> None:
    controller = Mpcc(track)
    x = _start(track, 1.0)
    controller(x)
    Z, V = controller.plan
    controller(Z[4, :6], elapsed=4 / controller.settings.rate_hz)  # four periods late
    _, guess_V, _ = controller.last_guess
    assert guess_V[:-4] == pytest.approx(V[4:])
    assert guess_V[-4:] == pytest.approx(np.repeat(V[-1:], 4, axis=0))


@pytest.mark.parametrize("vx", [-0.3, 0.0, 0.2, 1.5])
def test_the_controller_never_brakes_the_car_into_reverse(track, vx: float) -> None:
    """Facing backwards along the track, the plan wants to turn round; the command's braking
    stays within the safe stop's ``-brake_gain v_x`` (none at or below standstill)."""
    controller = Mpcc(track)
    x = _start(track, 0.0)
    x[2] += math.pi
    x[3] = vx
    for _ in range(5):
        u = controller(x)
        assert u[1] >= -controller.settings.brake_gain * max(vx, 0.0) - 1e-12, u


@pytest.mark.parametrize(
    "s, lateral, heading_offset", [(2.8, 0.0, 0.0), (2.8, 0.1, 0.4), (5.0, 0.1, 0.4)]
)
def test_from_rest_in_a_bend_the_car_drives_off(track, pose_at, s, lateral, heading_offset) -> None:
    """Standing in a bend, or a little off the path, the car drives on: 3 s on the model
    cover more than a metre of the track. Linearised at a standing car (where the steering
    has no effect), the plans stayed put in these three poses (0.35, 1.05, 0.21 m)."""
    controller = Mpcc(track)
    model, p = controller.model, controller.p
    x = pose_at(track, s, lateral, heading_offset)
    for _ in range(90):
        u = controller(x, None, controller.settings.dt)
        x = model.numeric.step(x, u, p, controller.settings.dt)
    travelled = (track.project(x[0], x[1]).s - s) % track.length
    assert 1.0 < travelled < 8.0, travelled
    assert x[3] > 0.5


def test_far_from_its_plan_the_controller_iterates_as_from_cold(track) -> None:
    """Racing at 1.5 m/s, then an estimate 0.2 m and 0.3 rad away from where the plan put the
    car (after a link outage, the plan had followed a dead-reckoned estimate): the command is
    the one a controller starting cold there gives, not one iteration from the stale plan: the
    same steering, and braking (3 iterations against a cold start's 10: the torque differs)."""
    controller = Mpcc(track)
    model, p, dt = controller.model, controller.p, controller.settings.dt
    x = _start(track, 1.5)
    for _ in range(10):
        u = controller(x, None, dt)
        x = model.numeric.step(x, u, p, dt)
    jumped = x + np.array([0.2 * -math.sin(x[2]), 0.2 * math.cos(x[2]), 0.3, 0, 0, 0])
    warm = controller(jumped, None, dt)
    assert controller.status.qp_iterations > 0
    cold = Mpcc(track)(jumped)
    assert warm[0] == pytest.approx(cold[0], abs=0.02)
    assert warm[1] < -0.5 and cold[1] < -0.5


def test_a_car_entering_the_hairpin_too_fast_turns_in_and_keeps_rolling(track, pose_at) -> None:
    """The state a 300 ms link outage left an emulated car in (the full torque it was given
    held for 200 ms, then coasting): at the demo track's hairpin entry (s = 4.95 m, radius
    0.3 m) at 1.95 m/s, 2 cm left, 0.17 rad left of the track's direction. Closed loop on the
    model for 1.5 s: the first command steers into the bend, the car brakes but never stands,
    stays within the track and is through the hairpin. The full SQP steps went from full
    right lock to full left lock (the linearised tires past their peak) and braked the car to
    a stand at the edge, facing out, in 0.7 s."""
    controller = Mpcc(track)
    model, p, dt = controller.model, controller.p, controller.settings.dt
    x = pose_at(track, 4.95, 0.02, 0.17)
    x[3] = 1.95
    first = controller(x, None, dt)
    assert first[0] < 0.0 and first[1] < 0.0  # turns right (into the bend) and brakes
    slowest, widest = math.inf, 0.0
    for _ in range(45):
        x = model.numeric.step(x, controller(x, None, dt), p, dt)
        slowest = min(slowest, float(x[3]))
        widest = max(widest, abs(track.project(x[0], x[1]).lateral_error))
    assert slowest > 0.3, slowest
    assert widest < 0.5 * track.width, widest
    assert track.project(x[0], x[1]).s > 5.9  # out of the hairpin (its exit: 6.25 m)


def test_no_plan_costs_more_than_the_guess_it_came_from(track, pose_at) -> None:
    """Every SQP step is a fraction of the QP's that lowers the nonlinear cost, or none: over
    a closed loop from the hairpin entry and a cold start, each call's plan costs no more
    than its guess (the real-time iteration's single step, and the cold start's ten)."""
    controller = Mpcc(track)
    model, p, dt = controller.model, controller.p, controller.settings.dt
    x = pose_at(track, 4.95, 0.02, 0.17)
    x[3] = 1.95
    for _ in range(30):
        u = controller(x, None, dt)
        Z_guess, V_guess, _ = controller.last_guess
        Z, V = controller.plan
        assert controller._merit(Z, V) <= controller._merit(Z_guess, V_guess) + 1e-9
        x = model.numeric.step(x, u, p, dt)


def test_a_solve_time_budget_ends_the_iterations_of_a_call(track) -> None:
    """With a budget shorter than one SQP iteration, a cold start makes one iteration (the
    same plan as ``cold_start_iterations=1``), not ten; without one (0) it makes ten."""
    x = _start(track, 1.0)
    hurried = Mpcc(track, settings=MpccSettings(solve_time_budget=1e-9))
    once = Mpcc(track, settings=MpccSettings(cold_start_iterations=1))
    unhurried = Mpcc(track)
    for controller in (hurried, once, unhurried):
        controller(x)
    np.testing.assert_allclose(hurried.plan[1], once.plan[1])
    assert hurried.status.qp_iterations == once.status.qp_iterations
    assert unhurried.status.qp_iterations > 3 * once.status.qp_iterations


@pytest.mark.parametrize("solver", ["hpipm", "native"])
def test_non_finite_qp_data_never_reach_the_solver(track, solver: str) -> None:
    """A guess with a NaN makes non-finite QP data: the iteration fails with the name of the
    first argument that holds one (the native iteration: its linearisation), and the QP
    solver is not called."""
    controller = Mpcc(track, settings=MpccSettings(solver=solver))
    controller(_start(track, 1.0))
    Z, V = controller.plan
    Z = Z.copy()
    Z[3, 3] = math.nan
    refs = controller._references(Z[:, controller._nxc])
    result = controller._solve_qp(Z, V, refs)
    assert not result.success and result.status.startswith("non-finite data in ")


def test_online_parameters_move_the_model_at_the_parameter_rate():
    """Cm1 and grip toward their estimates by at most parameter_rate of their value per second;
    a name the model does not have (gyro_bias) changes nothing; the values in use returned."""
    from crs_core.control.mpcc import Mpcc
    from crs_core.control.mpcc_problem import MpccSettings
    from crs_core.track import load_demo_track

    mpcc = Mpcc(load_demo_track(), settings=MpccSettings(parameter_rate=0.05, solver="hpipm"))
    values = mpcc.model.parameters
    used = mpcc.use_parameters(
        {"Cm1": 0.5 * values.value("Cm1"), "grip": 0.99, "gyro_bias": 1.0}, 1.0
    )
    assert used["Cm1"] == pytest.approx(0.95 * values.value("Cm1"))  # 5 % in 1 s, not 50 %
    assert used["Df"] == pytest.approx(0.99 * values.value("Df"))  # within the step
    assert used["Dr"] == pytest.approx(0.99 * values.value("Dr"))
    assert set(used) == {"Cm1", "Df", "Dr"}
    index = values.names.index("Cm1")
    assert mpcc.p[index] == used["Cm1"]


def test_warm_up_builds_the_hold_safety_filter_before_the_first_command(track, monkeypatch):
    """The hold-safety filter is built in ``warm_up`` (its first call cost 130 ms, over a car's
    200 ms cut-off beside two busy loops): a hold-safe call after it builds nothing, and the
    warm-up leaves no plan and no replaced command behind."""
    import crs_core.control.mpcc as mpcc_module

    controller = Mpcc(track)
    controller.warm_up()
    assert controller.plan is None and controller.hold_safe_replaced == 0

    def refuse(*args, **kwargs):
        raise AssertionError("the hold-safety filter was built in the control loop")

    monkeypatch.setattr(mpcc_module, "HoldSafetyFilter", refuse)
    moving = track.start_state().copy()
    moving[3] = 1.5
    u = controller(moving, hold_safe=True)
    assert np.all(np.isfinite(u))
