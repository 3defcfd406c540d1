"""``crs bench control``: MPCC solve time against an IPOPT peer, QP solvers, closed-loop racing.

Measured in one run on this machine:

- **Solve time** of the real-time-iteration MPCC (N = 40, 30 Hz; the whole call from Python:
  guess, path linearisation, compiled linearisation, QP, checks), over a 5-lap race on the true
  state, with its QP iterations and fallbacks; the **peer** (:class:`~benchmarks.control_peers.
  IpoptMpcc`, the same problem solved to convergence by IPOPT) on every ``peer_every``-th of the
  race's problems (same state, guess and path linearisation), after the race: the ratio of the
  medians, and how far one real-time iteration's first command is from the converged one.
- **acados** (:class:`~benchmarks.control_peers.AcadosRacer`: acados's SQP-RTI + HPIPM of the
  same problem, its own shift warm start, its ``solve()`` timed from Python) in its own race,
  and the MPCC with acados as its iteration (``MpccSettings(solver="acados")``, the whole call
  timed as the stack calls it) in another: time, lap times, contouring error, violations, the
  ratios of the medians (acados / ours), and on the IPOPT peer's problems how far acados's one
  iteration's first command is from ours.
- **QP solvers**: the same race with the native iteration (the default) and with the
  iteration in CasADi behind each CasADi QP plugin (HPIPM, qpOASES, OSQP, qrqp).
- **Closed loop**: 5 laps on the true state and with the MHE in the loop, each without and with
  a 1.127 s Lighthouse blackout every lap; then the MHE races a car the model does not know
  exactly (the onboard steering servo and a 20 ms input delay hidden in the truth), and the
  velocity-reference output through the onboard loop.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from benchmarks.control_peers import AcadosRacer, IpoptMpcc
from benchmarks.machine import format_ms, machine
from crs_core.acados_support import AcadosUnavailable
from crs_core.analysis.statistics import summary
from crs_core.control.mpcc import Mpcc
from crs_core.control.mpcc_problem import MpccSettings
from crs_core.estimation.factory import make_estimator
from crs_core.model import CarModel
from crs_core.track import Track, load_demo_track
from sim.closed_loop import ClosedLoopResult, run_closed_loop
from sim.onboard import OnboardSettings
from sim.sensors import SensorSuite
from sim.simulator import Simulator

#: The paper's Lighthouse blackout in closed loop, s.
BLACKOUT_S = 1.127
#: Truth effects of the mismatched run: a radio / firmware delay the controller does not know.
MISMATCH_EFFECTS = {"input_delay": 0.02}


def _stats_ms(seconds: np.ndarray) -> dict[str, float]:
    ms = np.asarray(seconds) * 1e3
    return {**summary(ms, ("median", "p95", "p99", "max"), digits=3), "calls": int(ms.size)}


def _race(
    mpcc: Mpcc,
    track: Track,
    *,
    estimator: str | None = None,
    blackout: bool = False,
    laps: int = 5,
    seed: int = 1,
    truth_effects: dict[str, float] | None = None,
    onboard: bool = False,
    command_mode: str = "torque",
    after_call: Callable[[], None] | None = None,
) -> tuple[ClosedLoopResult, np.ndarray]:
    """A race; the result and the controller's own call times (s, without ``after_call``)."""
    truth = CarModel(truth_effects or {})
    simulator = Simulator(
        truth, SensorSuite(), seed=seed, onboard=OnboardSettings() if onboard else None
    )
    mpcc.reset()
    observer = make_estimator(estimator, "lh+imu+we", CarModel()) if estimator else None

    times: list[float] = []

    def control(t: float, x: np.ndarray) -> np.ndarray:
        u = mpcc(x)
        times.append(mpcc.status.solve_time_s)
        if after_call is not None:
            after_call()
        return u

    result = run_closed_loop(
        simulator,
        track,
        control,
        mpcc.stop,
        mpcc.settings.rate_hz,
        laps=laps,
        max_duration=12.0 * laps,
        estimator=observer,
        blackout_s=BLACKOUT_S if blackout else 0.0,
        status_of=lambda: mpcc.status.mode,
        command_mode=command_mode,
    )
    return result, np.array(times)


def _row(race: tuple[ClosedLoopResult, np.ndarray], **labels: Any) -> dict[str, Any]:
    result, times = race
    return {**labels, **result.summary(), "solve_ms": _stats_ms(times[1:])}


def _accuracy(result: ClosedLoopResult) -> dict[str, Any]:
    """A race's laps and how close to the path and the edges it stayed."""
    raced = result.summary()
    lateral = np.asarray(result.lateral_error, dtype=float)
    keys = ("laps", "lap_times_s", "mean_lap_s", "boundary_violations", "max_contouring_error_m")
    return {
        **{key: raced[key] for key in keys},
        "contouring_error_rms_m": round(float(np.sqrt(np.mean(lateral**2))), 4),
        "max_outside_m": raced["max_outside_m"],
        "controller_modes": raced["controller_modes"],
    }


def _lockstep(
    replays: dict[str, tuple[Callable[[np.ndarray], Any], Callable[[], float], np.ndarray]],
) -> dict[str, dict[str, float]]:
    """Each controller called again on the states of its own race (``(call, last call's time,
    states)``; reset before), one call of each in turn: every controller meets the same host
    speed, which drifted up to twofold within one run here, so the ratio of their times holds
    where the races' own times, minutes apart, do not. The calls repeat the races' exactly
    (a controller's call depends only on the state and its own plan)."""
    count = min(len(states) for _, _, states in replays.values())
    times: dict[str, list[float]] = {name: [] for name in replays}
    for k in range(count):
        for name, (call, last_time, states) in replays.items():
            call(states[k])
            times[name].append(last_time())
    return {name: _stats_ms(np.asarray(t[1:])) for name, t in times.items()}


def _acados_races(
    track: Track,
    settings: MpccSettings,
    mpcc: Mpcc,
    problems: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    laps: int,
    our_states: np.ndarray,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """acados's own race (bare: its ``solve()`` timed), the first-command differences of its
    one iteration to ours on ``problems``, the race of the MPCC with acados as its
    iteration (the whole call timed), and the three timed again in lockstep (:func:`_lockstep`;
    ours on ``our_states``, the states of its race)."""
    racer = AcadosRacer(mpcc)
    truth = CarModel()
    result = run_closed_loop(
        Simulator(truth, SensorSuite(), seed=1),
        track,
        lambda t, x: racer(x),
        racer.stop,
        settings.rate_hz,
        laps=laps,
        max_duration=12.0 * laps,
        status_of=lambda: racer.mode,
    )
    to_ours = []
    for Z, V, refs in problems:
        ours = mpcc._solve_qp(Z, V, refs)
        theirs = racer.rti.iterate(
            Z, V, refs, mpcc._weights, mpcc.p, mpcc._v_lower, mpcc._v_upper, mpcc._half_width
        )
        if ours.success and theirs.success:
            to_ours.append(float(np.max(np.abs(ours.V[0, :2] - theirs.V[0, :2]))))
    statuses = np.asarray(racer.statuses)
    bare = {
        "name": "acados 0.2.2 (SQP-RTI, PARTIAL_CONDENSING_HPIPM; the same problem, its own "
        "shift warm start; solve() timed from Python)",
        "solve_ms": _stats_ms(np.asarray(racer.solve_times[1:])),
        "call_ms": _stats_ms(np.asarray(racer.call_times[1:])),
        **_accuracy(result),
        "failed_solves": int(np.count_nonzero(statuses)),
        "qp_iterations_median": float(np.median(racer.qp_iterations)),
        "first_command_difference_to_ours": {
            **summary(to_ours, ("median", "max")),
            "problems": len(to_ours),
        },
    }
    backend = Mpcc(track, settings=dataclasses.replace(settings, solver="acados"))
    raced, times = _race(backend, track, laps=laps)
    for controller in (mpcc, racer, backend):
        controller.reset()
    bare["lockstep"] = _lockstep(
        {
            "ours": (mpcc, lambda: mpcc.status.solve_time_s, our_states),
            "acados": (racer, lambda: racer.solve_times[-1], result.truth),
            "ours_acados_backend": (backend, lambda: backend.status.solve_time_s, raced.truth),
        }
    )
    return bare, {
        "name": "our MPCC with acados's iteration (MpccSettings(solver='acados'); the whole "
        "Mpcc.__call__ timed)",
        "solve_ms": _stats_ms(times[1:]),
        **_accuracy(raced),
    }


def control_benchmark(
    laps: int = 5, peer_every: int = 3, progress: Callable[[str], None] | None = None
) -> dict[str, Any]:
    """Run every measurement (about 3 min on 2 cores); JSON-ready."""
    say = progress or (lambda _: None)
    track = load_demo_track()
    settings = MpccSettings()
    mpcc = Mpcc(track, settings=settings)
    peer = IpoptMpcc(mpcc.problem)
    started = time.perf_counter()

    # solve time in a race on the true state; the peer then solves every peer_every-th of
    # the same problems (same initial state, guess and path linearisation) after the race, so
    # neither pollutes the other's caches
    say("solve time (true state)")
    iterations: list[int] = []
    problems: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    calls = [0]

    def after_call() -> None:
        status = mpcc.status
        if status.mode == "solved":
            iterations.append(status.qp_iterations)
        calls[0] += 1
        if calls[0] % peer_every == 0 and mpcc.last_guess is not None:
            problems.append(mpcc.last_guess)

    timed, times = _race(mpcc, track, laps=laps, after_call=after_call)
    solve = _stats_ms(times[1:])  # the first call is the cold start (several iterations)
    modes = timed.summary()["controller_modes"]
    say(f"IPOPT peer on {len(problems)} of the race's problems")
    peer_times: list[float] = []
    peer_iterations: list[int] = []
    peer_converged: list[bool] = []
    peer_gap: list[float] = []
    for Z, V, refs in problems:
        begun = time.perf_counter()
        _, plan_V, ok, count = peer.solve(
            Z,
            V,
            refs,
            settings.weights(),
            mpcc.p,
            mpcc._v_lower,
            mpcc._v_upper,
            mpcc._half_width,
        )
        peer_times.append(time.perf_counter() - begun)
        peer_iterations.append(count)
        peer_converged.append(ok)
        rti = mpcc._solve_qp(Z, V, refs)
        if ok and rti.success:  # first command of one RTI step vs the converged optimum
            peer_gap.append(float(np.max(np.abs(rti.V[0, :2] - plan_V[0, :2]))))
    peer_solve = _stats_ms(np.array(peer_times))

    say("acados: its own race, then the MPCC with acados as its iteration")
    acados: dict[str, Any] | None = None
    backend: dict[str, Any] | None = None
    try:
        acados, backend = _acados_races(track, settings, mpcc, problems, laps, timed.truth)
    except AcadosUnavailable as error:
        say(f"acados unavailable: {error}")
        acados = {"unavailable": str(error)}

    say("QP solvers")
    solvers = []
    for name in ("native", "hpipm", "qpoases", "osqp", "qrqp"):
        variant = Mpcc(track, settings=MpccSettings(solver=name, qp_max_iter=200))
        counts: list[int] = []

        def count(v: Mpcc = variant, out: list[int] = counts) -> None:
            if v.status.mode == "solved" and v.status.qp_iterations >= 0:  # OSQP: not reported
                out.append(v.status.qp_iterations)

        result, times = _race(variant, track, laps=min(2, laps), after_call=count)
        raced = result.summary()  # not "summary": that is the statistics function used below
        solvers.append(
            {
                "solver": name,
                "solve_ms": _stats_ms(times[1:]),
                "qp_iterations_median": float(np.median(counts)) if counts else None,
                "laps": raced["laps"],
                "lap_times_s": raced["lap_times_s"],
                "controller_modes": raced["controller_modes"],
            }
        )

    closed_loop = []
    for state in ("true", "mhe"):
        for blackout in (False, True):
            say(f"closed loop: {state} state, blackout {blackout}")
            race = _race(
                mpcc,
                track,
                estimator=None if state == "true" else "mhe",
                blackout=blackout,
                laps=laps,
            )
            closed_loop.append(_row(race, state=state, blackout=blackout, truth="nominal"))
    say("closed loop: MHE, truth with onboard steering servo and a 20 ms input delay")
    race = _race(
        mpcc,
        track,
        estimator="mhe",
        blackout=True,
        laps=laps,
        truth_effects=MISMATCH_EFFECTS,
        onboard=True,
    )
    closed_loop.append(
        _row(race, state="mhe", blackout=True, truth="onboard servo + 20 ms input delay")
    )
    say("closed loop: velocity references through the onboard loop")
    velocity = Mpcc(track, settings=settings, output="velocity")
    race = _race(velocity, track, laps=laps, onboard=True, command_mode="velocity")
    closed_loop.append(
        _row(race, state="true", blackout=False, truth="onboard loop, velocity references")
    )

    true_mean = closed_loop[0]["mean_lap_s"]
    mhe_mean = closed_loop[2]["mean_lap_s"]
    return {
        "machine": machine(),
        "settings": {
            "horizon": settings.horizon,
            "rate_hz": settings.rate_hz,
            "solver": settings.solver,
            "laps": laps,
            "blackout_s": BLACKOUT_S,
        },
        "solve_ms": solve,
        "qp_iterations": {
            **summary(iterations, ("median", "p95")),
            "max": int(np.max(iterations)),
        },
        "fallbacks": int(modes.get("fallback", 0)),
        "stops": int(modes.get("stop", 0)),
        "peer": {
            "name": "ipopt (casadi nlpsol, exact Hessian, same problem and guess)",
            "solve_ms": peer_solve,
            "iterations_median": float(np.median(peer_iterations)),
            "converged_fraction": round(float(np.mean(peer_converged)), 3),
            "first_command_difference_median": round(float(np.median(peer_gap)), 5),
        },
        "speedup_median": round(peer_solve["median"] / solve["median"], 1),
        "peers": {"acados": acados},
        "acados_backend": backend,
        "ours_accuracy": _accuracy(timed),
        "ratios": _ratios(acados) if backend is not None and acados is not None else None,
        "qp_solvers": solvers,
        "closed_loop": closed_loop,
        "mhe_vs_true_lap_ratio": round(mhe_mean / true_mean, 4) if true_mean and mhe_mean else None,
        "wall_time_s": round(time.perf_counter() - started, 1),
    }


def _ratios(acados: dict[str, Any]) -> dict[str, float]:
    """acados's bare solve over ours (the whole call), with our iteration and with acados's,
    from the lockstep timing (medians; >= 1: ours at most as slow)."""
    medians = {name: row["median"] for name, row in acados["lockstep"].items()}
    return {
        "acados/ours": round(medians["acados"] / medians["ours"], 3),
        "acados/ours_acados_backend": round(medians["acados"] / medians["ours_acados_backend"], 3),
    }


#: The QP solvers' names in the table.
QP_SOLVER_NAMES = {
    "native": "HPIPM, the whole iteration in one compiled call (acados's AVX build; default)",
    "hpipm": "HPIPM through CasADi (Riccati interior point, OCP structure)",
    "qpoases": "qpOASES (dense active set)",
    "osqp": "OSQP (ADMM, eps 10⁻⁸, polished)",
    "qrqp": "qrqp (CasADi active set)",
}


def _iteration(result: dict[str, Any]) -> str:
    """How the benchmarked MPCC iterated (its ``solver`` setting, in words)."""
    solver = result["settings"]["solver"]
    if solver == "native":
        return "real-time iteration in one compiled call (HPIPM)"
    return f"real-time iteration in CasADi + {solver.upper()}"


def _acados_lines(result: dict[str, Any]) -> list[str]:
    """The table of ours against acados, each in its own race (none in a result without
    acados: the saved runs before it)."""
    acados = (result.get("peers") or {}).get("acados")
    if acados is None:
        return []
    if "unavailable" in acados:
        return [f"acados: not measured ({acados['unavailable']}).", ""]
    rows = [
        (f"ours: MPCC, {_iteration(result)}, whole call", result["solve_ms"],
         result.get("ours_accuracy")),
        ("ours with acados's iteration (solver='acados'), whole call",
         (result.get("acados_backend") or {}).get("solve_ms"), result.get("acados_backend")),
        ("acados SQP-RTI + HPIPM, own race, solve() only", acados["solve_ms"], acados),
    ]  # fmt: skip
    lines = [
        "Against acados on the same problem (each controller in its own race on the true state):",
        "",
        "| controller | median ms | p95 ms | p99 ms | max ms | lap times s | mean lap | "
        "contouring error RMS | max \\|lateral\\| | violations |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, solve, race in rows:
        if solve is None or race is None:
            continue
        mean = "–" if race["mean_lap_s"] is None else f"{race['mean_lap_s']:.3f} s"
        lines.append(
            f"| {name} | "
            + " | ".join(format_ms(solve[k]) for k in ("median", "p95", "p99", "max"))
            + f" | {', '.join(f'{v:.2f}' for v in race['lap_times_s']) or '–'} | {mean} | "
            f"{1e3 * race['contouring_error_rms_m']:.1f} mm | "
            f"{race['max_contouring_error_m']:.3f} m | {race['boundary_violations']} |"
        )
    ratios = result.get("ratios") or {}
    difference = acados["first_command_difference_to_ours"]
    lockstep = acados.get("lockstep")
    timed_in = (
        "timed in lockstep, each on the states of its own race and one call of each in turn "
        f"so that all meet the same host speed: ours {format_ms(lockstep['ours']['median'])} ms, "
        f"acados's solve() {format_ms(lockstep['acados']['median'])} ms, ours with acados's "
        f"iteration {format_ms(lockstep['ours_acados_backend']['median'])} ms"
        if lockstep
        else "in the races above"
    )
    lines += [
        "",
        (
            f"**acados / ours = {ratios['acados/ours']:g}** (medians, {timed_in}; ≥ 1: ours "
            f"at most as slow), {ratios['acados/ours_acados_backend']:g} against ours with "
            "acados's iteration. "
            if "acados/ours" in ratios
            else ""
        )
        + (
            f"acados's whole call from Python (state, shift, path, data in and out): "
            f"{format_ms(acados['call_ms']['median'])} ms median. "
            if "call_ms" in acados
            else ""
        )
        + f"acados's one iteration's first command is {difference['median']:.2g} (median; max "
        f"{difference['max']:.2g}; steering rad or torque) from ours on {difference['problems']} "
        f"of the race's problems; {acados['failed_solves']} of its solves failed.",
        "",
    ]
    return lines


def format_table(result: dict[str, Any]) -> str:
    """The benchmark's figures as the docs' Markdown tables: the solve time against the peer,
    the QP solvers, the closed-loop races (ms: :func:`~benchmarks.machine.format_ms`; m; mm)."""
    settings, solve, peer = result["settings"], result["solve_ms"], result["peer"]
    laps = settings.get("laps", 5)
    converged = peer.get("converged_fraction")
    counted = (
        f" ({solve['calls']} calls, the first, cold one left out; the peer on "
        f"{peer['solve_ms']['calls']} of the race's problems)"
        if "calls" in solve and "calls" in peer["solve_ms"]
        else ""
    )
    lines = [
        f"Solve time: the whole `Mpcc.__call__` over a {laps}-lap race on the true state{counted}:",
        "",
        "| controller | median ms | p95 ms | p99 ms | max ms | iterations (median) |",
        "|---|---|---|---|---|---|",
        f"| MPCC, {_iteration(result)} | "
        + " | ".join(format_ms(solve[k]) for k in ("median", "p95", "p99", "max"))
        + f" | {result['qp_iterations']['median']:g} (QP) |",
        f"| peer: {peer['name']} | "
        + " | ".join(format_ms(peer["solve_ms"][k]) for k in ("median", "p95", "p99", "max"))
        + f" | {peer['iterations_median']:g} (NLP)"
        + ("" if converged is None else f", {converged:.0%} converged")
        + " |",
        "",
        f"**{result['speedup_median']:g}× faster** (medians); {result['fallbacks']} fallbacks, "
        f"{result['stops']} stops in the race. One real-time iteration's first command is "
        f"{peer['first_command_difference_median']:.2g} (median; steering rad or torque, "
        "whichever is larger) from IPOPT's converged optimum for the same problem.",
        "",
    ]
    lines += _acados_lines(result)
    lines += [
        "| QP solver | median ms | p99 ms | QP iterations | lap times s | solves that failed "
        "the constraint check |",
        "|---|---|---|---|---|---|",
    ]
    for row in result["qp_solvers"]:
        modes = row["controller_modes"]
        failed = modes.get("fallback", 0)
        iterations = row["qp_iterations_median"]
        lines.append(
            f"| {QP_SOLVER_NAMES.get(row['solver'], row['solver'])} | "
            f"{format_ms(row['solve_ms']['median'])} | {format_ms(row['solve_ms']['p99'])} | "
            f"{'(not reported)' if iterations is None else f'{iterations:g}'} | "
            f"{', '.join(f'{v:.2f}' for v in row['lap_times_s'])} | "
            f"{failed} of {sum(modes.values())}"
            + (" (fallback: shifted plan)" if failed else "")
            + " |"
        )
    lines += [
        "",
        "| state | Lighthouse blackout | simulated car | laps (s) | mean lap | violations | "
        "max \\|lateral\\| | closest corner to the edge | position RMSE of the estimate | "
        "call median / p99 |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    blackout = f"{settings.get('blackout_s', BLACKOUT_S):g} s per lap"
    for row in result["closed_loop"]:
        mean = "–" if row["mean_lap_s"] is None else f"{row['mean_lap_s']:.3f} s"
        rmse = row.get("estimation_rmse")
        position = "–" if not rmse else f"{1e3 * rmse['position']:.1f} mm"
        lap_times = ", ".join(f"{v:.2f}" for v in row["lap_times_s"]) or "–"
        lines.append(
            f"| {'true' if row['state'] == 'true' else row['state'].upper()} | "
            f"{blackout if row['blackout'] else '–'} | {row['truth']} | {lap_times} | "
            f"{mean} | {row['boundary_violations']} | {row['max_contouring_error_m']:.3f} m | "
            f"{-row['max_outside_m']:.3f} m | {position} | "
            f"{format_ms(row['solve_ms']['median'])} / {format_ms(row['solve_ms']['p99'])} ms |"
        )
    first = result["closed_loop"][0] if result["closed_loop"] else {}
    if result.get("mhe_vs_true_lap_ratio") is not None and "max_speed_mps" in first:
        lines += [
            "",
            f"MHE mean lap / true state's (no blackout): {result['mhe_vs_true_lap_ratio']:g}; "
            f"the first race: peak speed {first['max_speed_mps']:.1f} m/s, mean "
            f"{first['mean_speed_mps']:.1f} m/s.",
        ]
    return "\n".join(lines)
