"""Peer controller for comparison: the same MPCC problem as a plain NLP solved by IPOPT.

:class:`IpoptMpcc` states the optimal control problem of :mod:`crs_core.control.mpcc_problem`
(the same stage functions, dynamics, cost, track-boundary rows with slack, bounds and path
linearisation) as one multiple-shooting NLP and solves it to convergence with IPOPT (exact
Hessian, MUMPS), warm-started from the same shifted plan. It is what one writes first with
CasADi's ``nlpsol``: the yardstick for the real-time iteration's speed (``crs bench control``).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from crs_core.control.mpcc_problem import FREE, MpccProblem

__all__ = ["IpoptMpcc"]


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
