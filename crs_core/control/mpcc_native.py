r"""The MPCC's real-time iteration as one compiled C call (``MpccSettings(solver="native")``).

One SQP iteration of :class:`~crs_core.control.mpcc_problem.MpccProblem` in a single ``ctypes``
call: the horizon's linearisation (the problem's own CasADi functions, generated to C), the
optimal-control QP handed stage by stage to HPIPM's Riccati-based interior point method, its
solution read back and checked, with no Python per stage and no sparse matrices in between.
HPIPM is acados's build (BLASFEO with AVX kernels, loaded by
:func:`~crs_core.acados_support.acados_template`); CasADi's own HPIPM, behind ``"hpipm"``, uses
BLASFEO's generic kernels.

The QP is the one ``"hpipm"`` solves, stated on HPIPM's stages directly:

- stage 0's state is the fixed :math:`z_0`, eliminated (HPIPM's ``nx[0] = 0``): the dynamics'
  offset becomes :math:`A_0 z_0 + c_0` and the cost's input gradient :math:`r_0 + S_0 z_0`;
- the inputs' bounds on every stage, the two boundary rows
  :math:`e_c - \sigma \le w/2`, :math:`e_c + \sigma \ge -w/2` on stages 1 to N-1 (their open
  sides at :data:`~crs_core.control.mpcc_problem.FREE`, as there);
- the states have no bounds (``"hpipm"``'s :math:`\pm` ``FREE`` never bind).

The library is built once per problem into the compile cache (the generated code's hash names
it) and needs acados's wheel (``./run.sh setup``).
"""

from __future__ import annotations

import ctypes
import math
import os

import numpy as np

from crs_core.acados_support import AcadosUnavailable, acados_template
from crs_core.codegen import compile_library
from crs_core.control.mpcc_problem import FREE, Iterate, MpccProblem

__all__ = ["NativeRti"]

#: HPIPM's return codes.
STATUS = {
    0: "success",
    1: "iteration limit",
    2: "step too small",
    3: "NaN in the solution",
    4: "inconsistent equalities",
    -1: "non-finite data in the linearisation",
}

_DRIVER = r"""
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <dlfcn.h>
#include "hpipm_d_ocp_qp.h"
#include "hpipm_d_ocp_qp_dim.h"
#include "hpipm_d_ocp_qp_ipm.h"
#include "hpipm_d_ocp_qp_sol.h"

#define N_ {N}
#define NZ {nz}
#define NV {nv}
#define NW (NZ + NV)
#define NR 4
#define FREE_ {free}

typedef struct {
    struct d_ocp_qp_dim dim;
    struct d_ocp_qp qp;
    struct d_ocp_qp_sol sol;
    struct d_ocp_qp_ipm_arg arg;
    struct d_ocp_qp_ipm_ws ws;
    void *blocks[5];
    const casadi_real *h_arg[64];
    casadi_real *h_res[64];
    casadi_int *iw;
    casadi_real *w;
    double A[NZ * NZ * N_], B[NZ * NV * N_], c[NZ * N_], H[NW * NW * N_], g[NW * N_];
    double C[NZ * N_], e0[N_], HN[NZ * NZ], gN[NZ];
} rti;

static void *aligned(size_t size) {
    void *p = NULL;
    return posix_memalign(&p, 64, size + 64) == 0 ? p : NULL;
}

/* the path of the library HPIPM's solver comes from (which build is in use) */
const char *crs_rti_hpipm_library(void) {
    Dl_info info;
    return dladdr((void *) d_ocp_qp_ipm_solve, &info) && info.dli_fname ? info.dli_fname : "";
}

void *crs_rti_create(int iter_max) {
    casadi_int sz_arg, sz_res, sz_iw, sz_w, a2, r2, i2, w2;
    mpcc_horizon_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
    mpcc_terminal_work(&a2, &r2, &i2, &w2);
    if (sz_arg > 64 || sz_res > 64 || a2 > 64 || r2 > 64) return NULL;
    rti *m = calloc(1, sizeof(rti));
    if (!m) return NULL;
    m->iw = calloc((sz_iw > i2 ? sz_iw : i2) + 1, sizeof(casadi_int));
    m->w = calloc((sz_w > w2 ? sz_w : w2) + 1, sizeof(casadi_real));
    int nx[N_ + 1], nu[N_ + 1], nbx[N_ + 1], nbu[N_ + 1], ng[N_ + 1], zero[N_ + 1];
    for (int k = 0; k <= N_; k++) {
        nx[k] = k == 0 ? 0 : NZ;
        nu[k] = nbu[k] = k < N_ ? NV : 0;
        ng[k] = k >= 1 && k < N_ ? 2 : 0;
        nbx[k] = zero[k] = 0;
    }
    m->blocks[0] = aligned(d_ocp_qp_dim_memsize(N_));
    d_ocp_qp_dim_create(N_, &m->dim, m->blocks[0]);
    d_ocp_qp_dim_set_all(nx, nu, nbx, nbu, ng, zero, zero, zero, &m->dim);
    m->blocks[1] = aligned(d_ocp_qp_memsize(&m->dim));
    d_ocp_qp_create(&m->dim, &m->qp, m->blocks[1]);
    m->blocks[2] = aligned(d_ocp_qp_sol_memsize(&m->dim));
    d_ocp_qp_sol_create(&m->dim, &m->sol, m->blocks[2]);
    m->blocks[3] = aligned(d_ocp_qp_ipm_arg_memsize(&m->dim));
    d_ocp_qp_ipm_arg_create(&m->dim, &m->arg, m->blocks[3]);
    d_ocp_qp_ipm_arg_set_default(SPEED_ABS, &m->arg);
    int warm = 1;
    d_ocp_qp_ipm_arg_set_iter_max(&iter_max, &m->arg);
    d_ocp_qp_ipm_arg_set_warm_start(&warm, &m->arg);
    m->blocks[4] = aligned(d_ocp_qp_ipm_ws_memsize(&m->dim, &m->arg));
    d_ocp_qp_ipm_ws_create(&m->dim, &m->arg, &m->ws, m->blocks[4]);
    int idxbu[NV];
    for (int i = 0; i < NV; i++) idxbu[i] = i;
    double D[2 * NV];
    memset(D, 0, sizeof(D));
    D[2 * (NV - 1)] = -1.0;    /* e_c - slack <= w/2 */
    D[2 * (NV - 1) + 1] = 1.0; /* e_c + slack >= -w/2 */
    for (int k = 0; k < N_; k++) {
        d_ocp_qp_set_idxbu(k, idxbu, &m->qp);
        if (k >= 1) d_ocp_qp_set_D(k, D, &m->qp);
    }
    return m;
}

void crs_rti_free(void *memory) {
    rti *m = memory;
    if (!m) return;
    for (int i = 0; i < 5; i++) free(m->blocks[i]);
    free(m->iw);
    free(m->w);
    free(m);
}

static int all_finite(const double *x, int n) {
    for (int i = 0; i < n; i++)
        if (!isfinite(x[i])) return 0;
    return 1;
}

/* One iteration from the guess Z (NZ x N+1), V (NV x N), path points REF (4 x N+1), all
   column-major; Z[:, 0] is the fixed initial state. Writes the plan into Zo, Vo and
   (iterations, status, violation) into out. Returns HPIPM's status, -1 for data that are not
   finite (nothing solved). */
int crs_rti_iterate(void *memory, const double *Z, const double *V, const double *REF,
                    const double *wt, const double *p, const double *lbv, const double *ubv,
                    double half, double *Zo, double *Vo, double *out) {
    rti *m = memory;
    const double *z0 = Z;
    m->h_arg[0] = Z; m->h_arg[1] = V; m->h_arg[2] = REF; m->h_arg[3] = wt; m->h_arg[4] = p;
    m->h_res[0] = m->A; m->h_res[1] = m->B; m->h_res[2] = m->c; m->h_res[3] = m->H;
    m->h_res[4] = m->g; m->h_res[5] = m->C; m->h_res[6] = m->e0;
    out[0] = 0; out[1] = -1; out[2] = INFINITY;
    if (mpcc_horizon(m->h_arg, m->h_res, m->iw, m->w, 0)) return -1;
    m->h_arg[0] = Z + NZ * N_; m->h_arg[1] = REF + NR * N_; m->h_arg[2] = wt;
    m->h_res[0] = m->HN; m->h_res[1] = m->gN;
    if (mpcc_terminal(m->h_arg, m->h_res, m->iw, m->w, 0)) return -1;
    if (!(all_finite(m->A, NZ * NZ * N_) && all_finite(m->B, NZ * NV * N_)
          && all_finite(m->c, NZ * N_) && all_finite(m->H, NW * NW * N_)
          && all_finite(m->g, NW * N_) && all_finite(m->C, NZ * N_)
          && all_finite(m->e0, N_) && all_finite(m->HN, NZ * NZ) && all_finite(m->gN, NZ)))
        return -1;
    double Q[NZ * NZ], S[NV * NZ], R[NV * NV], q[NZ], r[NV], b[NZ], Cg[2 * NZ];
    double lg[2], ug[2];
    for (int k = 0; k < N_; k++) {
        const double *A = m->A + k * NZ * NZ, *B = m->B + k * NZ * NV, *H = m->H + k * NW * NW;
        const double *g = m->g + k * NW;
        for (int j = 0; j < NZ; j++)
            for (int i = 0; i < NZ; i++) Q[i + NZ * j] = H[i + NW * j];
        for (int j = 0; j < NZ; j++)
            for (int i = 0; i < NV; i++) S[i + NV * j] = H[NZ + i + NW * j];
        for (int j = 0; j < NV; j++)
            for (int i = 0; i < NV; i++) R[i + NV * j] = H[NZ + i + NW * (NZ + j)];
        memcpy(q, g, NZ * sizeof(double));
        memcpy(r, g + NZ, NV * sizeof(double));
        memcpy(b, m->c + k * NZ, NZ * sizeof(double));
        if (k == 0) { /* z0 fixed: folded into the offset and the input gradient */
            for (int j = 0; j < NZ; j++) {
                for (int i = 0; i < NZ; i++) b[i] += A[i + NZ * j] * z0[j];
                for (int i = 0; i < NV; i++) r[i] += S[i + NV * j] * z0[j];
            }
        } else {
            d_ocp_qp_set_A(k, (double *) A, &m->qp);
            d_ocp_qp_set_Q(k, Q, &m->qp);
            d_ocp_qp_set_S(k, S, &m->qp);
            d_ocp_qp_set_q(k, q, &m->qp);
            for (int j = 0; j < NZ; j++) Cg[2 * j] = Cg[2 * j + 1] = m->C[k * NZ + j];
            lg[0] = -FREE_; ug[0] = half - m->e0[k];
            lg[1] = -half - m->e0[k]; ug[1] = FREE_;
            d_ocp_qp_set_C(k, Cg, &m->qp);
            d_ocp_qp_set_lg(k, lg, &m->qp);
            d_ocp_qp_set_ug(k, ug, &m->qp);
            d_ocp_qp_sol_set_x(k, (double *) (Z + k * NZ), &m->sol);
        }
        d_ocp_qp_set_B(k, (double *) B, &m->qp);
        d_ocp_qp_set_b(k, b, &m->qp);
        d_ocp_qp_set_R(k, R, &m->qp);
        d_ocp_qp_set_r(k, r, &m->qp);
        d_ocp_qp_set_lbu(k, (double *) lbv, &m->qp);
        d_ocp_qp_set_ubu(k, (double *) ubv, &m->qp);
        d_ocp_qp_sol_set_u(k, (double *) (V + k * NV), &m->sol);
    }
    d_ocp_qp_set_Q(N_, m->HN, &m->qp);
    d_ocp_qp_set_q(N_, m->gN, &m->qp);
    d_ocp_qp_sol_set_x(N_, (double *) (Z + N_ * NZ), &m->sol);

    d_ocp_qp_ipm_solve(&m->qp, &m->sol, &m->arg, &m->ws);
    int status = 0, iterations = 0;
    d_ocp_qp_ipm_get_status(&m->ws, &status);
    d_ocp_qp_ipm_get_iter(&m->ws, &iterations);

    memcpy(Zo, z0, NZ * sizeof(double));
    for (int k = 0; k < N_; k++) {
        d_ocp_qp_sol_get_u(k, &m->sol, Vo + k * NV);
        d_ocp_qp_sol_get_x(k + 1, &m->sol, Zo + (k + 1) * NZ);
    }
    /* the largest violation: input bounds, boundary rows, dynamics */
    double worst = 0.0;
    for (int k = 0; k < N_; k++) {
        const double *v = Vo + k * NV, *z = Zo + k * NZ, *zn = Zo + (k + 1) * NZ;
        for (int i = 0; i < NV; i++) {
            worst = fmax(worst, v[i] - ubv[i]);
            worst = fmax(worst, lbv[i] - v[i]);
        }
        if (k >= 1) {
            double e = m->e0[k];
            for (int j = 0; j < NZ; j++) e += m->C[k * NZ + j] * z[j];
            worst = fmax(worst, e - v[NV - 1] - half);
            worst = fmax(worst, -half - e - v[NV - 1]);
        }
        const double *A = m->A + k * NZ * NZ, *B = m->B + k * NZ * NV;
        for (int i = 0; i < NZ; i++) {
            double x = m->c[k * NZ + i] - zn[i];
            for (int j = 0; j < NZ; j++) x += A[i + NZ * j] * z[j];
            for (int j = 0; j < NV; j++) x += B[i + NZ * j] * v[j];
            worst = fmax(worst, fabs(x));
        }
    }
    if (!all_finite(Zo, NZ * (N_ + 1)) || !all_finite(Vo, NV * N_)) worst = INFINITY;
    out[0] = iterations; out[1] = status; out[2] = worst;
    return status;
}
"""


class NativeRti:
    """One real-time iteration of ``problem`` per :meth:`iterate`, in one compiled call.

    Parameters
    ----------
    problem : MpccProblem
        The MPCC's problem (model, horizon, rate, weights, QP iteration limit).

    Raises
    ------
    AcadosUnavailable
        acados's wheel (whose HPIPM this links) is not installed.
    """

    def __init__(self, problem: MpccProblem) -> None:
        import acados

        acados_template()  # acados's BLASFEO and HPIPM in the process's global scope
        self.N, self.nz, self.nv = problem.N, problem.nz, problem.nv
        #: largest constraint violation of a usable plan
        self.tolerance = problem.settings.feasibility_tolerance
        include = os.path.join(acados.INCLUDE_DIR, "{}", "include")
        source = _DRIVER
        for key, value in (("N", self.N), ("nz", self.nz), ("nv", self.nv), ("free", FREE)):
            source = source.replace("{" + key + "}", repr(value))
        horizon, terminal = problem.horizon_linearization()
        try:
            library = compile_library(
                [horizon, terminal],
                f"mpcc_native_{problem.model.tag}_{problem.model.n_base_stations}bs_n{self.N}"
                f"_{round(1e6 / problem.settings.rate_hz)}",
                source,
                ("-I" + include.format("hpipm"), "-I" + include.format("blasfeo"), "-D_GNU_SOURCE"),
            )
        except RuntimeError as error:
            raise AcadosUnavailable(f"the native MPCC iteration does not build: {error}") from error
        pointer, double = ctypes.c_void_p, ctypes.c_double
        create = library.crs_rti_create
        create.restype, create.argtypes = pointer, [ctypes.c_int]
        self._free = library.crs_rti_free
        self._free.argtypes = [pointer]
        self._iterate = library.crs_rti_iterate
        self._iterate.restype = ctypes.c_int
        self._iterate.argtypes = [pointer] * 8 + [double] + [pointer] * 3
        hpipm = library.crs_rti_hpipm_library
        hpipm.restype = ctypes.c_char_p
        #: the file HPIPM's solver was loaded from (acados's build)
        self.hpipm_library = hpipm().decode()
        self._library = library
        self._memory = create(int(problem.settings.qp_max_iter))
        if not self._memory:
            raise AcadosUnavailable("the native MPCC iteration: HPIPM's memory not created")
        self._Z = np.zeros((self.N + 1, self.nz))
        self._V = np.zeros((self.N, self.nv))
        self._out = np.zeros(3)

    def __del__(self) -> None:
        memory = getattr(self, "_memory", None)
        if memory:
            self._free(memory)
            self._memory = None

    def iterate(
        self,
        Z: np.ndarray,
        V: np.ndarray,
        refs: np.ndarray,
        weights: np.ndarray,
        p: np.ndarray,
        v_lower: np.ndarray,
        v_upper: np.ndarray,
        half_width: float,
    ) -> Iterate:
        """One SQP iteration from the guess ``Z`` (N+1, nz; its row 0 the fixed state),
        ``V`` (N, nv), the path linearised at ``refs`` (N+1, 4): the new plan, usable when
        finite and within the settings' ``feasibility_tolerance`` of every constraint (an
        iteration limit counts)."""
        arrays = [
            np.ascontiguousarray(a, dtype=float) for a in (Z, V, refs, weights, p, v_lower, v_upper)
        ]
        status = self._iterate(
            self._memory,
            *(a.ctypes.data for a in arrays),
            float(half_width),
            self._Z.ctypes.data,
            self._V.ctypes.data,
            self._out.ctypes.data,
        )
        iterations, _, violation = self._out
        if status < 0:
            return Iterate(Z, V, False, math.inf, -1, STATUS[-1])
        return Iterate(
            self._Z.copy(),
            self._V.copy(),
            bool(violation <= self.tolerance),  # as "hpipm": a feasible iteration limit counts
            float(violation),
            int(iterations),
            STATUS.get(status, str(status)),
        )
