r"""The MHE's Gauss-Newton step as one compiled C call.

:class:`NativeGaussNewton` does what ``MovingHorizonEstimator._gauss_newton_step`` does in numpy
and LAPACK's banded Cholesky (the reference it is tested against), in a single ``ctypes`` call:
the horizon's Gauss-Newton blocks (the generated ``mhe_gn``), the arrival cost and the unused
nodes folded in, the block-tridiagonal normal equations factorised block by block
(:math:`L_j L_j^\top = D_j - B_j B_j^\top`, :math:`B_j = O_{j-1}^\top L_{j-1}^{-\top}`), the step
by forward and back substitution, the newest node's covariance
:math:`(L_M L_M^\top)^{-1}`, and the backtracking test on the cost (the generated
``mhe_cost``), with no Python per node. Its C (:meth:`NativeGaussNewton.driver`) is compiled
into the library of the MHE's generated functions.
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence

import casadi as ca
import numpy as np

__all__ = ["NativeGaussNewton"]


_DRIVER = r"""
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define NX {nx}
#define M_ {M}
#define NN (M_ + 1)
#define NY {ny}
#define LM_FLOOR 1e-9

typedef struct {
    const casadi_real *arg[64];
    casadi_real *res[64];
    casadi_int *iw;
    casadi_real *w;
    double D[NX * NX * NN], O[NX * NX * M_], G[NX * NN], cost, RY[NY * NN], S0[NX * NX];
    double g0b[NX];
    double L[NX * NX * NN], B[NX * NX * NN], y[NX * NN], step[NX * NN], cand[NX * NN];
} gn;

void *crs_gn_create(void) {
    casadi_int a1, r1, i1, w1, a2, r2, i2, w2;
    mhe_gn_work(&a1, &r1, &i1, &w1);
    mhe_cost_work(&a2, &r2, &i2, &w2);
    if (a1 > 64 || r1 > 64 || a2 > 64 || r2 > 64) return NULL;
    gn *m = calloc(1, sizeof(gn));
    if (!m) return NULL;
    m->iw = calloc((i1 > i2 ? i1 : i2) + 1, sizeof(casadi_int));
    m->w = calloc((w1 > w2 ? w1 : w2) + 1, sizeof(casadi_real));
    return m;
}

void crs_gn_free(void *memory) {
    gn *m = memory;
    if (!m) return;
    free(m->iw);
    free(m->w);
    free(m);
}

/* lower Cholesky factor of the symmetric a (column-major NX x NX) in place; 0 if not PD */
static int cholesky(double *a) {
    for (int j = 0; j < NX; j++) {
        double d = a[j + NX * j];
        for (int k = 0; k < j; k++) d -= a[j + NX * k] * a[j + NX * k];
        if (!(d > 0.0)) return 0;
        d = sqrt(d);
        a[j + NX * j] = d;
        for (int i = j + 1; i < NX; i++) {
            double s = a[i + NX * j];
            for (int k = 0; k < j; k++) s -= a[i + NX * k] * a[j + NX * k];
            a[i + NX * j] = s / d;
        }
        for (int i = 0; i < j; i++) a[i + NX * j] = 0.0;
    }
    return 1;
}

/* x <- L^-1 x and x <- L^-T x for a lower factor L */
static void lower_solve(const double *L, double *x) {
    for (int i = 0; i < NX; i++) {
        double s = x[i];
        for (int k = 0; k < i; k++) s -= L[i + NX * k] * x[k];
        x[i] = s / L[i + NX * i];
    }
}

static void lower_transposed_solve(const double *L, double *x) {
    for (int i = NX - 1; i >= 0; i--) {
        double s = x[i];
        for (int k = i + 1; k < NX; k++) s -= L[k + NX * i] * x[k];
        x[i] = s / L[i + NX * i];
    }
}

static double arrival_cost(const double *X, int first, const double *info, const double *mean) {
    double d[NX], c = 0.0;
    for (int i = 0; i < NX; i++) d[i] = X[first * NX + i] - mean[i];
    for (int j = 0; j < NX; j++)
        for (int i = 0; i < NX; i++) c += d[i] * info[i + NX * j] * d[j];
    return c;
}

/* the return codes are StepOutcome's (crs_core/estimation/mhe_problem.py) */
/* in: the 10 inputs of mhe_gn / mhe_cost (X first), the first node in use, its prior's
   information (NX x NX) and mean, the step fractions to try; out: X_out, the newest node's
   covariance, the weighted residuals (on a non-finite cost), the blocks the marginalisation of
   node 0 needs (D0, O0, S0, G0, g0b, x1: 3 NX^2 + 3 NX values). Returns a StepOutcome. */
int crs_gn_step(void *memory, const double **inputs, int first, const double *info,
                const double *mean, const double *fractions, int n_fractions, double *X_out,
                double *covariance, double *residuals, double *blocks) {
    gn *m = memory;
    const double *X = inputs[0];
    for (int i = 0; i < 10; i++) m->arg[i] = inputs[i];
    m->res[0] = m->D; m->res[1] = m->O; m->res[2] = m->G; m->res[3] = &m->cost;
    m->res[4] = m->RY; m->res[5] = m->S0; m->res[6] = m->g0b;
    if (mhe_gn(m->arg, m->res, m->iw, m->w, 0) || !isfinite(m->cost)) {
        memcpy(residuals, m->RY, sizeof(m->RY));
        return 1;
    }
    /* the prior on the first node in use; nodes before it held where they are */
    double *Df = m->D + first * NX * NX, *Gf = m->G + first * NX;
    for (int j = 0; j < NX; j++)
        for (int i = 0; i < NX; i++) {
            Df[i + NX * j] += info[i + NX * j];
            Gf[i] += info[i + NX * j] * (X[first * NX + j] - mean[j]);
        }
    for (int n = 0; n < first; n++) {
        double *D = m->D + n * NX * NX;
        memset(D, 0, NX * NX * sizeof(double));
        for (int i = 0; i < NX; i++) D[i + NX * i] = 1.0;
        memset(m->G + n * NX, 0, NX * sizeof(double));
        if (n < M_) memset(m->O + n * NX * NX, 0, NX * NX * sizeof(double));
    }
    memcpy(blocks, m->D, NX * NX * sizeof(double));
    memcpy(blocks + NX * NX, m->O, NX * NX * sizeof(double));
    memcpy(blocks + 2 * NX * NX, m->S0, NX * NX * sizeof(double));
    memcpy(blocks + 3 * NX * NX, m->G, NX * sizeof(double));
    memcpy(blocks + 3 * NX * NX + NX, m->g0b, NX * sizeof(double));
    memcpy(blocks + 3 * NX * NX + 2 * NX, X + NX, NX * sizeof(double));
    /* block Cholesky: L_n L_n^T = D_n - B_n B_n^T, B_n = O_{n-1}^T L_{n-1}^-T */
    for (int n = 0; n < NN; n++) {
        double *L = m->L + n * NX * NX, *B = m->B + n * NX * NX;
        memcpy(L, m->D + n * NX * NX, NX * NX * sizeof(double));
        for (int i = 0; i < NX; i++) L[i + NX * i] += LM_FLOOR;
        if (n > 0) {
            const double *Lp = m->L + (n - 1) * NX * NX, *Op = m->O + (n - 1) * NX * NX;
            /* row i of B_n solves L_{n-1} b = (column i of O_{n-1}) */
            for (int i = 0; i < NX; i++) {
                double b[NX];
                for (int k = 0; k < NX; k++) b[k] = Op[k + NX * i];
                lower_solve(Lp, b);
                for (int k = 0; k < NX; k++) B[i + NX * k] = b[k];
            }
            for (int j = 0; j < NX; j++)
                for (int i = 0; i < NX; i++) {
                    double s = 0.0;
                    for (int k = 0; k < NX; k++) s += B[i + NX * k] * B[j + NX * k];
                    L[i + NX * j] -= s;
                }
        }
        if (!cholesky(L)) return 2;
    }
    /* forward: L y = -G; back: L^T s = y */
    for (int n = 0; n < NN; n++) {
        double *y = m->y + n * NX;
        for (int i = 0; i < NX; i++) y[i] = -m->G[n * NX + i];
        if (n > 0) {
            const double *B = m->B + n * NX * NX, *yp = m->y + (n - 1) * NX;
            for (int i = 0; i < NX; i++)
                for (int k = 0; k < NX; k++) y[i] -= B[i + NX * k] * yp[k];
        }
        lower_solve(m->L + n * NX * NX, y);
    }
    for (int n = NN - 1; n >= 0; n--) {
        double *s = m->step + n * NX;
        memcpy(s, m->y + n * NX, NX * sizeof(double));
        if (n < NN - 1) {
            const double *B = m->B + (n + 1) * NX * NX, *sn = m->step + (n + 1) * NX;
            for (int i = 0; i < NX; i++)
                for (int k = 0; k < NX; k++) s[i] -= B[k + NX * i] * sn[k];
        }
        lower_transposed_solve(m->L + n * NX * NX, s);
    }
    for (int i = 0; i < NX * NN; i++)
        if (!isfinite(m->step[i])) return 3;
    /* backtracking on the cost, arrival cost included */
    double before = m->cost + arrival_cost(X, first, info, mean);
    for (int f = 0; f < n_fractions; f++) {
        for (int i = 0; i < NX * NN; i++) m->cand[i] = X[i] + fractions[f] * m->step[i];
        m->arg[0] = m->cand;
        double cost;
        m->res[0] = &cost;
        if (mhe_cost(m->arg, m->res, m->iw, m->w, 0)) continue;
        double after = cost + arrival_cost(m->cand, first, info, mean);
        if (isfinite(after) && after <= before * (1 + 1e-9) + 1e-12) {
            memcpy(X_out, m->cand, NX * NN * sizeof(double));
            const double *L = m->L + M_ * NX * NX;
            for (int j = 0; j < NX; j++) { /* column j of L^-T L^-1 */
                double e[NX];
                memset(e, 0, sizeof(e));
                e[j] = 1.0;
                lower_solve(L, e);
                lower_transposed_solve(L, e);
                for (int i = 0; i < NX; i++) covariance[i + NX * j] = e[i];
            }
            return 0;
        }
    }
    return 4;
}
"""


class NativeGaussNewton:
    """One Gauss-Newton step of the MHE's window per :meth:`step`, in one compiled call.

    Parameters
    ----------
    library : ctypes.CDLL
        The compiled library of the window's ``mhe_gn`` and ``mhe_cost``
        (:func:`~crs_core.estimation.mhe_problem.build_mhe_function`) with :meth:`driver`
        (:func:`~crs_core.codegen.compile_functions`).
    blocks : casadi.Function
        The window's ``mhe_gn`` (its sizes).
    step_fractions : sequence of float
        The step lengths tried, in order, until the cost does not rise.

    Raises
    ------
    RuntimeError
        The step's memory could not be allocated.
    """

    @staticmethod
    def driver(blocks: ca.Function) -> str:
        """The step's C for the window of ``mhe_gn`` ``blocks``, to be compiled with it."""
        source = _DRIVER
        sizes = (("nx", blocks.size1_in(0)), ("M", blocks.size2_in(0) - 1))
        for key, value in (*sizes, ("ny", blocks.size1_out(4))):
            source = source.replace("{" + key + "}", str(value))
        return source

    def __init__(
        self, library: ctypes.CDLL, blocks: ca.Function, step_fractions: Sequence[float]
    ) -> None:
        self.nx = blocks.size1_in(0)
        self.nodes = blocks.size2_in(0)
        self.ny = blocks.size1_out(4)
        pointer = ctypes.c_void_p
        create = library.crs_gn_create
        create.restype = pointer
        self._free = library.crs_gn_free
        self._free.argtypes = [pointer]
        self._step = library.crs_gn_step
        self._step.restype = ctypes.c_int
        self._step.argtypes = [pointer, pointer, ctypes.c_int, pointer, pointer, pointer]
        self._step.argtypes += [ctypes.c_int] + [pointer] * 4
        self._library = library
        self._memory = create()
        if not self._memory:
            raise RuntimeError("the MHE's native step: memory not created")
        self._fractions = np.asarray(step_fractions, dtype=float)
        nx, nodes = self.nx, self.nodes
        #: the accepted window (nx, nodes), after a taken step
        self.X = np.zeros((nx, nodes), order="F")
        #: the newest node's covariance, after a taken step
        self.covariance = np.zeros((nx, nx), order="F")
        #: the weighted measurement residuals (ny, nodes), after a non-finite cost
        self.residuals = np.zeros((self.ny, nodes), order="F")
        self._blocks = np.zeros(3 * nx * nx + 3 * nx)
        self._inputs = (ctypes.c_void_p * 10)()

    def __del__(self) -> None:
        memory = getattr(self, "_memory", None)
        if memory:
            self._free(memory)
            self._memory = None

    def step(
        self,
        inputs: Sequence[np.ndarray],
        first: int,
        information: np.ndarray,
        mean: np.ndarray,
    ) -> int:
        """One step from the window ``inputs[0]`` (the ten inputs of ``mhe_gn``), the prior
        ``information`` / ``mean`` on node ``first``; returns a
        :class:`~crs_core.estimation.mhe_problem.StepOutcome` code (:attr:`X`,
        :attr:`covariance` or :attr:`residuals` hold its results)."""
        # addresses as integers: an array's ``.ctypes`` object passed as an argument leaves a
        # reference cycle per call, garbage the long-stream memory test saw grow
        arrays = [np.asfortranarray(a, dtype=float) for a in inputs]
        for i, array in enumerate(arrays):
            self._inputs[i] = array.ctypes.data
        information = np.asfortranarray(information, dtype=float)
        mean = np.ascontiguousarray(mean, dtype=float)
        return int(
            self._step(
                self._memory,
                self._inputs,
                int(first),
                information.ctypes.data,
                mean.ctypes.data,
                self._fractions.ctypes.data,
                self._fractions.size,
                self.X.ctypes.data,
                self.covariance.ctypes.data,
                self.residuals.ctypes.data,
                self._blocks.ctypes.data,
            )
        )

    def marginalization_blocks(self) -> tuple[np.ndarray, ...]:
        """``(D0, O0, S0, g0, g0b, x1)`` of the last step (after the prior and the unused
        nodes were folded in), as the marginalisation of node 0 takes them."""
        nx, b = self.nx, self._blocks
        square = nx * nx
        return (
            b[:square].reshape((nx, nx), order="F").copy(),
            b[square : 2 * square].reshape((nx, nx), order="F").copy(),
            b[2 * square : 3 * square].reshape((nx, nx), order="F").copy(),
            b[3 * square : 3 * square + nx].copy(),
            b[3 * square + nx : 3 * square + 2 * nx].copy(),
            b[3 * square + 2 * nx :].copy(),
        )
