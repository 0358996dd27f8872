"""The self-calibration tracker's Kalman filter (:class:`rimu.fdi.selfcal.SelfCalTracker`) as generated C99.

:func:`selfcal_c` writes, for one tracker, a header and a source that compile on their own (``double`` only; no
dynamic memory, no recursion, fixed sizes ``RIMU_SC_N`` sensors x ``RIMU_SC_M`` blocks). What the generated
functions do, step for step, is the tracker's:

* ``<p>_init``: zero drift with the prior covariance (:meth:`SelfCalTracker.initial_state`);
* ``<p>_predict``: the random walks' variance grows by ``q dt`` (:meth:`SelfCalTracker.predict`);
* ``<p>_regressors``: ``1``, ``s_i = a_i . u``, ``dT^k`` of one sample (:meth:`SelfCalTracker.regressors`);
* ``<p>_update``: one window's Kalman update on the normalised parity of the active sensors (de Oliveira et al.
  2012, Eq. 6-11: ``p = Vz z``, ``Vz A = 0``), the chi-square gate, the optimal-gain covariance when every state
  may move, else Schmidt's consider update in Joseph form (:meth:`SelfCalTracker.update`);
* ``<p>_correction``, ``<p>_correction_covariance``, ``<p>_terms``: the correction ``Pi Phi theta`` that never
  moves the common mode, its covariance, the tracked terms and their 1-sigma (the methods of the same names).

What is precomputed. ``Pi = I - A G`` (the fusion's weighted least squares), the random-walk intensities, the
prior, the axes, the weights ``1 / sigma`` and the gate ``chi2_{1 - gate_p}(r)`` for every parity dimension r
(scipy, at export). What is not: the parity rows of the window's active set. The filter's every quantity
(innovation, its covariance, the gain applied to it, the chi-square of the gate) is invariant under an orthogonal
change of the parity basis, so the C builds its own orthonormal basis of the left null space of the whitened
axes of the active sensors (modified Gram-Schmidt, twice, on the columns of the projector
``I - Aw (Aw^T Aw)^-1 Aw^T``) rather than the SVD basis of :func:`rimu.geometry.base.null_space_rows`; the two
agree to rounding (tests/export/test_c_selfcal.py: 1e-12).

With ``sample_rate`` the runtime's loop around the tracker is generated too (``<p>_loop_correct``,
``<p>_loop_observe``: :class:`rimu.fdi.selfcal.SelfCalLoop` step for step): the correction of every epoch's
compensated outputs by the terms of the state at the window's start, the covariance handed to the window GLT at
every window's start (the state predicted to the window's end, the previous window's rms regressors, the largest
trace of the windows the detector's sum spans), the windows thrown away on an alarm or a statistic above the watch
level, the others held ``hold_s`` and then absorbed with the sensors isolated then frozen. The held windows keep
only their means (all the update uses), in a ring of ``ceil(hold_s * rate / M) + 2`` (with regular sampling never
full; full, the oldest is absorbed early).

With ``detector_window`` and ``p_fa`` the loop's detector too (``<p>_glt_*``, :class:`TrackedGltWindow`): the
window sum of the normalised parity and its statistic ``S^T (I + W Vz Sigma_c Vz^T)^-1 S / count`` (``|L S|^2 /
count`` in Python, the same in any orthonormal parity basis), thresholds ``chi2_{1-p_fa}(dof)`` tabulated.

In an exported unit (:func:`rimu.export.export_c` with ``selfcal=``, ``rimu export-c --selfcal``): per tracked
instrument these files (:func:`unit_files`, prefix ``rimu_<instrument>_sc``), and in ``rimu_unit.c`` the step that
runs them around the manager as :class:`rimu.fdi.Runtime` does (:func:`unit_source`: correct, the manager's step with
the window GLT's statistic, observe), ``rimu_selfcal_step`` for the epoch; the filter writes the tracked terms
(tests/export/test_c_selfcal_unit.py: the compiled filter against ``rimu replay --selfcal``).

The held-out check (``guard_s``, ``guard_z``; :meth:`SelfCalLoop._check`) runs at every window's end with the
terms fitted before the window, per group of blocks (:data:`rimu.fdi.selfcal.GROUPS`), on the window's samples
(kept in the loop's state when the check is on); the parity is the C's own basis (the check's sums of squares and
inner products are the same in any orthonormal basis).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.special import chdtri  # chdtri(d, p) = chi2.isf(p, d), without importing scipy.stats (~40 MB)

from ..errors import ExportError
from ..fdi.selfcal import BLOCKS, CUSUM_RHO_NODES, CUSUM_RHO_STEP, GROUPS, SelfCalTracker, tracked_cusum_design

__all__ = ["selfcal_c", "unit_files", "unit_header", "unit_prefix", "unit_source"]


def _num(v: float) -> str:
    s = repr(float(v))
    if "e" not in s and "." not in s:
        s += ".0"
    return s


def _array(values: Any, per_line: int = 4) -> str:
    flat = [_num(v) for v in np.asarray(values, dtype=float).ravel()]
    return "{\n    " + ",\n    ".join(", ".join(flat[i:i + per_line]) for i in range(0, len(flat), per_line)) + "\n}"


_HEADER = """/* rimu self-calibration tracker (rimu.fdi.selfcal.SelfCalTracker), generated: do not edit.
 * {what} */
#ifndef {guard}
#define {guard}

#define {P}_N {n}      /* sensors */
#define {P}_M {m}      /* blocks: {blocks} */
#define {P}_S ({P}_N * {P}_M)  /* state size */

/* The tracker's state (SelfCalState): theta block-major (theta[b * N + i], SI; the scale block relative), P its
 * covariance (row-major), t the time it refers to, s; work: scratch of the update. */
typedef struct {{
    double theta[{P}_S];
    double P[{P}_S * {P}_S];
    double t;
    long updates, rejected;
    double work[3][{P}_S * {P}_S];
}} {p};

/* what one window did (SelfCalUpdate): accepted, the normalised innovation d2, its gate, the parity dimension */
typedef struct {{
    int accepted;
    double d2, gate;
    int dof;
}} {p}_update_info;

void {p}_init({p} *s, double t);
int {p}_predict({p} *s, double t);
void {p}_regressors(const double *u, double temperature, double *g);
void {p}_update({p} *s, const double *z, const double *g, long M, const unsigned char *active,
                const unsigned char *frozen, {p}_update_info *info);
void {p}_update_mean({p} *s, const double *zbar, const double *gbar, long M, const unsigned char *active,
                     const unsigned char *frozen, {p}_update_info *info);
void {p}_correction(const {p} *s, const double *g, double *c);
void {p}_correction_covariance(const {p} *s, const double *g, double *C);
void {p}_terms(const {p} *s, double *values, double *sigmas);
void {p}_terms_ahead(const {p} *s, double t, double *values, double *sigmas);

#endif
"""


_SOURCE = r"""
#define N {P}_N
#define NB {P}_M
#define S {P}_S
#define R ((N > 3) ? (N - 3) : 1)

/* P[i][j] of a row-major S x S matrix */
#define AT(A, i, j) ((A)[((i) * S) + (j)])

void {p}_init({p} *s, double t)
{{
    int i, j;
    for (i = 0; i < S; ++i) {{
        s->theta[i] = 0.0;
        for (j = 0; j < S; ++j) {{
            AT(s->P, i, j) = (i == j) ? {p}_p0[i] : 0.0;
        }}
    }}
    s->t = t;
    s->updates = 0L;
    s->rejected = 0L;
}}

/* 0, or -1 (nothing done) when t is before the state's time: the filter never predicts backwards */
int {p}_predict({p} *s, double t)
{{
    double dt = t - s->t;
    int i;
    if (dt < 0.0) {{
        return -1;
    }}
    for (i = 0; i < S; ++i) {{
        AT(s->P, i, i) += {p}_q[i] * dt;
    }}
    s->t = t;
    return 0;
}}

/* the regressors (NB x N) of one sample: 1 (bias), a_i . u (scale; u the input in MB, SI; may be NULL when the
 * scale is not tracked), dT^k (temperature terms, dT = temperature - T_ref, degC) */
void {p}_regressors(const double *u, double temperature, double *g)
{{
    int b, i;
    double dT = temperature - {p}_tref;
    for (b = 0; b < NB; ++b) {{
        int order = {p}_order[b];
        for (i = 0; i < N; ++i) {{
            double v = 1.0;
            int k;
            if (order < 0) {{
                const double *a = {p}_axes + 3 * i;
                v = (u != NULL) ? ((u[0] * a[0]) + (u[1] * a[1]) + (u[2] * a[2])) : 0.0;
            }} else {{
                for (k = 0; k < order; ++k) {{
                    v *= dT;
                }}
            }}
            g[(b * N) + i] = v;
        }}
    }}
}}

/* orthonormal rows V (r x N) spanning the left null space of the whitened axes a_i / sigma_i of the active
 * sensors (zero columns for the others); r = 0 when fewer than 4 are active or they do not span 3-D */
static int {p}_parity(const unsigned char *act, double *V)
{{
    double Nm[9] = {{0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0}}, L[9] = {{0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0}};
    double Q[N * N], Aw[N * 3];
    int i, j, k, c, na = 0, r = 0;
    for (i = 0; i < N; ++i) {{
        for (c = 0; c < 3; ++c) {{
            Aw[(3 * i) + c] = (act[i] != 0u) ? ({p}_axes[(3 * i) + c] * {p}_w[i]) : 0.0;
        }}
        if (act[i] != 0u) {{
            ++na;
        }}
    }}
    if (na <= 3) {{
        return 0;
    }}
    for (i = 0; i < N; ++i) {{
        for (j = 0; j < 3; ++j) {{
            for (k = 0; k < 3; ++k) {{
                Nm[(3 * j) + k] += Aw[(3 * i) + j] * Aw[(3 * i) + k];
            }}
        }}
    }}
    /* Cholesky of Aw^T Aw; a pivot below (1e-9)^2 (a singular value of Aw below 1e-9): not 3-D */
    for (j = 0; j < 3; ++j) {{
        double d = Nm[(3 * j) + j];
        for (k = 0; k < j; ++k) {{
            d -= L[(3 * j) + k] * L[(3 * j) + k];
        }}
        if (!(d > 1e-18)) {{
            return 0;
        }}
        L[(3 * j) + j] = sqrt(d);
        for (i = j + 1; i < 3; ++i) {{
            double v = Nm[(3 * i) + j];
            for (k = 0; k < j; ++k) {{
                v -= L[(3 * i) + k] * L[(3 * j) + k];
            }}
            L[(3 * i) + j] = v / L[(3 * j) + j];
        }}
    }}
    /* Q = I - Aw (L L^T)^-1 Aw^T: with Y = Aw L^-T, Q = I - Y Y^T */
    for (i = 0; i < N; ++i) {{
        double y[3] = {{0.0, 0.0, 0.0}};
        for (j = 0; j < 3; ++j) {{
            double v = Aw[(3 * i) + j];
            for (k = 0; k < j; ++k) {{
                v -= L[(3 * j) + k] * y[k];
            }}
            y[j] = v / L[(3 * j) + j];
        }}
        for (j = 0; j < 3; ++j) {{
            Aw[(3 * i) + j] = y[j];
        }}
    }}
    for (i = 0; i < N; ++i) {{
        for (j = 0; j < N; ++j) {{
            double v = ((i == j) && (act[i] != 0u)) ? 1.0 : 0.0;
            for (k = 0; k < 3; ++k) {{
                v -= Aw[(3 * i) + k] * Aw[(3 * j) + k];
            }}
            Q[(i * N) + j] = v;
        }}
    }}
    /* modified Gram-Schmidt (twice) on Q's columns: na - 3 orthonormal rows */
    for (j = 0; (j < N) && (r < (na - 3)); ++j) {{
        double v[N], nv = 0.0;
        int pass;
        if (act[j] == 0u) {{
            continue;
        }}
        for (i = 0; i < N; ++i) {{
            v[i] = Q[(i * N) + j];
        }}
        for (pass = 0; pass < 2; ++pass) {{
            for (k = 0; k < r; ++k) {{
                double d = 0.0;
                for (i = 0; i < N; ++i) {{
                    d += V[(k * N) + i] * v[i];
                }}
                for (i = 0; i < N; ++i) {{
                    v[i] -= d * V[(k * N) + i];
                }}
            }}
        }}
        for (i = 0; i < N; ++i) {{
            nv += v[i] * v[i];
        }}
        if (!(nv > 1e-12)) {{
            continue;  /* in the span of the rows already taken */
        }}
        nv = sqrt(nv);
        for (i = 0; i < N; ++i) {{
            V[(r * N) + i] = v[i] / nv;
        }}
        ++r;
    }}
    return r;
}}

/* Cholesky of the r x r matrix A in place (lower), 0 when not positive definite */
static int {p}_chol(double *A, int r)
{{
    int i, j, k;
    for (j = 0; j < r; ++j) {{
        double d = A[(j * R) + j];
        for (k = 0; k < j; ++k) {{
            d -= A[(j * R) + k] * A[(j * R) + k];
        }}
        if (!(d > 0.0)) {{
            return 0;
        }}
        A[(j * R) + j] = sqrt(d);
        for (i = j + 1; i < r; ++i) {{
            double v = A[(i * R) + j];
            for (k = 0; k < j; ++k) {{
                v -= A[(i * R) + k] * A[(j * R) + k];
            }}
            A[(i * R) + j] = v / A[(j * R) + j];
        }}
    }}
    return 1;
}}

/* x = (L L^T)^-1 b, r x r, in place */
static void {p}_cholsolve(const double *L, int r, double *x)
{{
    int i, k;
    for (i = 0; i < r; ++i) {{
        double v = x[i];
        for (k = 0; k < i; ++k) {{
            v -= L[(i * R) + k] * x[k];
        }}
        x[i] = v / L[(i * R) + i];
    }}
    for (i = r - 1; i >= 0; --i) {{
        double v = x[i];
        for (k = i + 1; k < r; ++k) {{
            v -= L[(k * R) + i] * x[k];
        }}
        x[i] = v / L[(i * R) + i];
    }}
}}

/* SelfCalTracker.update: one window of M samples, z (M x N) the compensated outputs (SF y - B, without the
 * tracked correction), g (M x NB x N) their regressors; sensors not active are left out of the parity, the states
 * of frozen (and inactive) sensors do not move (Schmidt); frozen may be NULL. A window failing the gate is not
 * absorbed (rejected += 1). */
void {p}_update({p} *s, const double *z, const double *g, long M, const unsigned char *active,
                const unsigned char *frozen, {p}_update_info *info)
{{
    double zbar[N], gbar[S];
    int i;
    long t;
    for (i = 0; i < N; ++i) {{
        double v = 0.0;
        for (t = 0L; t < M; ++t) {{
            v += z[(t * N) + i];
        }}
        zbar[i] = (M > 0L) ? (v / (double)M) : 0.0;
    }}
    for (i = 0; i < S; ++i) {{
        double v = 0.0;
        for (t = 0L; t < M; ++t) {{
            v += g[(t * S) + i];
        }}
        gbar[i] = (M > 0L) ? (v / (double)M) : 0.0;
    }}
    {p}_update_mean(s, zbar, gbar, M, active, frozen, info);
}}

/* the update on the window's means zbar (N), gbar (NB x N) of M samples */
void {p}_update_mean({p} *s, const double *zbar, const double *gbar, long M, const unsigned char *active,
                     const unsigned char *frozen, {p}_update_info *info)
{{
    double V[R * N], H[R * S], nu[R], Sm[R * R], y[R];
    double *PHt = s->work[0];  /* S x R, row stride R */
    double *K = s->work[1];    /* S x R, row stride R */
    double *J = s->work[2];
    int i, j, k, l, r, all = 1;
    r = {p}_parity(active, V);
    info->accepted = 0;
    info->d2 = 0.0;
    info->dof = r;
    info->gate = HUGE_VAL;
    if ((M < 1L) || (r < 1)) {{
        return;
    }}
    /* H = Vz diag(gbar_b) per block, Vz = V diag(1 / sigma); nu = Vz zbar - H theta */
    for (k = 0; k < r; ++k) {{
        double v = 0.0;
        for (i = 0; i < N; ++i) {{
            double vz = V[(k * N) + i] * {p}_w[i];
            v += vz * zbar[i];
            for (j = 0; j < NB; ++j) {{
                H[(k * S) + (j * N) + i] = vz * gbar[(j * N) + i];
            }}
        }}
        for (i = 0; i < S; ++i) {{
            v -= H[(k * S) + i] * s->theta[i];
        }}
        nu[k] = v;
    }}
    for (i = 0; i < S; ++i) {{
        for (k = 0; k < r; ++k) {{
            double v = 0.0;
            for (j = 0; j < S; ++j) {{
                v += AT(s->P, i, j) * H[(k * S) + j];
            }}
            PHt[(i * R) + k] = v;
        }}
    }}
    for (k = 0; k < r; ++k) {{
        for (l = 0; l < r; ++l) {{
            double v = (k == l) ? (1.0 / (double)M) : 0.0;
            for (i = 0; i < S; ++i) {{
                v += H[(k * S) + i] * PHt[(i * R) + l];
            }}
            Sm[(k * R) + l] = v;
        }}
    }}
    for (k = 0; k < r; ++k) {{  /* symmetric to rounding: use the mean of the two triangles */
        for (l = 0; l < k; ++l) {{
            double v = 0.5 * (Sm[(k * R) + l] + Sm[(l * R) + k]);
            Sm[(k * R) + l] = v;
            Sm[(l * R) + k] = v;
        }}
    }}
    if ({p}_chol(Sm, r) == 0) {{
        return;
    }}
    for (k = 0; k < r; ++k) {{
        y[k] = nu[k];
    }}
    {p}_cholsolve(Sm, r, y);
    for (k = 0; k < r; ++k) {{
        info->d2 += nu[k] * y[k];
    }}
    info->gate = {p}_gate[r];
    if (!(info->d2 <= info->gate)) {{
        s->rejected += 1L;
        return;
    }}
    /* K = P H^T S^-1: rows of PHt solved; the rows of frozen or inactive sensors zero (Schmidt) */
    for (i = 0; i < S; ++i) {{
        int sensor = i % N;
        int keep = 1;
        double row[R];
        if ((active[sensor] == 0u) || ((frozen != NULL) && (frozen[sensor] != 0u))) {{
            keep = 0;
        }}
        for (k = 0; k < r; ++k) {{
            row[k] = PHt[(i * R) + k];
        }}
        {p}_cholsolve(Sm, r, row);
        for (k = 0; k < r; ++k) {{
            K[(i * R) + k] = (keep != 0) ? row[k] : 0.0;
        }}
        if (keep == 0) {{
            all = 0;
        }}
    }}
    for (i = 0; i < S; ++i) {{
        double v = 0.0;
        for (k = 0; k < r; ++k) {{
            v += K[(i * R) + k] * nu[k];
        }}
        s->theta[i] += v;
    }}
    if (all != 0) {{  /* the optimal gain: P - K (P H^T)^T */
        for (i = 0; i < S; ++i) {{
            for (j = 0; j < S; ++j) {{
                double v = 0.0;
                for (k = 0; k < r; ++k) {{
                    v += K[(i * R) + k] * PHt[(j * R) + k];
                }}
                AT(s->P, i, j) -= v;
            }}
        }}
    }} else {{  /* Joseph form, exact for any gain: J P J^T + K K^T / M, J = I - K H */
        double *T = PHt;  /* PHt is no longer needed: T = J P (S x S) needs S x S, use the rows of work[0] */
        for (i = 0; i < S; ++i) {{
            for (j = 0; j < S; ++j) {{
                double v = (i == j) ? 1.0 : 0.0;
                for (k = 0; k < r; ++k) {{
                    v -= K[(i * R) + k] * H[(k * S) + j];
                }}
                AT(J, i, j) = v;
            }}
        }}
        for (i = 0; i < S; ++i) {{
            for (j = 0; j < S; ++j) {{
                double v = 0.0;
                for (l = 0; l < S; ++l) {{
                    v += AT(J, i, l) * AT(s->P, l, j);
                }}
                AT(T, i, j) = v;
            }}
        }}
        for (i = 0; i < S; ++i) {{
            for (j = 0; j < S; ++j) {{
                double v = 0.0;
                for (l = 0; l < S; ++l) {{
                    v += AT(T, i, l) * AT(J, j, l);
                }}
                for (k = 0; k < r; ++k) {{
                    v += K[(i * R) + k] * K[(j * R) + k] / (double)M;
                }}
                AT(s->P, i, j) = v;
            }}
        }}
    }}
    for (i = 0; i < S; ++i) {{
        for (j = 0; j < i; ++j) {{
            double v = 0.5 * (AT(s->P, i, j) + AT(s->P, j, i));
            AT(s->P, i, j) = v;
            AT(s->P, j, i) = v;
        }}
    }}
    s->updates += 1L;
    info->accepted = 1;
}}

/* the correction c (N), SI, for regressors g (NB x N): Pi Phi theta (A^T W c = 0: the common mode untouched) */
void {p}_correction(const {p} *s, const double *g, double *c)
{{
    double d[N];
    int i, j, b;
    for (i = 0; i < N; ++i) {{
        double v = 0.0;
        for (b = 0; b < NB; ++b) {{
            v += g[(b * N) + i] * s->theta[(b * N) + i];
        }}
        d[i] = v;
    }}
    for (i = 0; i < N; ++i) {{
        double v = 0.0;
        for (j = 0; j < N; ++j) {{
            v += {p}_Pi[(i * N) + j] * d[j];
        }}
        c[i] = v;
    }}
}}

/* the correction covariance of regressors g with the state predicted dt ahead (without changing the state) */
static void {p}_cov_ahead(const {p} *s, const double *g, double dt, double *C)
{{
    double B[N * S], T[N * S];
    int i, j, l;
    for (i = 0; i < N; ++i) {{
        for (j = 0; j < S; ++j) {{
            B[(i * S) + j] = {p}_Pi[(i * N) + (j % N)] * g[j];
        }}
    }}
    for (i = 0; i < N; ++i) {{
        for (j = 0; j < S; ++j) {{
            double v = 0.0;
            for (l = 0; l < S; ++l) {{
                double p = AT(s->P, l, j);
                if (l == j) {{
                    p += {p}_q[l] * dt;
                }}
                v += B[(i * S) + l] * p;
            }}
            T[(i * S) + j] = v;
        }}
    }}
    for (i = 0; i < N; ++i) {{
        for (j = 0; j < N; ++j) {{
            double v = 0.0;
            for (l = 0; l < S; ++l) {{
                v += T[(i * S) + l] * B[(j * S) + l];
            }}
            C[(i * N) + j] = v;
        }}
    }}
}}

/* covariance C (N x N), SI^2, of the correction's error for regressors g (NB x N): (Pi Phi) P (Pi Phi)^T */
void {p}_correction_covariance(const {p} *s, const double *g, double *C)
{{
    {p}_cov_ahead(s, g, 0.0, C);
}}

/* the tracked terms and their 1-sigma (NB x N each), SI: bias-like blocks without their common mode (Pi theta_b,
 * Pi P_bb Pi^T), the scale block as estimated */
void {p}_terms(const {p} *s, double *values, double *sigmas)
{{
    {p}_terms_ahead(s, s->t, values, sigmas);
}}

/* the terms of the state predicted to t (not before its own time; the state is not changed) */
void {p}_terms_ahead(const {p} *s, double t, double *values, double *sigmas)
{{
    double dt = (t > s->t) ? (t - s->t) : 0.0;
    int b, i, j, l;
    for (b = 0; b < NB; ++b) {{
        int o = b * N;
        for (i = 0; i < N; ++i) {{
            double v = 0.0, var = 0.0;
            if ({p}_order[b] < 0) {{
                v = s->theta[o + i];
                var = AT(s->P, o + i, o + i) + ({p}_q[o + i] * dt);
            }} else {{
                for (j = 0; j < N; ++j) {{
                    double pij = {p}_Pi[(i * N) + j], row = 0.0;
                    v += pij * s->theta[o + j];
                    for (l = 0; l < N; ++l) {{
                        double pjl = AT(s->P, o + j, o + l);
                        if (j == l) {{
                            pjl += {p}_q[o + j] * dt;
                        }}
                        row += pjl * {p}_Pi[(i * N) + l];
                    }}
                    var += pij * row;
                }}
            }}
            values[o + i] = v;
            sigmas[o + i] = (var > 0.0) ? sqrt(var) : 0.0;
        }}
    }}
}}
"""


_LOOP_HEADER = """
/* ---- the runtime's loop around the tracker (rimu.fdi.selfcal.SelfCalLoop), {rate} Hz */
#define {P}_WIN {M}L      /* samples per window (window_s * sample_rate) */
#define {P}_SPAN {span}   /* windows the detector's sum spans, + 1 */
#define {P}_NPEND {npend}  /* the most windows held (hold_s): a full hold absorbs its oldest early */
#define {P}_NG {ng}      /* groups of terms the held-out check applies or suspends as one */

typedef struct {{
    double t, z[{P}_N], g[{P}_S];   /* the window's end, its mean outputs and regressors */
    unsigned char act[{P}_N];
}} {p}_window;

/* The loop's state. Zero-initialise it (or call {p}_loop_reset). */
typedef struct {{
    {p} s;                          /* the tracker's state (valid once started) */
    int started;
    long k;                         /* samples in the current window */
    int flag;                       /* the window saw an alarm or a statistic above the watch level */
    double t_end, th[{P}_S];        /* the last sample's time; the state's terms the window corrects with */
    double zs[{P}_N], gs[{P}_S], g2[{P}_S];  /* sums over the window */
    unsigned char ok[{P}_N];        /* valid on every sample of the window */
    double g_last[{P}_S];           /* the previous window's rms regressors (signed) */
    int have_last;
    double recent[{P}_SPAN][{P}_N * {P}_N];  /* correction covariances of the windows the detector spans */
    double recent_o[{P}_SPAN][{P}_N];  /* and the correction of their suspended groups (SI) */
    int nrecent, next_recent;
    {p}_window pend[{P}_NPEND];
    int npend, first;
    long accepted, rejected, discarded;
    double last_correction[{P}_N];
    /* the held-out check (SelfCalLoop.guard): per group of terms (GROUPS: bias, scale, temperature) */
    int applied[{P}_NG];
    double gain[{P}_NG], var[{P}_NG], gain_total[{P}_NG], var_total[{P}_NG], t_gain;
    int have_gain;
    long suspended_windows[{P}_NG], suspensions[{P}_NG], n_par;
    double ss[2];                   /* held-out sums of squares of the normalised parity: fixed, applied */
    double nis[2];                  /* the gate's windows: sum of d2, sum of dof */
{guard_fields}}} {p}_loop;

void {p}_loop_reset({p}_loop *L);
int {p}_loop_correct({p}_loop *L, const double *y, const unsigned char *valid, double t, const double *temperature,
                     double *out, double *sigma_c);
void {p}_loop_observe({p}_loop *L, int alarm, double statistic, int dof, const unsigned char *isolated);
void {p}_loop_terms(const {p}_loop *L, double *values, double *sigmas);
"""

_LOOP_SOURCE = r"""
/* ======================================================================== the loop (SelfCalLoop) */
void {p}_loop_reset({p}_loop *L)
{{
    unsigned char *b = (unsigned char *)L;
    size_t i;
    for (i = 0; i < sizeof *L; ++i) {{
        b[i] = 0u;
    }}
}}

/* SelfCalLoop.correct: the compensated raw outputs y (N) of one epoch corrected by the tracked terms, out = y - c / SF
 * (valid: NULL all; temperature, degC: NULL when there is none; NaN invalidates the epoch). At a window's
 * first sample it returns 1 and writes sigma_c (N x N, SI^2): the covariance the detector's thresholds carry from
 * now on (TrackedGltWindow.set_tracker_covariance); else 0. */
int {p}_loop_correct({p}_loop *L, const double *y, const unsigned char *valid, double t, const double *temperature,
                     double *out, double *sigma_c)
{{
    double z[N], u[3] = {{0.0, 0.0, 0.0}}, g[S], c[N], T = (temperature != NULL) ? *temperature : {p}_tref;
    unsigned char ok[N];
    int i, j, all = 1, fresh = 0;
    if (L->started == 0) {{
        {p}_init(&L->s, t);
        L->started = 1;
        for (j = 0; j < {P}_NG; ++j) {{  /* with the held-out check, every group waits for its evidence */
            L->applied[j] = 1;
            if ({p}_guard != 0) {{
                L->applied[j] = 0;
            }}
        }}
    }}
    for (i = 0; i < N; ++i) {{
        ok[i] = (((valid == NULL) || (valid[i] != 0u)) && (isfinite(y[i]) != 0)) ? 1u : 0u;
    }}
    if (temperature != NULL) {{
        if (isfinite(T) == 0) {{
            for (i = 0; i < N; ++i) {{
                ok[i] = 0u;
            }}
            T = {p}_tref;
        }}
    }}
    for (i = 0; i < N; ++i) {{
        z[i] = (ok[i] != 0u) ? ((y[i] * {p}_sf[i]) - {p}_b[i]) : 0.0;
        if (ok[i] == 0u) {{
            all = 0;
        }}
    }}
    if (all != 0) {{
        for (j = 0; j < 3; ++j) {{
            double v = 0.0;
            for (i = 0; i < N; ++i) {{
                v += z[i] * {p}_G[(j * N) + i];
            }}
            u[j] = v;
        }}
    }}
    {p}_regressors(u, T, g);
    if (L->k == 0L) {{  /* a new window: the state's terms, and the detector's covariance */
        for (i = 0; i < S; ++i) {{
            L->th[i] = L->s.theta[i];
            L->zs[i % N] = 0.0;
            L->gs[i] = 0.0;
            L->g2[i] = 0.0;
        }}
        for (i = 0; i < N; ++i) {{
            L->ok[i] = 1u;
        }}
        if ({p}_detector != 0) {{
            double ahead = t + {p}_window_s, dt;
            int best = 0, r;
            double tbest = -1.0;
            if (ahead < L->s.t) {{
                ahead = L->s.t;
            }}
            dt = ahead - L->s.t;
            {p}_cov_ahead(&L->s, (L->have_last != 0) ? L->g_last : g, dt, L->recent[L->next_recent]);
            {{  /* SelfCalTracker.unapplied_correction: Pi Phi theta on the blocks of the suspended groups */
                const double *gc = (L->have_last != 0) ? L->g_last : g;
                double v[N];
                for (i = 0; i < N; ++i) {{
                    int b;
                    v[i] = 0.0;
                    for (b = 0; b < NB; ++b) {{
                        if (L->applied[{p}_group[b]] == 0) {{
                            v[i] += gc[(b * N) + i] * L->s.theta[(b * N) + i];
                        }}
                    }}
                }}
                for (i = 0; i < N; ++i) {{
                    double o = 0.0;
                    for (j = 0; j < N; ++j) {{
                        o += {p}_Pi[(i * N) + j] * v[j];
                    }}
                    L->recent_o[L->next_recent][i] = o;
                }}
            }}
            L->next_recent = (L->next_recent + 1) % {P}_SPAN;
            if (L->nrecent < {P}_SPAN) {{
                L->nrecent += 1;
            }}
            /* the largest trace, the oldest first on a tie (Python's max over the list, oldest first) */
            for (r = 0; r < L->nrecent; ++r) {{
                int idx = (L->next_recent - L->nrecent + r + (2 * {P}_SPAN)) % {P}_SPAN;
                double tr = 0.0;
                for (i = 0; i < N; ++i) {{
                    tr += L->recent[idx][(i * N) + i];
                }}
                if ((r == 0) || (tr > tbest)) {{
                    tbest = tr;
                    best = idx;
                }}
            }}
            for (i = 0; i < (N * N); ++i) {{
                sigma_c[i] = L->recent[best][i];
            }}
            /* the drift the suspended groups leave in: every spanned window's outer product, the oldest first */
            for (r = 0; r < L->nrecent; ++r) {{
                const double *o = L->recent_o[(L->next_recent - L->nrecent + r + (2 * {P}_SPAN)) % {P}_SPAN];
                for (i = 0; i < N; ++i) {{
                    for (j = 0; j < N; ++j) {{
                        sigma_c[(i * N) + j] += o[i] * o[j];
                    }}
                }}
            }}
            fresh = 1;
        }}
        L->flag = 0;
        for (j = 0; j < {P}_NG; ++j) {{
            if (L->applied[j] == 0) {{
                L->suspended_windows[j] += 1L;
            }}
        }}
    }}
    for (i = 0; i < N; ++i) {{
        double v = 0.0;
        int b;
        for (b = 0; b < NB; ++b) {{  /* the terms of the groups applied (the held-out check) */
            double mask = (L->applied[{p}_group[b]] != 0) ? 1.0 : 0.0;
            v += g[(b * N) + i] * (L->th[(b * N) + i] * mask);
        }}
        c[i] = v;
    }}
{keep}
    for (i = 0; i < N; ++i) {{
        double v = 0.0;
        for (j = 0; j < N; ++j) {{
            v += {p}_Pi[(i * N) + j] * c[j];
        }}
        L->last_correction[i] = v;
        out[i] = y[i] - (v / {p}_sf[i]);
        L->zs[i] += z[i];
        if (ok[i] == 0u) {{
            L->ok[i] = 0u;
        }}
    }}
    for (i = 0; i < S; ++i) {{
        L->gs[i] += g[i];
        L->g2[i] += g[i] * g[i];
    }}
    L->t_end = t;
    return fresh;
}}

/* the tracked terms after the latest window (SelfCalLoop.history: the state predicted to the window's end); before
 * any sample, those of the initial state */
void {p}_loop_terms(const {p}_loop *L, double *values, double *sigmas)
{{
    int b, i, j;
    if (L->started != 0) {{
        {p}_terms_ahead(&L->s, L->t_end, values, sigmas);
        return;
    }}
    for (b = 0; b < NB; ++b) {{  /* zero drift with the prior's sigmas (bias-like blocks: diag(Pi P0 Pi^T)) */
        for (i = 0; i < N; ++i) {{
            double var = 0.0;
            if ({p}_order[b] < 0) {{
                var = {p}_p0[(b * N) + i];
            }} else {{
                for (j = 0; j < N; ++j) {{
                    var += {p}_Pi[(i * N) + j] * {p}_Pi[(i * N) + j] * {p}_p0[(b * N) + j];
                }}
            }}
            values[(b * N) + i] = 0.0;
            sigmas[(b * N) + i] = sqrt(var);
        }}
    }}
}}

/* absorb the oldest held window: predicted to its end, its sensors not active or isolated now frozen (Schmidt) */
static void {p}_absorb({p}_loop *L, const unsigned char *isolated)
{{
    const {p}_window *w = &L->pend[L->first];
    unsigned char frozen[N];
    {p}_update_info info;
    int i;
    for (i = 0; i < N; ++i) {{
        frozen[i] = ((w->act[i] == 0u) || (isolated[i] != 0u)) ? 1u : 0u;
    }}
    if (w->t > L->s.t) {{
        (void){p}_predict(&L->s, w->t);
    }}
    {p}_update_mean(&L->s, w->z, w->g, {P}_WIN, w->act, frozen, &info);
    if ((info.dof >= 1) && (info.gate < HUGE_VAL)) {{
        L->nis[0] += info.d2;
        L->nis[1] += (double)info.dof;
    }}
    L->accepted += (long)info.accepted;
    if ((info.accepted == 0) && (info.gate < HUGE_VAL)) {{
        L->rejected += 1L;
    }}
    L->first = (L->first + 1) % {P}_NPEND;
    L->npend -= 1;
}}

/* SelfCalLoop.observe: after the manager's step on the corrected outputs, its alarm, statistic and parity dof,
 * and the sensors it keeps isolated (N) */
void {p}_loop_observe({p}_loop *L, int alarm, double statistic, int dof, const unsigned char *isolated)
{{
    double t = L->t_end, Md = (double){P}_WIN;
    int i;
    if ((alarm != 0) || ((dof >= 1) && (statistic > {p}_watch[(dof < {P}_NWATCH) ? dof : ({P}_NWATCH - 1)]))) {{
        L->flag = 1;
    }}
    L->k += 1L;
    if (L->k < {P}_WIN) {{
        return;
    }}
    L->k = 0L;
    for (i = 0; i < S; ++i) {{
        double mean = L->gs[i] / Md, rms = sqrt(L->g2[i] / Md), sg = mean + 1e-300;
        L->g_last[i] = (sg > 0.0) ? rms : ((sg < 0.0) ? -rms : 0.0);
    }}
    L->have_last = 1;
    if (L->flag != 0) {{
        L->discarded += (long)L->npend + 1L;
        L->npend = 0;
        L->first = 0;
    }} else {{
        while ((L->npend > 0) && (L->pend[L->first].t <= (t - {p}_hold_s))) {{
            {p}_absorb(L, isolated);
        }}
    }}
{check}    if (L->flag == 0) {{
        {p}_window *w;
        if (L->npend == {P}_NPEND) {{  /* more held than hold_s allows at the nominal rate: absorb the oldest now */
            {p}_absorb(L, isolated);
        }}
        w = &L->pend[(L->first + L->npend) % {P}_NPEND];
        w->t = t;
        for (i = 0; i < N; ++i) {{
            w->z[i] = L->zs[i] / Md;
            w->act[i] = ((L->ok[i] != 0u) && (isolated[i] == 0u)) ? 1u : 0u;
        }}
        for (i = 0; i < S; ++i) {{
            w->g[i] = L->gs[i] / Md;
        }}
        L->npend += 1;
    }}
    while ((L->npend > 0) && (L->pend[L->first].t <= (t - {p}_hold_s))) {{
        {p}_absorb(L, isolated);
    }}
}}
"""


_GUARD_KEEP = """    {{
        int b;
        for (i = 0; i < N; ++i) {{  /* the window's samples, for the held-out check at its end */
            L->zb[L->k][i] = z[i];
            L->okb[L->k][i] = ok[i];
        }}
        for (b = 0; b < S; ++b) {{
            L->gb[L->k][b] = g[b];
        }}
    }}
"""

_GUARD_CHECK = r"""
/* SelfCalLoop._check: the held-out check of the window just ended (the sensors not isolated, on the samples where
 * all of them are valid, else those valid throughout), with the state fitted before it: per group of terms the
 * sum of squares of the normalised parity it removes given the other groups applied, its variance
 * 4 sum_k (r_k . D_gk)^2 (White's sandwich), both summed with the memory guard_s and since the start; a group is
 * applied while both sums exceed guard_z standard deviations. The parity basis is the C's own (every quantity is
 * a norm or an inner product in parity space: the same in any orthonormal basis). */
static void {p}_check({p}_loop *L, const unsigned char *isolated, double t)
{{
    double V[R * N], p[R], Da[R], Dg[{P}_NG][R], sq[{P}_NG], vr[{P}_NG], ssp = 0.0, ssa = 0.0, decay;
    unsigned char act[N], full[{P}_WIN];
    int i, j, r, d, b, nfull = 0;
    long k;
    for (i = 0; i < N; ++i) {{
        act[i] = (isolated[i] == 0u) ? 1u : 0u;
    }}
    for (k = 0L; k < {P}_WIN; ++k) {{
        full[k] = 1u;
        for (i = 0; i < N; ++i) {{
            if ((act[i] != 0u) && (L->okb[k][i] == 0u)) {{
                full[k] = 0u;
            }}
        }}
        if (full[k] != 0u) {{
            ++nfull;
        }}
    }}
    if (nfull == 0) {{  /* no sample with all of them: the sensors valid throughout, on every sample */
        for (k = 0L; k < {P}_WIN; ++k) {{
            full[k] = 1u;
            for (i = 0; i < N; ++i) {{
                if (L->okb[k][i] == 0u) {{
                    act[i] = 0u;
                }}
            }}
        }}
    }}
    d = {p}_parity(act, V);
    if (d < 1) {{
        return;
    }}
    for (j = 0; j < {P}_NG; ++j) {{
        sq[j] = 0.0;
        vr[j] = 0.0;
    }}
    for (k = 0L; k < {P}_WIN; ++k) {{
        if (full[k] == 0u) {{
            continue;
        }}
        for (r = 0; r < d; ++r) {{
            double v = 0.0;
            for (i = 0; i < N; ++i) {{
                v += V[(r * N) + i] * {p}_w[i] * L->zb[k][i];
            }}
            p[r] = v;
            Da[r] = 0.0;
            for (j = 0; j < {P}_NG; ++j) {{
                Dg[j][r] = 0.0;
            }}
            for (b = 0; b < NB; ++b) {{
                double e = 0.0;
                for (i = 0; i < N; ++i) {{
                    e += L->gb[k][(b * N) + i] * L->s.theta[(b * N) + i] * V[(r * N) + i] * {p}_w[i];
                }}
                Dg[{p}_group[b]][r] += e;
            }}
            for (j = 0; j < {P}_NG; ++j) {{
                if (L->applied[j] != 0) {{
                    Da[r] += Dg[j][r];
                }}
            }}
            ssp += p[r] * p[r];
            ssa += (p[r] - Da[r]) * (p[r] - Da[r]);
        }}
        for (j = 0; j < {P}_NG; ++j) {{
            double dot = 0.0;
            for (r = 0; r < d; ++r) {{
                double e = (L->applied[j] != 0) ? (p[r] - Da[r] + Dg[j][r]) : (p[r] - Da[r] - Dg[j][r]);
                double res = (L->applied[j] != 0) ? (p[r] - Da[r] + Dg[j][r]) : (p[r] - Da[r]);
                sq[j] += e * e;
                dot += res * Dg[j][r];
            }}
            vr[j] += dot * dot;
        }}
        L->n_par += (long)d;
    }}
    decay = (L->have_gain == 0) ? 1.0 : exp(-((t > L->t_gain) ? (t - L->t_gain) : 0.0) / {p}_guard_s);
    L->t_gain = t;
    L->have_gain = 1;
    L->ss[0] += ssp;
    L->ss[1] += ssa;
    for (j = 0; j < {P}_NG; ++j) {{
        double gj = (L->applied[j] != 0) ? (sq[j] - ssa) : (ssa - sq[j]);
        int on;
        L->gain[j] = (decay * L->gain[j]) + gj;
        L->var[j] = (decay * decay * L->var[j]) + (4.0 * vr[j]);
        L->gain_total[j] += gj;
        L->var_total[j] += 4.0 * vr[j];
        on = 0;
        if ((L->gain[j] > ({p}_guard_z * sqrt(L->var[j])))
            && (L->gain_total[j] > ({p}_guard_z * sqrt(L->var_total[j])))) {{
            on = 1;
        }}
        if ((L->applied[j] != 0) && (on == 0)) {{
            L->suspensions[j] += 1L;
        }}
        L->applied[j] = on;
    }}
}}
"""

_GLT_HEADER = '''
/* ---- the window GLT with the tracker's covariance in its thresholds (rimu.fdi.selfcal.TrackedGltWindow) */
#define {P}_GLT_WINDOW {W}
typedef struct {{
    double V[{P}_N * {P}_N];        /* orthonormal parity rows of the active set (whitened), r of them */
    int r;
    double buf[{P}_GLT_WINDOW][{P}_N], sum[{P}_N];
    int k, count, have_cov;
    double sigma_c[{P}_N * {P}_N];   /* the tracker's correction covariance, SI^2 */
    /* the CUSUM bank beside it: per sensor A_j = Vz^T u_j (X_j = A_j . z), S+ and S-, 1 / threshold (0: off), the
     * threshold's node of the table */
    double A[{P}_N * {P}_N], Sp[{P}_N], Sm[{P}_N], inv_h[{P}_N];
    int node[{P}_N];
}} {p}_glt;

void {p}_glt_configure({p}_glt *G, const unsigned char *active);
void {p}_glt_set_covariance({p}_glt *G, const double *sigma_c);
double {p}_glt_update({p}_glt *G, const double *z, double *threshold);
'''

_GLT_SOURCE = r'''
/* ======================================================================== the window GLT (TrackedGltWindow) */
/* each active sensor's CUSUM threshold for the tracker's covariance (TrackedGltWindow._cusum_thresholds): node
 * ceil(rho / step), rho = sqrt(A_j^T Sigma_c A_j) / k, off past the table; a statistic restarts when its node falls
 * and is held at zero while off */
static void {p}_cusum_thresholds({p}_glt *G)
{{
    int j, i, l, d = G->r;
    double ck = 0.5 * {p}_cusum_delta[d];
    for (j = 0; j < N; ++j) {{
        int node = {P}_CUSUM_NODES, on = 0;
        for (i = 0; i < N; ++i) {{
            if (G->A[(j * N) + i] != 0.0) {{
                on = 1;
            }}
        }}
        if (on != 0) {{
            double var = 0.0, rho;
            if (G->have_cov != 0) {{
                for (i = 0; i < N; ++i) {{
                    double v = 0.0;
                    for (l = 0; l < N; ++l) {{
                        v += G->sigma_c[(i * N) + l] * G->A[(j * N) + l];
                    }}
                    var += G->A[(j * N) + i] * v;
                }}
            }}
            rho = sqrt((var > 0.0) ? var : 0.0) / ck;
            node = (int)ceil((rho / {p}_cusum_step) - 1e-9);
            if (node > {P}_CUSUM_NODES) {{
                node = {P}_CUSUM_NODES;
            }}
        }}
        if ((node >= {P}_CUSUM_NODES) || (node < G->node[j])) {{
            G->Sp[j] = 0.0;
            G->Sm[j] = 0.0;
        }}
        G->inv_h[j] = (node < {P}_CUSUM_NODES) ? (1.0 / {p}_cusum_h[d][node]) : 0.0;
        G->node[j] = node;
    }}
}}

/* a new active set: its parity rows, the window forgotten (GltWindow.configure) */
void {p}_glt_configure({p}_glt *G, const unsigned char *active)
{{
    int i, j;
    G->r = {p}_parity(active, G->V);
    for (i = 0; i < {P}_GLT_WINDOW; ++i) {{
        for (j = 0; j < N; ++j) {{
            G->buf[i][j] = 0.0;
        }}
    }}
    for (j = 0; j < N; ++j) {{
        G->sum[j] = 0.0;
    }}
    G->k = 0;
    G->count = 0;
    /* the CUSUM bank: unit columns u_j = v_j / |v_j| (v_j = column j of V diag(w)), A_j = diag(w) V^T u_j */
    for (j = 0; j < N; ++j) {{
        double nv = 0.0;
        int l;
        for (i = 0; i < G->r; ++i) {{
            nv += (G->V[(i * N) + j] * {p}_w[j]) * (G->V[(i * N) + j] * {p}_w[j]);
        }}
        nv = sqrt(nv);
        for (l = 0; l < N; ++l) {{
            double v = 0.0;
            if (nv > 1e-12) {{
                for (i = 0; i < G->r; ++i) {{
                    v += ((G->V[(i * N) + j] * {p}_w[j]) / nv) * G->V[(i * N) + l];
                }}
            }}
            G->A[(j * N) + l] = v * {p}_w[l];
        }}
        G->Sp[j] = 0.0;
        G->Sm[j] = 0.0;
        G->node[j] = {P}_CUSUM_NODES;
        G->inv_h[j] = 0.0;
    }}
    if (({p}_cusum_on != 0) && (G->r >= 1)) {{
        {p}_cusum_thresholds(G);
    }}
}}

/* the tracker's covariance from now on (the window's sums and the CUSUMs are kept) */
void {p}_glt_set_covariance({p}_glt *G, const double *sigma_c)
{{
    int i;
    for (i = 0; i < (N * N); ++i) {{
        G->sigma_c[i] = sigma_c[i];
    }}
    G->have_cov = 1;
    if (({p}_cusum_on != 0) && (G->r >= 1)) {{
        {p}_cusum_thresholds(G);
    }}
}}

/* one sample's compensated outputs z (N, SI; those of inactive sensors ignored): the statistic
 * S^T (I + W Vz Sigma_c Vz^T)^-1 S / count of the window sum S of the normalised parity (= |L S|^2 / count, L the
 * inverse Cholesky factor: the same in any orthonormal parity basis), and its threshold chi2_(1-p_fa)(r)
 * (HUGE_VAL and 0 without parity) */
/* the detector's statistic on the scale of chi2_(1-p_fa)(d): the window GLT's (at p_fa / 2) scaled by
 * thr(p_fa) / thr(p_fa / 2), or the CUSUM's ratio times thr(p_fa), the larger */
static double {p}_combine(double glt, double ratio, int d)
{{
    double scale = {p}_thr_det[d] / {p}_thr_half[d], a = glt * scale, b = ratio * {p}_thr_det[d];
    return (b > a) ? b : a;
}}

double {p}_glt_update({p}_glt *G, const double *z, double *threshold)
{{
    double p[R], old[R], C[R * R], x[R], stat = 0.0, ratio = 0.0;
    int i, j, l, d = G->r, k = G->k;
    *threshold = HUGE_VAL;
    if (d < 1) {{
        return 0.0;
    }}
    for (i = 0; i < d; ++i) {{
        double v = 0.0;
        for (j = 0; j < N; ++j) {{
            v += G->V[(i * N) + j] * {p}_w[j] * z[j];
        }}
        p[i] = v;
        old[i] = G->buf[k][i];
        G->buf[k][i] = v;
        G->sum[i] += p[i] - old[i];
    }}
    k += 1;
    if (k == {P}_GLT_WINDOW) {{  /* refresh the running sum once per turn (no drift) */
        k = 0;
        for (i = 0; i < d; ++i) {{
            double v = 0.0;
            for (j = 0; j < {P}_GLT_WINDOW; ++j) {{
                v += G->buf[j][i];
            }}
            G->sum[i] = v;
        }}
    }}
    G->k = k;
    if (G->count < {P}_GLT_WINDOW) {{
        G->count += 1;
    }}
    *threshold = {p}_thr_det[d];
    /* the CUSUM bank: S+ = max(S+ + X - k, 0), S- = max(S- - X - k, 0) per active sensor; the largest S / h */
    if ({p}_cusum_on != 0) {{
        double ck = 0.5 * {p}_cusum_delta[d];
        for (j = 0; j < N; ++j) {{
            double X = 0.0, a, b;
            for (l = 0; l < N; ++l) {{
                X += G->A[(j * N) + l] * z[l];
            }}
            a = (G->Sp[j] + X) - ck;
            b = (G->Sm[j] - X) - ck;
            G->Sp[j] = (a > 0.0) ? a : 0.0;
            G->Sm[j] = (b > 0.0) ? b : 0.0;
            if (G->inv_h[j] == 0.0) {{
                G->Sp[j] = 0.0;
                G->Sm[j] = 0.0;
            }}
            a = ((G->Sp[j] > G->Sm[j]) ? G->Sp[j] : G->Sm[j]) * G->inv_h[j];
            if (a > ratio) {{
                ratio = a;
            }}
        }}
    }}
    if (G->have_cov == 0) {{
        for (i = 0; i < d; ++i) {{
            stat += G->sum[i] * G->sum[i];
        }}
        return {p}_combine((stat / (double)G->count), ratio, d);
    }}
    /* C = I + W (V D) Sigma_c (V D)^T, D = diag(1 / sigma) */
    for (i = 0; i < d; ++i) {{
        for (j = 0; j <= i; ++j) {{
            double v = 0.0;
            int a;
            for (a = 0; a < N; ++a) {{
                double row = 0.0;
                for (l = 0; l < N; ++l) {{
                    row += G->sigma_c[(a * N) + l] * G->V[(j * N) + l] * {p}_w[l];
                }}
                v += G->V[(i * N) + a] * {p}_w[a] * row;
            }}
            v *= (double){P}_GLT_WINDOW;
            if (i == j) {{
                v += 1.0;
            }}
            C[(i * R) + j] = v;
            C[(j * R) + i] = v;
        }}
    }}
    if ({p}_chol(C, d) == 0) {{
        return HUGE_VAL;
    }}
    for (i = 0; i < d; ++i) {{
        x[i] = G->sum[i];
    }}
    {p}_cholsolve(C, d, x);
    for (i = 0; i < d; ++i) {{
        stat += G->sum[i] * x[i];
    }}
    return {p}_combine((stat / (double)G->count), ratio, d);
}}
'''


def selfcal_c(tracker: SelfCalTracker, prefix: str = "rimu_sc", sample_rate: float | None = None,
              detector_window: int | None = None, p_fa: float | None = None, cusum: bool = False) -> tuple[str, str]:
    """The header and the source (C99, double) of ``tracker``'s Kalman filter, functions named ``prefix_*``.

    Parameters
    ----------
    tracker : rimu.fdi.selfcal.SelfCalTracker
    prefix : str
        A C identifier: the functions' and types' prefix (``RIMU_SC_N``... for the sizes: its upper case).
    sample_rate : float, optional
        Hz: with it, the runtime's loop around the tracker too (``prefix_loop_*``, :class:`SelfCalLoop`).
    detector_window : int, optional
        The loop's detector is a :class:`rimu.fdi.selfcal.TrackedGltWindow` of this many samples (it gets the
        tracker's covariance at every window's start); None: no detector to inform.
    p_fa : float, optional
        With ``detector_window``: that detector as C too (``prefix_glt_*``), thresholds ``chi2_{1-p_fa}(dof)``.
    cusum : bool
        That detector with its CUSUM bank (``TrackedGltWindow(..., cusum=True)``: the window GLT at ``p_fa / 2``).

    Returns
    -------
    header, source : str
        ``prefix.h`` and ``prefix.c`` (the source includes ``prefix.h``, <math.h> and <stddef.h>).

    Examples
    --------
    >>> from rimu.calibration import InstrumentCalibration
    >>> from rimu.fdi.selfcal import SelfCalSettings
    >>> from rimu.geometry import cone6
    >>> cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)
    >>> h, c = selfcal_c(SelfCalTracker(cal, SelfCalSettings(bias_rw=1e-6, scale_rw=1e-8)), sample_rate=100.0)
    >>> "#define RIMU_SC_S (RIMU_SC_N * RIMU_SC_M)" in h, "rimu_sc_update" in c, "#define RIMU_SC_WIN 100L" in h
    (True, True, True)
    """
    if not prefix.isidentifier():
        raise ExportError(f"the prefix must be a C identifier, got {prefix!r}")
    trk = tracker
    st = trk.settings
    n, m = trk.n, trk.m
    P = prefix.upper()
    order = [-1 if b == "scale" else (0 if b == "bias" else int(b[2])) for b in trk.blocks]
    assert set(trk.blocks) <= set(BLOCKS)
    gates = [0.0] + [float(chdtri(r, st.gate_p)) for r in range(1, max(n - 3, 1) + 1)]
    header = _HEADER.format(guard=f"{P}_H", P=P, p=prefix, n=n, m=m, blocks=", ".join(trk.blocks),
                            what=f"{trk.calibration.instrument}, {n} sensors, gate_p={st.gate_p!r}")
    consts = [
        f'#include "{prefix}.h"',
        "#include <math.h>",
        "#include <stddef.h>",
        "",
        f"static const double {prefix}_axes[{n} * 3] = {_array(trk.axes, 3)};",
        f"/* 1 / sigma, the per-sample noise of the compensated outputs, 1/SI */\n"
        f"static const double {prefix}_w[{n}] = {_array(1.0 / trk.sigma)};",
        f"/* Pi = I - A G (row-major) */\nstatic const double {prefix}_Pi[{n} * {n}] = {_array(trk.Pi)};",
        f"/* random-walk intensities, SI^2/s, and the prior variances, SI^2 */\n"
        f"static const double {prefix}_q[{n * m}] = {_array(trk.q)};",
        f"static const double {prefix}_p0[{n * m}] = {_array(trk.p0)};",
        f"/* per block: -1 scale, 0 bias, k temperature order k */\n"
        f"static const int {prefix}_order[{m}] = {{{', '.join(str(o) for o in order)}}};",
        f"static const double {prefix}_tref = {_num(st.reference_temperature)};  /* degC */",
        f"/* the gate chi2_(1 - gate_p)(r) by parity dimension r (entry 0 unused) */\n"
        f"static const double {prefix}_gate[{len(gates)}] = {_array(gates)};",
    ]
    source = _SOURCE.format(p=prefix, P=P)
    if sample_rate is not None:
        if not (sample_rate > 0 and np.isfinite(sample_rate)):
            raise ExportError(f"sample_rate must be positive (Hz), got {sample_rate}")
        M = max(1, int(round(st.window_s * float(sample_rate))))
        span = 1 if detector_window is None else int(np.ceil(int(detector_window) / M)) + 1
        npend = int(np.ceil(st.hold_s * float(sample_rate) / M)) + 2
        watch = [0.0] + [float(chdtri(d, st.watch_p)) for d in range(1, max(n - 3, 1) + 1)]
        cal = trk.calibration
        groups = [g for g, blks in GROUPS if any(b in blks for b in trk.blocks)]
        group_of = [next(j for j, g in enumerate(groups) if b in dict(GROUPS)[g]) for b in trk.blocks]
        guard = st.guard_s is not None
        fields = (f"    double zb[{P}_WIN][{P}_N], gb[{P}_WIN][{P}_S];  /* the window's samples (held-out check) */\n"
                  f"    unsigned char okb[{P}_WIN][{P}_N];\n") if guard else ""
        header = header.replace("\n#endif\n", _LOOP_HEADER.format(P=P, p=prefix, M=M, span=span, npend=npend,
                                                                   rate=f"{float(sample_rate)!r}", ng=len(groups),
                                                                   guard_fields=fields) + "\n#endif\n")
        consts += [
            "/* the loop: the fusion's weighted least squares G (3 x N), scale factor (SI per raw unit), bias (SI) */",
            f"static const double {prefix}_G[3 * {n}] = {_array(trk.G)};",
            f"static const double {prefix}_sf[{n}] = {_array(cal.scale)};",
            f"static const double {prefix}_b[{n}] = {_array(cal.bias)};",
            f"static const double {prefix}_window_s = {_num(st.window_s)};  /* s */",
            f"static const double {prefix}_hold_s = {_num(st.hold_s)};  /* s */",
            f"static const int {prefix}_detector = {0 if detector_window is None else 1};",
            f"#define {P}_NWATCH {len(watch)}",
            f"/* the watch level chi2_(1 - watch_p)(dof) by dof (entry 0 unused) */\n"
            f"static const double {prefix}_watch[{P}_NWATCH] = {_array(watch)};",
            f"/* the held-out check: on (guard_s, s; guard_z), and the group (bias, scale, temperature) of each block */\n"
            f"static const int {prefix}_guard = {int(guard)};",
        ] + ([f"static const double {prefix}_guard_s = {_num(st.guard_s)};",
              f"static const double {prefix}_guard_z = {_num(st.guard_z)};"] if guard else []) + [

            f"static const int {prefix}_group[{m}] = {{{', '.join(str(j) for j in group_of)}}};",
        ]
        loop = _LOOP_SOURCE.format(P=P, p=prefix, keep=_GUARD_KEEP.format(P=P, p=prefix) if guard else "",
                                   check=f"    if ({prefix}_guard != 0) {{\n        {prefix}_check(L, isolated, t);\n"
                                         "    }\n" if guard else "")
        source += (_GUARD_CHECK.format(P=P, p=prefix) if guard else "") + loop
    if detector_window is not None and p_fa is not None:
        dofs = range(1, max(n - 3, 1) + 1)
        thr = [0.0] + [float(chdtri(d, p_fa)) for d in dofs]
        half = [0.0] + [float(chdtri(d, p_fa / 2.0)) for d in dofs] if cusum else thr
        designs = [tracked_cusum_design(d, int(detector_window), float(p_fa)) if cusum
                   else (1.0, np.ones(CUSUM_RHO_NODES)) for d in dofs]
        delta = [0.0] + [dz for dz, _ in designs]
        htab = [np.full(CUSUM_RHO_NODES, 1.0)] + [h for _, h in designs]
        header = header.replace("\n#endif\n", _GLT_HEADER.format(P=P, p=prefix, W=int(detector_window)) + "\n#endif\n")
        consts += [f"/* the detector's thresholds chi2_(1 - p_fa)(dof), p_fa = {p_fa!r}, and its window GLT's at p_fa / 2 "
                   "(entry 0 unused) */\n"
                   f"static const double {prefix}_thr_det[{len(thr)}] = {_array(thr)};",
                   f"static const double {prefix}_thr_half[{len(half)}] = {_array(half)};",
                   f"/* the CUSUM bank beside the window GLT: on (1) or not (0) */\n"
                   f"static const int {prefix}_cusum_on = {int(bool(cusum))};",
                   f"/* the CUSUM bank (rimu.fdi.selfcal.tracked_cusum_design): design shift delta by dof, thresholds h by dof "
                   f"and node (rho = node * step) */\n#define {P}_CUSUM_NODES {CUSUM_RHO_NODES}\n"
                   f"static const double {prefix}_cusum_step = {_num(CUSUM_RHO_STEP)};\n"
                   f"static const double {prefix}_cusum_delta[{len(delta)}] = {_array(delta)};\n"
                   f"static const double {prefix}_cusum_h[{len(htab)}][{P}_CUSUM_NODES] = {{\n"
                   + ",\n".join(_array(h) for h in htab) + "\n};"]
        source += _GLT_SOURCE.format(P=P, p=prefix)
    return header, "\n".join(consts) + source


# ---------------------------------------------------------------------------------------------- in the exported unit
def unit_prefix(instrument: str) -> str:
    """The prefix of an instrument's tracker in an exported unit (its files ``<prefix>.h`` / ``<prefix>.c``).

    >>> unit_prefix("gyro")
    'rimu_gyro_sc'
    """
    return f"rimu_{instrument.lower()}_sc"


def unit_files(trackers: dict[str, SelfCalTracker], sample_rate: float, p_fa: float,
               detector_window: int | None = None, cusum: bool = False) -> dict[str, str]:
    """The trackers' own translation units in an exported unit (:func:`rimu.export.export_c` with ``selfcal=``):
    each with its loop and the window GLT of the tracker's window (what :class:`rimu.fdi.Runtime` gives a tracked
    instrument's manager: ``TrackedGltWindow(round(window_s * rate), p_fa)``; ``detector_window``: of that many
    samples instead).

    >>> from rimu.calibration import InstrumentCalibration
    >>> from rimu.fdi.selfcal import SelfCalSettings
    >>> from rimu.geometry import cone6
    >>> cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)
    >>> files = unit_files({"gyro": SelfCalTracker(cal, SelfCalSettings(bias_rw=1e-8))}, 100.0, 1e-3)
    >>> sorted(files), "#define RIMU_GYRO_SC_GLT_WINDOW 100" in files["rimu_gyro_sc.h"]
    (['rimu_gyro_sc.c', 'rimu_gyro_sc.h'], True)
    """
    out = {}
    for k, trk in trackers.items():
        M = max(1, int(round(trk.settings.window_s * float(sample_rate))))
        h, c = selfcal_c(trk, unit_prefix(k), sample_rate, M if detector_window is None else int(detector_window), p_fa,
                         cusum)
        out[f"{unit_prefix(k)}.h"] = h
        out[f"{unit_prefix(k)}.c"] = c
    return out


def unit_header(trackers: dict[str, SelfCalTracker]) -> str:
    """Declarations for ``rimu_unit.h``: each tracked instrument's state and its step through the manager (the
    trackers' headers are included at the top of ``rimu_unit.h``: ``#include "<unit_prefix(k)>.h"``)."""
    lines = ["", "/* ---- in-flight self-calibration (rimu.fdi.selfcal; docs/selfcal.md): per tracked instrument */"]
    for k, trk in trackers.items():
        p, P = unit_prefix(k), unit_prefix(k).upper()
        lines += [
            f"/* {k}: the tracker's loop, the window GLT whose thresholds carry its covariance, and the tracked terms",
            " * the estimates file shows on a sample (those after the last window that ended before it). Zero-initialise",
            " * it. */",
            "typedef struct {",
            f"    {p}_loop loop;",
            f"    {p}_glt glt;",
            f"    double terms[{P}_S], sigmas[{P}_S];        /* SI, block-major ({', '.join(trk.blocks)}) x sensor */",
            f"    double terms_next[{P}_S], sigmas_next[{P}_S];",
            "    int started;",
            f"}} rimu_{k.lower()}_tracked;",
            f"/* {k}: one sample through the self-calibration and the redundancy manager, as rimu.fdi.Runtime does: the",
            " * compensated outputs corrected by the tracked terms, the manager's step with the window GLT, the tracker",
            " * told the alarm, the statistic and the isolated sensors (t: s, the log's own time; temperature: degC or",
            " * NULL). */",
            f"void rimu_{k.lower()}_sc_fdi_step(rimu_fdi *m, rimu_{k.lower()}_tracked *sc, double t, "
            "const double *temperature, const rimu_real *y, const unsigned char *valid, rimu_fdi_output *out);",
        ]
    return "\n".join(lines) + "\n"


def unit_source(trackers: dict[str, SelfCalTracker]) -> str:
    """The tracked instruments' steps for ``rimu_unit.c`` (after the manager's code: ``rimu_fdi_run``)."""
    out = []
    for k in trackers:
        p, P, lc = unit_prefix(k), unit_prefix(k).upper(), k.lower()
        out.append(f"""
/* {k}: Runtime._mstep with a SelfCalLoop: correct, the manager's step (its detector the tracked window GLT), observe */
void rimu_{lc}_sc_fdi_step(rimu_fdi *m, rimu_{lc}_tracked *sc, double t, const double *temperature, const rimu_real *y,
                          const unsigned char *valid, rimu_fdi_output *out)
{{
    double yc[{P}_N], C[{P}_N * {P}_N], st, thr;
    rimu_real z[RIMU_NMAX] = {{0}}, stat;
    unsigned char use[RIMU_NMAX] = {{0}}, iso[{P}_N];
    const rimu_fdi_unit *u = &{lc}_unit;
    int i, fresh;
    fresh = {p}_loop_correct(&sc->loop, y, valid, t, temperature, yc, C);
    if (sc->started == 0) {{
        {p}_loop_terms(&sc->loop, sc->terms_next, sc->sigmas_next);
        sc->started = 1;
    }}
    for (i = 0; i < {P}_S; ++i) {{  /* this sample shows the terms of the last window that ended before it */
        sc->terms[i] = sc->terms_next[i];
        sc->sigmas[i] = sc->sigmas_next[i];
    }}
    if (fresh != 0) {{
        {p}_glt_set_covariance(&sc->glt, C);
    }}
    /* the manager's sensor set of this sample and its compensated outputs, as rimu_fdi_run makes them */
    for (i = 0; i < {P}_N; ++i) {{
        int good = rimu_flag(((valid == NULL) || (valid[i] != 0u)) && (isfinite(yc[i]) != 0));
        int sat = rimu_flag((good != 0) && (u->range != NULL) && (RIMU_FABS(yc[i]) >= u->range[i]));
        use[i] = ((good != 0) && (sat == 0) && (m->iso[i] == 0u)) ? 1u : 0u;
        z[i] = (use[i] != 0u) ? (u->sf[i] * yc[i] - u->b[i]) : 0.0;
    }}
    if ((m->started == 0) || (rimu_same(use, m->prev, {P}_N) == 0)) {{  /* a new set: the window starts over */
        {p}_glt_configure(&sc->glt, use);
    }}
    st = {p}_glt_update(&sc->glt, z, &thr);
    stat = st;
    rimu_fdi_run(u, m, yc, valid, out, &stat);
    for (i = 0; i < {P}_N; ++i) {{
        iso[i] = (m->sensor[i] >= RIMU_ISOLATED) ? 1u : 0u;
    }}
    {p}_loop_observe(&sc->loop, out->alarm, out->statistic, out->dof, iso);
    if (sc->loop.k == 0L) {{  /* a window ended: its terms show from the next sample on */
        {p}_loop_terms(&sc->loop, sc->terms_next, sc->sigmas_next);
    }}
}}
""")
    return "".join(out)
