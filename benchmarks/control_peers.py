"""Peer controllers for comparison, on the same MPCC problem (``crs bench control``).

:class:`IpoptMpcc` states the optimal control problem of :mod:`crs_core.control.mpcc_problem`
(the same stage functions, dynamics, cost, track-boundary rows with slack, bounds and path
linearisation) as one multiple-shooting NLP and solves it to convergence with IPOPT (exact
Hessian, MUMPS), warm-started from the same shifted plan. It is what one writes first with
CasADi's ``nlpsol``: the yardstick for the real-time iteration's speed.

:class:`AcadosRacer` races with acados's SQP-RTI of the same problem
(:class:`~crs_core.control.mpcc_acados.AcadosRti`) as acados's users run it: per call the
previous solution shifted by one stage as the guess, the path linearised at the guess's
progress, one ``solve()``, the first input; its ``solve()`` calls are timed from Python.
"""

from __future__ import annotations

import math
import time

import casadi as ca
import numpy as np

from crs_core.control.mpcc import Mpcc
from crs_core.control.mpcc_problem import FREE, MpccProblem

__all__ = ["AcadosRacer", "IpoptMpcc"]


class IpoptMpcc:
    """The MPCC problem as an NLP for IPOPT.

    Parameters
    ----------
    problem : MpccProblem
        The problem (model, horizon, rate); its symbolic stage functions are reused.
    tolerance : float
        IPOPT's convergence tolerance.
    max_iter : int
        IPOPT's iteration limit.
    """

    def __init__(self, problem: MpccProblem, tolerance: float = 1e-6, max_iter: int = 200):
        self.problem = problem
        N, nz, nv = problem.N, problem.nz, problem.nv
        Z, V = ca.SX.sym("Z", nz, N + 1), ca.SX.sym("V", nv, N)
        REF = ca.SX.sym("REF", 4, N + 1)
        w = ca.SX.sym("w", problem.w_sym.numel())
        p = ca.SX.sym("p", problem.model.np)
        half = ca.SX.sym("half")
        cost, gaps, boundary = 0, [], []
        for k in range(N):
            cost += problem.stage_cost(Z[:, k], V[:, k], REF[:, k], w, p)
            gaps.append(Z[:, k + 1] - problem.dynamics(Z[:, k], V[:, k], p))
            if k >= 1:
                contour = problem.contouring_error(Z[:, k], REF[:, k])
                boundary += [contour - V[3, k] - half, contour + V[3, k] + half]
        cost += problem.terminal_cost(Z[:, N], REF[:, N], w)
        variables = ca.vertcat(ca.vec(ca.vertcat(Z[:, :N], V)), Z[:, N])
        nlp = {
            "x": variables,
            "p": ca.vertcat(ca.vec(REF), w, p, half),
            "f": cost,
            "g": ca.vertcat(*gaps, *boundary),
        }
        options = {
            "ipopt": {"print_level": 0, "tol": tolerance, "max_iter": max_iter, "sb": "yes"},
            "print_time": False,
        }
        self._solver = ca.nlpsol("ipopt_mpcc", "ipopt", nlp, options)
        self._n_gaps = N * nz
        self._n_boundary = 2 * (N - 1)

    def solve(
        self,
        Z: np.ndarray,
        V: np.ndarray,
        refs: np.ndarray,
        weights: np.ndarray,
        p: np.ndarray,
        v_lower: np.ndarray,
        v_upper: np.ndarray,
        half_width: float,
    ) -> tuple[np.ndarray, np.ndarray, bool, int]:
        """Solve from the guess ``Z`` (N+1, nz), ``V`` (N, nv) with stage 0 fixed to ``Z[0]``.

        Returns the plan ``(Z, V)``, whether IPOPT converged, and its iteration count.
        """
        N, nz, nv = self.problem.N, self.problem.nz, self.problem.nv
        z_free = np.full(nz, FREE)
        lower = np.concatenate([np.concatenate((-z_free, v_lower))] * N + [-z_free])
        upper = np.concatenate([np.concatenate((z_free, v_upper))] * N + [z_free])
        lower[:nz] = upper[:nz] = Z[0]
        guess = np.concatenate((np.hstack((Z[:N], V)).ravel(), Z[N]))
        boundary_upper = np.tile([0.0, np.inf], N - 1)
        boundary_lower = np.tile([-np.inf, 0.0], N - 1)
        result = self._solver(
            x0=guess,
            p=np.concatenate((refs.ravel(), weights, p, [half_width])),
            lbx=lower,
            ubx=upper,
            lbg=np.concatenate((np.zeros(self._n_gaps), boundary_lower)),
            ubg=np.concatenate((np.zeros(self._n_gaps), boundary_upper)),
        )
        stats = self._solver.stats()
        w = np.asarray(result["x"], dtype=float).ravel()
        stages = w[: N * (nz + nv)].reshape(N, nz + nv)
        plan_Z = np.vstack((stages[:, :nz], w[N * (nz + nv) :]))
        return plan_Z, stages[:, nz:], bool(stats["success"]), int(stats["iter_count"])


class AcadosRacer:
    """acados's real-time iteration as a racing controller: ``racer(x) -> [delta, T]``.

    Per call: the stage state from ``x`` (progress by projection near the plan's, the previous
    command; below ``kinematic_speed`` the kinematic bicycle's lateral velocity and yaw rate,
    as :class:`~crs_core.control.mpcc.Mpcc` does, since the tire model is singular at rest),
    the previous solution shifted by one stage as acados's initial guess (a cold start: the
    MPCC's driving guess and ``cold_start_iterations`` solves), the path linearised at the
    guess's progress, one ``solve()``; the plan's first input, clipped to the limits. A failed
    solve keeps the shifted plan. No rollout, step check or safe stop: the bare solver.

    Parameters
    ----------
    mpcc : Mpcc
        The MPCC whose problem, path, weights, parameters and limits are raced (and whose
        driving guess starts a cold call).
    rti : AcadosRti, optional
        acados's iteration of ``mpcc.problem`` (built if not given).

    Attributes
    ----------
    solve_times : list of float
        Each call's time in ``solve()``, s (a cold call's solves summed).
    call_times : list of float
        Each whole call's time, s (state, shift, path, data in and out, ``solve()``).
    statuses, qp_iterations : list of int
        Each ``solve()``'s acados status and HPIPM iterations.
    mode : str
        The last call's: ``"solved"``, ``"fallback"`` (a failed solve: the shifted plan's input)
        or ``"stop"``.
    """

    def __init__(self, mpcc: Mpcc, rti=None) -> None:
        if rti is None:
            from crs_core.control.mpcc_acados import AcadosRti

            rti = AcadosRti(mpcc.problem)
        self.mpcc, self.rti = mpcc, rti
        self.settings = mpcc.settings
        self.solve_times: list[float] = []
        self.call_times: list[float] = []
        self.statuses: list[int] = []
        self.qp_iterations: list[int] = []
        self.mode = ""
        self.reset()

    def reset(self) -> None:
        """Forget the plan (the next call starts cold)."""
        self._Z: np.ndarray | None = None
        self._V: np.ndarray | None = None
        self._command = np.zeros(2)
        self._progress_speed = 0.0

    def stop(self, x: np.ndarray | None = None, reason: str = "") -> np.ndarray:
        """The MPCC's safe-stop command; forgets the plan."""
        self.reset()
        self.mode = "stop"
        return self.mpcc._stop_command(x)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        called = time.perf_counter()
        mpcc, s = self.mpcc, self.settings
        nxc = mpcc.model.nx
        state = np.array(x, dtype=float).ravel()[:nxc]
        vx = float(state[3])
        if abs(vx) < s.kinematic_speed:
            lf, lr = mpcc._wheelbase_parts
            tan_delta = math.tan(float(self._command[0]))
            state[4] = vx * lr * tan_delta / (lf + lr)
            state[5] = vx * tan_delta / (lf + lr)
        near = None if self._Z is None else float(self._Z[1, nxc])
        theta = mpcc.path.progress(state[0], state[1], near)
        z0 = np.concatenate((state, [theta], self._command, [self._progress_speed]))
        if self._Z is None or self._V is None:
            Z, V = mpcc._driving_guess(z0)
            iterations = s.cold_start_iterations
        else:
            Z = np.vstack((self._Z[1:], self._Z[-1:]))
            V = np.vstack((self._V[1:], self._V[-1:]))
            Z[0] = z0
            iterations = 1
        elapsed = 0.0
        plan = (Z, V)
        self.mode = "solved"
        for _ in range(iterations):
            refs = mpcc._references(Z[:, nxc])
            self.rti.load(
                Z, V, refs, mpcc._weights, mpcc.p, mpcc._v_lower, mpcc._v_upper, mpcc._half_width
            )
            started = time.perf_counter()
            status = self.rti.solve()
            elapsed += time.perf_counter() - started
            self.statuses.append(status)
            self.qp_iterations.append(self.rti.qp_iterations())
            Z, V = self.rti.plan()
            if status != 0 or not (np.all(np.isfinite(Z)) and np.all(np.isfinite(V))):
                Z, V = plan  # keep the shifted plan
                self.mode = "fallback"
                break
        self.solve_times.append(elapsed)
        self._Z, self._V = Z, V
        self._command = np.array(
            [
                min(max(float(V[0, 0]), -s.steer_max), s.steer_max),
                min(max(float(V[0, 1]), s.torque_min), s.torque_max),
            ]
        )
        self._progress_speed = float(V[0, 2])
        self.call_times.append(time.perf_counter() - called)
        return self._command.copy()
