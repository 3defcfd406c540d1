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
from typing import Any

import numpy as np

from crs_core.acados_support import AcadosUnavailable, acados_template
from crs_core.codegen import CompiledFunction, compile_functions
from crs_core.control.mpcc_problem import FREE, Iterate, MpccProblem, SqpStep
from crs_core.control.reference_path import ReferencePath

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
#: :meth:`NativeRti.sqp`'s answer for a guess in which the car stands.
STANDING = -2

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
#define NXC {nxc}
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
    const casadi_real *f_arg[64];
    casadi_real *f_res[64];
    casadi_int *iw;
    casadi_real *w;
    double A[NZ * NZ * N_], B[NZ * NV * N_], c[NZ * N_], H[NW * NW * N_], g[NW * N_];
    double C[NZ * N_], e0[N_], HN[NZ * NZ], gN[NZ];
    /* the reference path: a piecewise cubic, coefficients [piece][power][value] */
    int pieces;
    double length, *breaks, *coefs;
    /* the QP's plan, and a trial step's inputs, states and path points */
    double Zq[NZ * (N_ + 1)], Vq[NV * N_], Zt[NZ * (N_ + 1)], Vt[NV * N_], Rt[NR * (N_ + 1)];
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

void crs_rti_free(void *memory) {
    rti *m = memory;
    if (!m) return;
    for (int i = 0; i < 5; i++) free(m->blocks[i]);
    free(m->iw);
    free(m->w);
    free(m->breaks);
    free(m->coefs);
    free(m);
}

#define WORK(f) do { \
    casadi_int a_, r_, i_, w_; \
    f##_work(&a_, &r_, &i_, &w_); \
    if (a_ > 64 || r_ > 64) return NULL; \
    if (i_ > n_iw) n_iw = i_; \
    if (w_ > n_w) n_w = w_; \
} while (0)

/* breaks: pieces + 1 arc lengths from 0 to the lap length; coefs: (4, pieces, 6) C order,
   highest power first, of x, y and their first and second derivatives */
void *crs_rti_create(int iter_max, int pieces, const double *breaks, const double *coefs) {
    casadi_int n_iw = 0, n_w = 0;
    WORK(mpcc_stage);
    WORK(mpcc_terminal);
    WORK(mpcc_merit);
    WORK(mpcc_dynamics);
    rti *m = calloc(1, sizeof(rti));
    if (!m) return NULL;
    m->iw = calloc(n_iw + 1, sizeof(casadi_int));
    m->w = calloc(n_w + 1, sizeof(casadi_real));
    m->pieces = pieces;
    m->length = breaks[pieces];
    m->breaks = malloc((pieces + 1) * sizeof(double));
    m->coefs = malloc(24 * pieces * sizeof(double));
    memcpy(m->breaks, breaks, (pieces + 1) * sizeof(double));
    for (int i = 0; i < pieces; i++)
        for (int k = 0; k < 4; k++)
            for (int j = 0; j < 6; j++)
                m->coefs[24 * i + 6 * k + j] = coefs[(k * pieces + i) * 6 + j];
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

static int all_finite(const double *x, int n) {
    for (int i = 0; i < n; i++)
        if (!isfinite(x[i])) return 0;
    return 1;
}

/* [X, Y, heading, theta] of the path at arc length theta (any real: reduced modulo the lap) */
static void path_point(const rti *m, double theta, double *ref) {
    double s = fmod(theta, m->length);
    if (s < 0) s += m->length;
    int lo = 0, hi = m->pieces;
    while (hi - lo > 1) {
        int mid = (lo + hi) / 2;
        if (m->breaks[mid] <= s) lo = mid; else hi = mid;
    }
    double d = s - m->breaks[lo], v[6];
    const double *c = m->coefs + 24 * lo;
    for (int j = 0; j < 6; j++) v[j] = ((c[j] * d + c[6 + j]) * d + c[12 + j]) * d + c[18 + j];
    ref[0] = v[0]; ref[1] = v[1]; ref[2] = atan2(v[3], v[2]); ref[3] = theta;
}

static int linearize_stage(rti *m, int k, const double *z, const double *v, const double *ref,
                           const double *wt, const double *p) {
    m->f_arg[0] = z; m->f_arg[1] = v; m->f_arg[2] = ref; m->f_arg[3] = wt; m->f_arg[4] = p;
    m->f_res[0] = m->A + k * NZ * NZ; m->f_res[1] = m->B + k * NZ * NV;
    m->f_res[2] = m->c + k * NZ; m->f_res[3] = m->H + k * NW * NW; m->f_res[4] = m->g + k * NW;
    m->f_res[5] = m->C + k * NZ; m->f_res[6] = m->e0 + k;
    return mpcc_stage(m->f_arg, m->f_res, m->iw, m->w, 0);
}

static int linearize_terminal(rti *m, const double *z, const double *ref, const double *wt) {
    m->f_arg[0] = z; m->f_arg[1] = ref; m->f_arg[2] = wt;
    m->f_res[0] = m->HN; m->f_res[1] = m->gN;
    return mpcc_terminal(m->f_arg, m->f_res, m->iw, m->w, 0);
}

static int linearization_finite(const rti *m) {
    return all_finite(m->A, NZ * NZ * N_) && all_finite(m->B, NZ * NV * N_)
        && all_finite(m->c, NZ * N_) && all_finite(m->H, NW * NW * N_)
        && all_finite(m->g, NW * N_) && all_finite(m->C, NZ * N_)
        && all_finite(m->e0, N_) && all_finite(m->HN, NZ * NZ) && all_finite(m->gN, NZ);
}

static int merit(rti *m, const double *Z, const double *V, const double *REF, const double *wt,
                 const double *p, double half, double *cost) {
    m->f_arg[0] = Z; m->f_arg[1] = V; m->f_arg[2] = REF; m->f_arg[3] = wt; m->f_arg[4] = p;
    m->f_arg[5] = &half;
    m->f_res[0] = cost;
    return mpcc_merit(m->f_arg, m->f_res, m->iw, m->w, 0);
}

/* the stage states of V from z0 under the model, and the path at each stage's progress */
static int roll_out(rti *m, const double *z0, const double *V, const double *p, double *Z,
                    double *REF) {
    memcpy(Z, z0, NZ * sizeof(double));
    for (int k = 0; k < N_; k++) {
        path_point(m, Z[k * NZ + NXC], REF + k * NR);
        m->f_arg[0] = Z + k * NZ; m->f_arg[1] = V + k * NV; m->f_arg[2] = p;
        m->f_res[0] = Z + (k + 1) * NZ;
        if (mpcc_dynamics(m->f_arg, m->f_res, m->iw, m->w, 0)) return 1;
    }
    path_point(m, Z[N_ * NZ + NXC], REF + N_ * NR);
    return 0;
}

/* HPIPM on the linearisation in m (the guess Z, V its warm start); the plan into Zo, Vo and
   (iterations, status, violation) into out */
static int solve_qp(rti *m, const double *Z, const double *V, const double *lbv,
                    const double *ubv, double half, double *Zo, double *Vo, double *out) {
    const double *z0 = Z;
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

/* One iteration from the guess Z (NZ x N+1), V (NV x N), path points REF (4 x N+1), all
   column-major; Z[:, 0] is the fixed initial state. Writes the plan into Zo, Vo and
   (iterations, status, violation) into out. Returns HPIPM's status, -1 for data that are not
   finite (nothing solved). */
int crs_rti_iterate(void *memory, const double *Z, const double *V, const double *REF,
                    const double *wt, const double *p, const double *lbv, const double *ubv,
                    double half, double *Zo, double *Vo, double *out) {
    rti *m = memory;
    out[0] = 0; out[1] = -1; out[2] = INFINITY;
    for (int k = 0; k < N_; k++)
        if (linearize_stage(m, k, Z + k * NZ, V + k * NV, REF + k * NR, wt, p)) return -1;
    if (linearize_terminal(m, Z + N_ * NZ, REF + N_ * NR, wt)) return -1;
    if (!linearization_finite(m)) return -1;
    return solve_qp(m, Z, V, lbv, ubv, half, Zo, Vo, out);
}

/* One SQP iteration of a call from the car's stage state z0 with the inputs V (NV x N): V
   rolled out from z0 (the states from the linearisation: z+ = A z + B v + c) with the path at
   each stage's progress (the guess Zg, Rg), the QP, and the step check: the first of the QP's
   step's fractions (n_fractions of them) whose rollout's merit is no more than the guess's,
   else the cheapest, else the guess (the plan into Zo, Vo). With standing >= 0, a guess whose
   largest v_x is below it returns -2 before the QP. out: iterations, status, violation (as
   crs_rti_iterate's), the contouring error at z0, the guess's merit, the plan's merit.
   Returns HPIPM's status, -1 for a linearisation that is not finite, -2 for a standing guess;
   Zo, Vo hold the guess unless the QP's plan passed the violation check (tolerance). */
int crs_rti_sqp(void *memory, const double *z0, const double *V, const double *wt,
                const double *p, const double *lbv, const double *ubv, double half,
                double standing, double tolerance, const double *fractions, int n_fractions,
                double *Zg, double *Rg, double *Zo, double *Vo, double *out) {
    rti *m = memory;
    out[0] = 0; out[1] = -1; out[2] = INFINITY; out[3] = NAN; out[4] = NAN; out[5] = NAN;
    memcpy(Zg, z0, NZ * sizeof(double));
    for (int k = 0; k < N_; k++) {
        const double *z = Zg + k * NZ, *v = V + k * NV;
        path_point(m, z[NXC], Rg + k * NR);
        if (linearize_stage(m, k, z, v, Rg + k * NR, wt, p)) return -1;
        const double *A = m->A + k * NZ * NZ, *B = m->B + k * NZ * NV;
        double *zn = Zg + (k + 1) * NZ;
        for (int i = 0; i < NZ; i++) {
            double x = m->c[k * NZ + i];
            for (int j = 0; j < NZ; j++) x += A[i + NZ * j] * z[j];
            for (int j = 0; j < NV; j++) x += B[i + NZ * j] * v[j];
            zn[i] = x;
        }
    }
    path_point(m, Zg[N_ * NZ + NXC], Rg + N_ * NR);
    if (linearize_terminal(m, Zg + N_ * NZ, Rg + N_ * NR, wt)) return -1;
    double contour = m->e0[0];
    for (int j = 0; j < NZ; j++) contour += m->C[j] * z0[j];
    out[3] = contour;
    memcpy(Zo, Zg, NZ * (N_ + 1) * sizeof(double));
    memcpy(Vo, V, NV * N_ * sizeof(double));
    if (standing >= 0) {
        double fastest = -INFINITY;
        for (int k = 0; k <= N_; k++) fastest = fmax(fastest, Zg[k * NZ + 3]);
        if (!(fastest >= standing)) return -2;
    }
    if (!linearization_finite(m)) return -1;
    double reference = NAN, cost = NAN;
    if (merit(m, Zg, V, Rg, wt, p, half, &reference)) return -1;
    out[4] = out[5] = reference;
    int status = solve_qp(m, Zg, V, lbv, ubv, half, m->Zq, m->Vq, out);
    if (!(out[2] <= tolerance)) return status;
    double best = reference;
    for (int f = 0; f < n_fractions; f++) {
        for (int i = 0; i < NV * N_; i++) m->Vt[i] = V[i] + fractions[f] * (m->Vq[i] - V[i]);
        if (roll_out(m, z0, m->Vt, p, m->Zt, m->Rt)
            || merit(m, m->Zt, m->Vt, m->Rt, wt, p, half, &cost))
            cost = NAN;
        if (cost < best) {
            best = cost;
            memcpy(Zo, m->Zt, NZ * (N_ + 1) * sizeof(double));
            memcpy(Vo, m->Vt, NV * N_ * sizeof(double));
        }
        if (cost <= reference) break;
    }
    out[5] = best;
    return status;
}
"""


class NativeRti:
    """One real-time iteration of ``problem`` per :meth:`iterate` (or per :meth:`sqp`, with its
    rollouts and step check), in one compiled call.

    Parameters
    ----------
    problem : MpccProblem
        The MPCC's problem (model, horizon, rate, weights, QP iteration limit).
    path : ReferencePath
        The path the contouring follows (evaluated in the compiled call).

    Raises
    ------
    AcadosUnavailable
        acados's wheel (whose HPIPM this links) is not installed.
    """

    def __init__(self, problem: MpccProblem, path: ReferencePath) -> None:
        import acados

        acados_template()  # acados's BLASFEO and HPIPM in the process's global scope
        self.N, self.nz, self.nv = problem.N, problem.nz, problem.nv
        #: largest constraint violation of a usable plan
        self.tolerance = problem.settings.feasibility_tolerance
        include = os.path.join(acados.INCLUDE_DIR, "{}", "include")
        source = _DRIVER
        sizes = {"N": self.N, "nz": self.nz, "nv": self.nv, "nxc": problem.nx_car, "free": FREE}
        for key, value in sizes.items():
            source = source.replace("{" + key + "}", repr(value))
        functions = [
            problem.stage_linearization(),
            problem.terminal_linearization(),
            problem.merit(),
            problem.dynamics,
            problem.dynamics.mapaccum("mpcc_rollout", self.N),
        ]
        try:
            compiled = compile_functions(
                functions,
                f"mpcc_native_{problem.model.tag}_{problem.model.n_base_stations}bs_n{self.N}"
                f"_{round(1e6 / problem.settings.rate_hz)}",
                "compiled",
                source,
                ("-I" + include.format("hpipm"), "-I" + include.format("blasfeo"), "-D_GNU_SOURCE"),
            )
        except RuntimeError as error:
            raise AcadosUnavailable(f"the native MPCC iteration does not build: {error}") from error
        #: the horizon's rollout (``mpcc_rollout``) and the plan's cost (``mpcc_merit``) from
        #: the same library: the functions of the Python steps around the call
        self.checks = {name: compiled[name] for name in ("mpcc_rollout", "mpcc_merit")}
        merit = compiled["mpcc_merit"]
        assert isinstance(merit, CompiledFunction)  # the compiled backend was asked for
        library = merit.library
        pointer, double, integer = ctypes.c_void_p, ctypes.c_double, ctypes.c_int
        create = library.crs_rti_create
        create.restype, create.argtypes = pointer, [integer, integer, pointer, pointer]
        self._free = library.crs_rti_free
        self._free.argtypes = [pointer]
        self._iterate = library.crs_rti_iterate
        self._iterate.restype = integer
        self._iterate.argtypes = [pointer] * 8 + [double] + [pointer] * 3
        self._sqp = library.crs_rti_sqp
        self._sqp.restype = integer
        arguments: list[type[ctypes._SimpleCData[Any]]] = [pointer] * 7 + [double] * 3
        self._sqp.argtypes = [*arguments, pointer, integer, *[pointer] * 5]
        hpipm = library.crs_rti_hpipm_library
        hpipm.restype = ctypes.c_char_p
        #: the file HPIPM's solver was loaded from (acados's build)
        self.hpipm_library = hpipm().decode()
        self._library = library
        breaks, coefficients = path.pieces
        breaks = np.ascontiguousarray(breaks, dtype=float)
        coefficients = np.ascontiguousarray(coefficients, dtype=float)
        self._memory = create(
            int(problem.settings.qp_max_iter),
            breaks.size - 1,
            breaks.ctypes.data,
            coefficients.ctypes.data,
        )
        if not self._memory:
            raise AcadosUnavailable("the native MPCC iteration: HPIPM's memory not created")
        self._Z = np.zeros((self.N + 1, self.nz))
        self._V = np.zeros((self.N, self.nv))
        self._guess = np.zeros((self.N + 1, self.nz))
        self._refs = np.zeros((self.N + 1, 4))
        self._z0 = np.zeros(self.nz)
        self._inputs = np.zeros((self.N, self.nv))
        self._out = np.zeros(6)

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
        iterations, _, violation = self._out[:3]
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

    def sqp(
        self,
        z0: np.ndarray,
        V: np.ndarray,
        weights: np.ndarray,
        p: np.ndarray,
        v_lower: np.ndarray,
        v_upper: np.ndarray,
        half_width: float,
        fractions: np.ndarray,
        standing: float | None = None,
    ) -> SqpStep | None:
        """One SQP iteration of a call from the stage state ``z0`` with the inputs ``V``
        (N, nv): ``V`` rolled out from ``z0`` (the guess) with the path at each stage's
        progress, the QP, and the step check over ``fractions`` of the QP's step (the first
        whose rollout's merit is no more than the guess's, else the cheapest, else the guess:
        :meth:`~crs_core.control.mpcc.Mpcc._step`'s rule). With ``standing`` (m/s), None when
        no stage of the guess reaches that speed (nothing solved)."""
        np.copyto(self._z0, z0)
        np.copyto(self._inputs, V)
        out = self._out
        status = self._sqp(
            self._memory,
            self._z0.ctypes.data,
            self._inputs.ctypes.data,
            weights.ctypes.data,
            p.ctypes.data,
            v_lower.ctypes.data,
            v_upper.ctypes.data,
            float(half_width),
            -1.0 if standing is None else float(standing),
            self.tolerance,
            fractions.ctypes.data,
            fractions.size,
            self._guess.ctypes.data,
            self._refs.ctypes.data,
            self._Z.ctypes.data,
            self._V.ctypes.data,
            out.ctypes.data,
        )
        if status == STANDING:
            return None
        guess = (self._guess.copy(), self._inputs.copy())
        if status < 0:
            qp = Iterate(*guess, False, math.inf, -1, STATUS[-1])
        else:
            violation = float(out[2])
            success = violation <= self.tolerance  # as "hpipm": a feasible iteration limit counts
            qp = Iterate(
                self._Z.copy(),
                self._V.copy(),
                success,
                violation,
                int(out[0]),
                STATUS.get(status, str(status)),
            )
        return SqpStep(guess, self._refs.copy(), qp, float(out[3]))
