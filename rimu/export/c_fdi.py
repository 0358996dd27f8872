"""The decision logic of :class:`rimu.fdi.RedundancyManager` as generated C99 (used by :func:`rimu.export.export_c`).

What the generated ``rimu_<instrument>_fdi_step`` does per sample is the manager's ``step`` with its default
detector (:class:`rimu.fdi.GltSnapshot`) and isolator (:class:`rimu.fdi.multiple.FaultSetGlt`), decision for
decision:

* the GLT snapshot detector: ``|p|^2 > chi2_{1 - p_fa}(dof)`` (Daly, Gai & Harrison 1979), thresholds tabulated
  per parity dof at export time; with a calibration noise model (``cal.noise``) the statistic is the manager's
  whitened one, ``|L p|^2``, which equals the residual chi-square of the least squares weighted with the model's
  per-sample variances ``v_i`` (a parity statistic does not depend on the parity basis), so no per-set Cholesky
  factor is needed;
* the alarm episode's evidence (sum and scatter of the parity vectors) and the generalised likelihood test over
  sets of 1..``max_size`` sensors (``max_size`` <= 2) on its mean and on its scatter, confirmation over
  ``confirm`` consecutive alarms naming the same set, isolation (Cho & Park 2005, Eq. 21), the "fault present,
  not isolable" report and its clearing after ``clear_after`` quiet samples;
* isolation of a sensor invalid for ``invalid_persist`` consecutive samples (unless the rest would not span 3-D);
* the per-sensor state machine of :mod:`rimu.fdi.health` (SUSPECT, ISOLATED, RECOVERING, FAILED after
  ``fail_after`` isolations; clean period ``readmit_after * backoff^(isolations - 1)``, its length and energy
  thresholds tabulated) and the re-admission test;
* the set state (:class:`rimu.fdi.HealthState`) and the :class:`rimu.fusion.validity.Validity` flag.

What is precomputed and what is not. Nothing is tabulated per active set: the parity-space quantities of a set
are computed from the O(n) weighted least-squares solution (the closed form of :mod:`rimu.export.c99`). With
``e = W r`` the whitened residuals and ``Pi = I - W A P A^T W`` (``Pi_jk = delta_jk - sqrt(w_j w_k) a_j^T P a_k``),
the normalised parity ``p`` of any parity basis satisfies ``V^T p = e``, ``v_j . v_k = sqrt(w_j w_k) Pi_jk`` and for
a sensor set S ``|Q_S^T p|^2 = e_S^T Pi_SS^-1 e_S``, so the set test's ``R_S = trace(M) - trace(Pi_SS^-1 M_SS)``
needs the episode's scatter in sensor space (n(n+1)/2 numbers) and a 1x1 or 2x2 inverse per hypothesis. The
thresholds are tables written at export time by scipy: detection and re-admission by dof, and the consistency
thresholds of the set test, ``chi2_{1 - alpha}(N (dof - k))``, for every ``N (dof - k)`` it can need
(:meth:`rimu.fdi.FdiSettings.set_thresholds`): the scatter pools at most ``scatter_window`` samples of an episode
(two blocks of half as many, the older dropped when the newer is full, as the Python manager does), so ``N`` is
bounded and no chi-square quantile is computed on the target.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.special import chdtri  # chdtri(d, p) = chi2.isf(p, d), without importing scipy.stats (~40 MB)

from ..fdi.settings import C_INT_MAX, MAX_ISOLATIONS, FdiSettings  # noqa: F401  (re-exported)

__all__ = ["FdiSettings"]  # the one settings object lives in rimu.fdi.settings (with the C-int limits)


def detection_variance(inst: Any) -> np.ndarray | None:
    """Per-sample variances the manager's default detector whitens with (calibration noise model), or None."""
    noise = getattr(inst, "noise", None)
    if noise is None:
        return None
    from ..fdi.glt import as_noise_settings

    return np.asarray(as_noise_settings(noise).variance(1), dtype=float)


_FDI_HEADER = """
/* ---- fault detection, isolation and re-admission (rimu.fdi.RedundancyManager, generated with:
 * {settings}) */
#define RIMU_HEALTHY 0
#define RIMU_SUSPECT 1
#define RIMU_ISOLATED 2
#define RIMU_RECOVERING 3
#define RIMU_FAILED 4
/* Validity (rimu.fusion.validity.Validity) */
#define RIMU_NOMINAL 0
#define RIMU_DEGRADED 1
#define RIMU_UNOBSERVABLE 2
/* HealthState of a sensor set (rimu.fdi.HealthState, in the order of its STATE_CODES) */
#define RIMU_STATE_NOMINAL 0
#define RIMU_STATE_FAULT_ISOLATED 1
#define RIMU_STATE_DETECTION_ONLY 2
#define RIMU_STATE_NO_REDUNDANCY 3
#define RIMU_STATE_UNOBSERVABLE 4
#define RIMU_NTRI (RIMU_NMAX * (RIMU_NMAX + 1) / 2)
#define RIMU_STATE_CACHE 4

/* The manager's state of one instrument. Zero-initialise it (or call rimu_fdi_reset): every sensor healthy. */
typedef struct {{
    signed char sensor[RIMU_NMAX];      /* per-sensor state: RIMU_HEALTHY ... RIMU_FAILED */
    unsigned char iso[RIMU_NMAX];       /* 1: kept out of the estimate (isolated, recovering or failed) */
    int isolations[RIMU_NMAX];
    long clean[RIMU_NMAX];
    rimu_real csum[RIMU_NMAX], csumsq[RIMU_NMAX];
    long invalid_run[RIMU_NMAX];
    int invalid_pending, started, suspects_on, not_isolable;
    long quiet, samples;
    unsigned char prev[RIMU_NMAX];      /* the previous sample's set */
    long ep_n, ep_alarms, ep_quiet;     /* alarm episode: samples, alarms, quiet samples at its end */
    rimu_real ep_sum[RIMU_NMAX];        /* sum of the whitened residuals (= parity vectors) */
    rimu_real ep_M[2][RIMU_NTRI];       /* their scatter in two blocks (packed upper triangles): [ep_cur] the newer */
    long ep_mn;                         /* samples in the newer block (at most RIMU_FDI_BLOCK) */
    int ep_cur, ep_old;                 /* the newer block; 1: the older one is full and counts */
    int cand[2], ncand;
    long streak;
    int last_kind, last_nset, last_set[2];
    unsigned char last_sus[RIMU_NMAX];
    unsigned char cache_mask[RIMU_STATE_CACHE][RIMU_NMAX];
    signed char cache_state[RIMU_STATE_CACHE];
    int cache_next;
}} rimu_fdi;

/* One instrument's output for one sample, with the manager's decisions. */
typedef struct {{
    rimu_real x[3];             /* estimate in the master-body frame, SI (NaN when validity is RIMU_UNOBSERVABLE) */
    rimu_real P[9];             /* its covariance (zeros when unobservable) */
    int validity;               /* RIMU_NOMINAL, RIMU_DEGRADED or RIMU_UNOBSERVABLE */
    int state;                  /* HealthState of the sample's sensor set (RIMU_STATE_...) */
    int alarm;                  /* the detection test alarmed on this sample */
    rimu_real statistic, threshold;  /* the detector's, on the sample's set (threshold < 0: no parity) */
    int fault_not_isolable;     /* a fault is reported present but not isolable */
    int dof;                    /* parity dimension of the set x was computed from */
    unsigned char active[RIMU_NMAX];  /* sensors in x */
}} rimu_fdi_output;

void rimu_fdi_reset(rimu_fdi *m);
"""


_FDI_SOURCE = r"""
/* ======================================================================== fault management */
typedef struct {
    int n;
    const rimu_real *sf, *b, *ax, *w, *sig2, *wdet, *range; /* range: NULL when the calibration states none */
    const rimu_real *thr_det;   /* detection threshold by dof (index 0 unused) */
} rimu_fdi_unit;

typedef struct {
    rimu_real x[3], P[9], Pa[3 * RIMU_NMAX], q[RIMU_NMAX], e[RIMU_NMAX], chi2;
    int used, dof, observable;
} rimu_fit;

typedef struct {
    int kind, nset, set[2];
    unsigned char sus[RIMU_NMAX];
} rimu_dec;

enum { RIMU_DEC_NONE = 0, RIMU_DEC_ISOLATED, RIMU_DEC_AMBIGUOUS, RIMU_DEC_UNEXPLAINED, RIMU_DEC_NOT_ISOLABLE };

void rimu_fdi_reset(rimu_fdi *m)
{
    unsigned char *p = (unsigned char *)m;
    size_t i;
    for (i = 0; i < sizeof *m; ++i) {
        p[i] = 0u;
    }
}

/* the unit's sensor count, bounded by the arrays it indexes (RIMU_NMAX): every sensor loop runs to this */
static int rimu_n(const rimu_fdi_unit *u)
{
    return (u->n < RIMU_NMAX) ? u->n : RIMU_NMAX;
}

/* 1 for a true condition, 0 for a false one: the int flags of the state and output */
static int rimu_flag(int c)
{
    return (c != 0) ? 1 : 0;
}

/* table index of a dof (the tables are sized for RIMU_NMAX; the clamp only tells the compiler so) */
#define RIMU_DOFC(d) (((d) < 0) ? 0 : (((d) > (RIMU_NMAX - 3)) ? (RIMU_NMAX - 3) : (d)))

/* chi2_{1-alpha}(samples (dof - k)): the set test's consistency threshold, from the table written at export time
 * (samples <= RIMU_FDI_WINDOW, dof <= RIMU_NMAX - 3: every index is in the table; the clamp only tells the
 * compiler so) */
static rimu_real rimu_thr_set(int dof, int k, long samples)
{
    long nu = samples * ((long)dof - (long)k);
    if (nu < 1L) {
        nu = 1L;
    }
    if (nu > RIMU_FDI_NU) {
        nu = RIMU_FDI_NU;
    }
    return rimu_fdi_chi2[nu];
}

/* P a_i and q_i = 1 - w_i a_i^T P a_i of the used sensors of an observable fit: made for the isolation test only
 * (a set's state, an alarm), not on every sample */
static void rimu_fit_q(const rimu_fdi_unit *u, const rimu_real *w, const unsigned char *use, rimu_fit *f)
{
    rimu_real P00 = f->P[0], P01 = f->P[1], P02 = f->P[2], P11 = f->P[4], P12 = f->P[5], P22 = f->P[8];
    int i, n = rimu_n(u);
    if (f->observable == 0) {
        return;
    }
    for (i = 0; i < n; ++i) {
        const rimu_real *a = u->ax + 3 * i;
        rimu_real *pa = f->Pa + 3 * i;
        if (use[i] == 0u) {
            continue;
        }
        pa[0] = P00 * a[0] + P01 * a[1] + P02 * a[2];
        pa[1] = P01 * a[0] + P11 * a[1] + P12 * a[2];
        pa[2] = P02 * a[0] + P12 * a[1] + P22 * a[2];
        f->q[i] = 1.0 - w[i] * (a[0] * pa[0] + a[1] * pa[1] + a[2] * pa[2]);
    }
}

/* ---- weighted least squares on one sensor set (weights w), with the whitened residuals
 * e_i = sqrt(w_i) (z_i - a_i . x) when z is given, else with P a_i and q_i (rimu_fit_q) */
static void rimu_fit_set(const rimu_fdi_unit *u, const rimu_real *w, const unsigned char *use, const rimu_real *z,
                         rimu_fit *f)
{
    rimu_real N00 = 0.0, N01 = 0.0, N02 = 0.0, N11 = 0.0, N12 = 0.0, N22 = 0.0, h0 = 0.0, h1 = 0.0, h2 = 0.0;
    rimu_real scale = 0.0, x0, x1, x2;
    int i, m = 0, n = rimu_n(u);
    for (i = 0; i < n; ++i) {
        const rimu_real *a = u->ax + 3 * i;
        f->e[i] = 0.0;
        f->q[i] = 0.0;
        if (use[i] == 0u) {
            continue;
        }
        N00 += w[i] * a[0] * a[0]; N01 += w[i] * a[0] * a[1]; N02 += w[i] * a[0] * a[2];
        N11 += w[i] * a[1] * a[1]; N12 += w[i] * a[1] * a[2]; N22 += w[i] * a[2] * a[2];
        if (z != NULL) {
            h0 += w[i] * z[i] * a[0]; h1 += w[i] * z[i] * a[1]; h2 += w[i] * z[i] * a[2];
        }
        scale += w[i];
        ++m;
    }
    for (i = 0; i < 9; ++i) {
        f->P[i] = 0.0;
    }
    f->x[0] = f->x[1] = f->x[2] = 0.0;
    f->chi2 = 0.0;
    f->used = m;
    f->dof = 0;
    {
        const rimu_real Nv[6] = {N00, N01, N02, N11, N12, N22}, hv[3] = {h0, h1, h2};
        if (rimu_inverse3(Nv, scale, m, hv, f->P, f->x) == 0) {
            f->observable = 0;
            return;
        }
    }
    f->observable = 1;
    f->dof = m - 3;
    if (z == NULL) {
        rimu_fit_q(u, w, use, f);
        return;
    }
    x0 = f->x[0]; x1 = f->x[1]; x2 = f->x[2];  /* in registers: the stores below may alias f->x */
    for (i = 0; i < n; ++i) {
        const rimu_real *a = u->ax + 3 * i;
        rimu_real r;
        if (use[i] == 0u) {
            continue;
        }
        r = z[i] - (a[0] * x0 + a[1] * x1 + a[2] * x2);
        f->e[i] = RIMU_SQRT(w[i]) * r;
        f->chi2 += w[i] * r * r;
    }
}

/* Pi_jk of the set fitted in f (j != k) */
static rimu_real rimu_pi(const rimu_fdi_unit *u, const rimu_fit *f, int j, int k)
{
    const rimu_real *a = u->ax + 3 * j, *pb = f->Pa + 3 * k;
    return -RIMU_SQRT(u->w[j] * u->w[k]) * (a[0] * pb[0] + a[1] * pb[1] + a[2] * pb[2]);
}

static int rimu_same(const unsigned char *a, const unsigned char *b, int n)
{
    int i;
    for (i = 0; i < n; ++i) {
        if ((a[i] != 0u) != (b[i] != 0u)) {
            return 0;
        }
    }
    return 1;
}

/* HealthState of a sensor set (RedundancyManager._state_of), cached for a few sets */
static int rimu_state_of(const rimu_fdi_unit *u, rimu_fdi *m, const unsigned char *use)
{
    rimu_fit f;
    int i, j, k, n = rimu_n(u), st, ok;
    for (i = 0; i < RIMU_STATE_CACHE; ++i) {
        if ((m->cache_state[i] > 0) && (rimu_same(m->cache_mask[i], use, n) != 0)) {
            return m->cache_state[i] - 1;
        }
    }
    rimu_fit_set(u, u->w, use, NULL, &f);
    if (f.observable == 0) {
        st = RIMU_STATE_UNOBSERVABLE;
    } else if ((f.used == 3) || (f.dof == 0)) {
        st = RIMU_STATE_NO_REDUNDANCY;
    } else {
        ok = rimu_flag(f.dof >= 2);
        for (j = 0; (ok != 0) && (j < n); ++j) {
            if ((use[j] == 0u) || !(RIMU_SQRT(u->w[j] * f.q[j]) > (rimu_real)1e-9)) {
                continue;
            }
            for (k = j + 1; k < n; ++k) {
                rimu_real rho;
                if ((use[k] == 0u) || !(RIMU_SQRT(u->w[k] * f.q[k]) > (rimu_real)1e-9)) {
                    continue;
                }
                rho = rimu_pi(u, &f, j, k) / RIMU_SQRT(f.q[j] * f.q[k]);
                if (!(RIMU_FABS(rho) < (rimu_real)(1.0 - 1e-6))) {
                    ok = 0;
                    break;
                }
            }
        }
        if (ok == 0) {
            st = RIMU_STATE_DETECTION_ONLY;
        } else if (f.used < n) {
            st = RIMU_STATE_FAULT_ISOLATED;
        } else {
            st = RIMU_STATE_NOMINAL;
        }
    }
    i = m->cache_next;
    m->cache_next = (i + 1) % RIMU_STATE_CACHE;
    for (j = 0; j < n; ++j) {
        m->cache_mask[i][j] = (use[j] != 0u) ? 1u : 0u;
    }
    m->cache_state[i] = (signed char)(st + 1);
    return st;
}

#define RIMU_TRI(i, j) ((((j) * ((j) + 1)) / 2) + (i))  /* i <= j */

/* an entry of the scatter M + Mo (packed; Mo NULL: M alone) */
static rimu_real rimu_mij(const rimu_real *M, const rimu_real *Mo, int k)
{
    return (Mo != NULL) ? (M[k] + Mo[k]) : M[k];
}

/* Generalised likelihood test over sensor sets of 1..RIMU_FDI_K (FaultSetGlt.decide_scatter), on the scatter
 * M + Mo (packed; samples of it) or, when M is NULL, on the single vector s (M = s s^T). f: the set's fit. */
static void rimu_decide(const rimu_fdi_unit *u, const rimu_fit *f, const unsigned char *use, const rimu_real *M,
                        const rimu_real *Mo, const rimu_real *s, long samples, rimu_dec *dec)
{
    int n = rimu_n(u), d = f->dof, cand[RIMU_NMAX], mm = 0, K, i, a, b, nmin = 0;
    unsigned char single[RIMU_NMAX] = {0};
    rimu_real total = 0.0, c;
    long pairs;
    dec->kind = RIMU_DEC_NOT_ISOLABLE;
    dec->nset = 0;
    for (i = 0; i < n; ++i) {
        dec->sus[i] = 0u;
    }
    if (d < 2) {
        return;
    }
    for (i = 0; i < n; ++i) {
        single[i] = 0u;
        if (use[i] == 0u) {
            continue;
        }
        if (RIMU_SQRT(u->w[i] * f->q[i]) > (rimu_real)1e-12) {
            cand[mm] = i;
            ++mm;
        }
        total += (M != NULL) ? rimu_mij(M, Mo, RIMU_TRI(i, i)) : (s[i] * s[i]);
    }
    K = RIMU_FDI_K;
    if (K > (d - 1)) {
        K = d - 1;
    }
    if (K > mm) {
        K = mm;
    }
    pairs = ((long)mm * ((long)mm - 1L)) / 2L;
    if ((K >= 1) && (mm <= RIMU_FDI_MAX_SETS)) {
        c = rimu_thr_set(d, 1, samples);
        for (a = 0; a < mm; ++a) {
            int j = cand[a];
            rimu_real Mjj = (M != NULL) ? rimu_mij(M, Mo, RIMU_TRI(j, j)) : (s[j] * s[j]);
            rimu_real R = total - (Mjj / f->q[j]);
            if (R <= c) {
                single[j] = 1u;
                dec->sus[j] = 1u;
                if (nmin == 0) {
                    dec->set[0] = j;
                    dec->nset = 1;
                }
                ++nmin;
            }
        }
        if ((K >= 2) && (pairs <= RIMU_FDI_MAX_SETS)) {
            int nsingle = nmin, tested = 0;
            rimu_real c2 = 0.0;
            for (a = 0; a < mm; ++a) {
                int j = cand[a];
                for (b = a + 1; b < mm; ++b) {
                    int l = cand[b];
                    rimu_real pjl = rimu_pi(u, f, j, l), rho = pjl / RIMU_SQRT(f->q[j] * f->q[l]), det, T, R;
                    rimu_real Mjj, Mll, Mjl;
                    if (!(RIMU_SQRT(1.0 - RIMU_FABS(rho)) > RIMU_FDI_COLLINEAR_TOL)) {
                        continue;  /* not a hypothesis */
                    }
                    if (tested == 0) {
                        c2 = rimu_thr_set(d, 2, samples);
                        tested = 1;
                    }
                    if (M != NULL) {
                        Mjj = rimu_mij(M, Mo, RIMU_TRI(j, j)); Mll = rimu_mij(M, Mo, RIMU_TRI(l, l));
                        Mjl = rimu_mij(M, Mo, RIMU_TRI(j, l));
                    } else {
                        Mjj = s[j] * s[j]; Mll = s[l] * s[l]; Mjl = s[j] * s[l];
                    }
                    det = f->q[j] * f->q[l] - pjl * pjl;
                    T = (f->q[l] * Mjj - 2.0 * pjl * Mjl + f->q[j] * Mll) / det;
                    R = total - T;
                    if ((R <= c2) && ((nsingle == 0) || ((single[j] == 0u) && (single[l] == 0u)))) {
                        dec->sus[j] = 1u;
                        dec->sus[l] = 1u;
                        if (nmin == 0) {
                            dec->set[0] = j;
                            dec->set[1] = l;
                            dec->nset = 2;
                        }
                        ++nmin;
                    }
                }
            }
        }
    }
    if (nmin == 1) {
        dec->kind = RIMU_DEC_ISOLATED;
    } else if (nmin > 1) {
        dec->kind = RIMU_DEC_AMBIGUOUS;
        dec->nset = 0;
    } else {
        dec->kind = RIMU_DEC_UNEXPLAINED;
        dec->nset = 0;
    }
}

static void rimu_set_suspects(rimu_fdi *m, int n, const unsigned char *mask)
{
    int i;
    for (i = 0; i < n; ++i) {
        if ((mask[i] != 0u) && (m->sensor[i] == RIMU_HEALTHY)) {
            m->sensor[i] = RIMU_SUSPECT;
        } else if ((mask[i] == 0u) && (m->sensor[i] == RIMU_SUSPECT)) {
            m->sensor[i] = RIMU_HEALTHY;
        } else {
            /* the state stays */
        }
    }
}

static void rimu_new_episode(rimu_fdi *m, int n)
{
    int i;
    m->ep_n = 0L;
    m->ep_alarms = 0L;
    m->ep_quiet = 0L;
    for (i = 0; i < n; ++i) {
        m->ep_sum[i] = 0.0;
    }
    m->ep_mn = 0L;  /* the scatter's blocks are written over by the first sample of the episode */
    m->ep_cur = 0;
    m->ep_old = 0;
    m->ncand = 0;
    m->streak = 0L;
    m->last_kind = RIMU_DEC_NONE;
}

/* the sample's whitened residuals into the episode's sum and the newer block of its scatter; when that block is
 * full (RIMU_FDI_BLOCK samples) it becomes the older one and the oldest is written over
 * (RedundancyManager._accumulate) */
static void rimu_accumulate(rimu_fdi *m, int n, const rimu_fit *f)
{
    int i, j;
    rimu_real *M;
    if (m->ep_mn >= RIMU_FDI_BLOCK) {
        m->ep_cur = 1 - m->ep_cur;
        m->ep_old = 1;
        m->ep_mn = 0L;
    }
    M = m->ep_M[m->ep_cur];
    for (j = 0; j < n; ++j) {
        if (m->ep_mn == 0L) {  /* the block's first sample: written, not added (no zeroing pass) */
            for (i = 0; i <= j; ++i) {
                M[RIMU_TRI(i, j)] = f->e[i] * f->e[j];
            }
        } else if (f->e[j] != 0.0) {
            for (i = 0; i <= j; ++i) {
                M[RIMU_TRI(i, j)] += f->e[i] * f->e[j];
            }
        } else {
            /* a sensor out of the set: nothing to add */
        }
        m->ep_sum[j] += f->e[j];
    }
    m->ep_mn += 1L;
    m->ep_n += 1L;
}

static void rimu_apply(rimu_fdi *m, int n)
{
    int i;
    for (i = 0; i < n; ++i) {
        m->iso[i] = (m->sensor[i] >= RIMU_ISOLATED) ? 1u : 0u;
    }
}

/* SensorHealth.isolate */
static void rimu_isolate(rimu_fdi *m, int i)
{
    if (m->sensor[i] >= RIMU_ISOLATED) {
        return;
    }
    m->isolations[i] += 1;
    m->clean[i] = 0L;
    m->csum[i] = 0.0;
    m->csumsq[i] = 0.0;
    m->sensor[i] = (m->isolations[i] >= RIMU_FDI_FAIL_AFTER) ? RIMU_FAILED : RIMU_ISOLATED;
}

static void rimu_unclean(rimu_fdi *m, int i)
{
    if (m->sensor[i] == RIMU_RECOVERING) {
        m->sensor[i] = RIMU_ISOLATED;
    }
    m->clean[i] = 0L;
    m->csum[i] = 0.0;
    m->csumsq[i] = 0.0;
}

/* SensorHealth.clean_sample: 1 when sensor i is re-admitted by this sample */
static int rimu_clean_sample(rimu_fdi *m, int i, rimu_real z)
{
    int k;
    long need;
    if ((m->sensor[i] != RIMU_ISOLATED) && (m->sensor[i] != RIMU_RECOVERING)) {
        return 0;
    }
    if (RIMU_FDI_READMIT_AFTER <= 0) {
        return 0;
    }
    k = m->isolations[i] - 1;
    if (k < 0) {
        k = 0;
    }
    if (k >= RIMU_FDI_NREQ) {
        k = RIMU_FDI_NREQ - 1;
    }
    need = rimu_fdi_required[k];
    if (!((z * z) < RIMU_FDI_SAMPLE_THR)) {
        rimu_unclean(m, i);
        return 0;
    }
    m->sensor[i] = RIMU_RECOVERING;
    m->clean[i] += 1L;
    m->csum[i] += z;
    m->csumsq[i] += z * z;
    if (m->clean[i] >= need) {
        rimu_real N = (rimu_real)m->clean[i];
        if (((m->csum[i] * m->csum[i] / N) < RIMU_FDI_MEAN_THR) && (m->csumsq[i] < rimu_fdi_energy[k])) {
            m->sensor[i] = RIMU_HEALTHY;
            m->clean[i] = 0L;
            m->csum[i] = 0.0;
            m->csumsq[i] = 0.0;
            return 1;
        }
        rimu_unclean(m, i);
    }
    return 0;
}

/* RedundancyManager._invalid: 1 when the isolation set changed */
static int rimu_invalid(const rimu_fdi_unit *u, rimu_fdi *m, const unsigned char *inv)
{
    int i, j, k, n = rimu_n(u), changed = 0, any = 0, nc = 0, cand[RIMU_NMAX] = {0};
    unsigned char mask[RIMU_NMAX] = {0};
    for (i = 0; i < n; ++i) {
        if ((inv[i] == 0u) && (m->invalid_run[i] > 0L)) {
            m->invalid_run[i] = 0L;
        }
        if (inv[i] != 0u) {
            m->invalid_run[i] += 1L;
        }
        if (m->invalid_run[i] != 0L) {
            any = 1;
        }
        mask[i] = ((inv[i] != 0u) || (m->sensor[i] == RIMU_SUSPECT)) ? 1u : 0u;
    }
    m->invalid_pending = any;
    rimu_set_suspects(m, n, mask);
    m->suspects_on = 1;
    for (i = 0; i < n; ++i) {
        if ((m->invalid_run[i] >= RIMU_FDI_INVALID_PERSIST) && (m->iso[i] == 0u)) {
            cand[nc] = i;
            ++nc;
        }
    }
    for (j = 0; j < nc; ++j) {
        unsigned char keep[RIMU_NMAX] = {0};
        i = cand[j];
        for (k = 0; k < n; ++k) {
            keep[k] = (m->iso[k] == 0u) ? 1u : 0u;
        }
        keep[i] = 0u;
        if (rimu_state_of(u, m, keep) == RIMU_STATE_UNOBSERVABLE) {
            continue;
        }
        rimu_isolate(m, i);
        rimu_apply(m, n);
        changed = 1;
    }
    return changed;
}

/* RedundancyManager._decide */
static void rimu_decide_episode(const rimu_fdi_unit *u, rimu_fdi *m, const rimu_fit *f, const unsigned char *use,
                                rimu_dec *dec)
{
    int i, n = rimu_n(u);
    long N = m->ep_n;
    rimu_real s[RIMU_NMAX] = {0}, ss = 0.0, sq = RIMU_SQRT((rimu_real)N);
    if ((m->last_kind != RIMU_DEC_NONE) && (m->last_kind != RIMU_DEC_ISOLATED)
        && (m->ep_alarms > (4L * RIMU_FDI_CONFIRM)) && ((m->ep_alarms % 10L) != 0L)) {
        dec->kind = m->last_kind;
        dec->nset = m->last_nset;
        dec->set[0] = m->last_set[0];
        dec->set[1] = m->last_set[1];
        for (i = 0; i < n; ++i) {
            dec->sus[i] = m->last_sus[i];
        }
        return;
    }
    for (i = 0; i < n; ++i) {
        s[i] = m->ep_sum[i] / sq;
        ss += s[i] * s[i];
    }
    rimu_decide(u, f, use, NULL, NULL, s, 1L, dec);
    if ((dec->kind != RIMU_DEC_ISOLATED) && (N > 1L)) {
        /* the scatter of the last RIMU_FDI_BLOCK + 1 .. RIMU_FDI_WINDOW samples: a threshold of the table */
        rimu_dec d2;
        long ns = m->ep_mn;
        const rimu_real *Mo = NULL;
        if (m->ep_old != 0) {
            ns += RIMU_FDI_BLOCK;
            Mo = m->ep_M[1 - m->ep_cur];
        }
        rimu_decide(u, f, use, m->ep_M[m->ep_cur], Mo, NULL, ns, &d2);
        if ((d2.kind == RIMU_DEC_ISOLATED) || (ss < rimu_thr_set(f->dof, 0, 1L))) {
            *dec = d2;
        }
    }
}

/* RedundancyManager._on_alarm: the sensors to leave out of this sample's output (excl), 1 when isolated */
static int rimu_on_alarm(const rimu_fdi_unit *u, rimu_fdi *m, const rimu_fit *f, const unsigned char *use,
                         const unsigned char *inv, unsigned char *excl)
{
    int i, n = rimu_n(u), same;
    unsigned char mask[RIMU_NMAX] = {0}, rest[RIMU_NMAX] = {0};
    rimu_dec dec = {0};  /* set[] is read below even when nset is 0 */
    m->ep_alarms += 1L;
    m->ep_quiet = 0L;
    if (f->dof >= 1) {
        rimu_accumulate(m, n, f);
        rimu_decide_episode(u, m, f, use, &dec);
    } else {
        dec.kind = RIMU_DEC_NOT_ISOLABLE;
        dec.nset = 0;
        for (i = 0; i < n; ++i) {
            dec.sus[i] = 0u;
        }
    }
    m->last_kind = dec.kind;
    m->last_nset = dec.nset;
    m->last_set[0] = dec.set[0];
    m->last_set[1] = dec.set[1];
    for (i = 0; i < n; ++i) {
        m->last_sus[i] = dec.sus[i];
        mask[i] = ((dec.sus[i] != 0u) || (inv[i] != 0u)) ? 1u : 0u;
    }
    rimu_set_suspects(m, n, mask);
    m->suspects_on = 1;
    if (dec.kind != RIMU_DEC_ISOLATED) {
        int any = 0;
        m->streak = 0L;
        m->ncand = 0;
        if ((m->ep_alarms >= RIMU_FDI_CONFIRM) && (m->not_isolable == 0)) {
            m->not_isolable = 1;
            m->quiet = 0L;
        }
        for (i = 0; i < n; ++i) {
            rest[i] = ((use[i] != 0u) && (dec.sus[i] == 0u)) ? 1u : 0u;
            if (dec.sus[i] != 0u) {
                any = 1;
            }
        }
        if ((any != 0) && (rimu_state_of(u, m, rest) != RIMU_STATE_UNOBSERVABLE)) {
            for (i = 0; i < n; ++i) {
                excl[i] = dec.sus[i];
            }
        }
        return 0;
    }
    same = rimu_flag(dec.nset == m->ncand);
    for (i = 0; (same != 0) && (i < dec.nset); ++i) {
        same = rimu_flag(dec.set[i] == m->cand[i]);
    }
    if (same != 0) {
        m->streak += 1L;
    } else {
        m->ncand = dec.nset;
        m->cand[0] = dec.set[0];
        m->cand[1] = dec.set[1];
        m->streak = 1L;
    }
    for (i = 0; i < n; ++i) {
        rest[i] = use[i];
    }
    for (i = 0; i < dec.nset; ++i) {
        rest[dec.set[i]] = 0u;
    }
    if (rimu_state_of(u, m, rest) == RIMU_STATE_UNOBSERVABLE) {
        return 0;  /* never isolate into blindness */
    }
    for (i = 0; i < dec.nset; ++i) {
        excl[dec.set[i]] = 1u;
    }
    if (m->streak < RIMU_FDI_CONFIRM) {
        return 0;
    }
    for (i = 0; i < dec.nset; ++i) {
        rimu_isolate(m, dec.set[i]);
    }
    rimu_apply(m, n);
    rimu_new_episode(m, n);
    if (m->not_isolable != 0) {
        m->not_isolable = 0;
        m->quiet = 0L;
    }
    return 1;
}

/* one sample through the manager; stat_ext: the detection statistic of the caller's detector on this sample's set
 * (the window GLT of the self-calibration, rimu.fdi.selfcal.TrackedGltWindow), NULL: the GLT snapshot's */
static void rimu_fdi_run(const rimu_fdi_unit *u, rimu_fdi *m, const rimu_real *y, const unsigned char *valid,
                         rimu_fdi_output *out, const rimu_real *stat_ext)
{
    int i, n = rimu_n(u), changed = 0, alarm, nex = 0, code_full = 1;
    unsigned char inv[RIMU_NMAX] = {0}, use[RIMU_NMAX] = {0}, excl[RIMU_NMAX] = {0}, notiso[RIMU_NMAX] = {0};
    unsigned char use_y[RIMU_NMAX] = {0};
    rimu_real z[RIMU_NMAX] = {0}, stat = 0.0, thr = -1.0;
    rimu_fit f, g;
    const rimu_fit *o;
    m->samples += 1L;
    /* the pipeline: compensation (Cho & Park Eq. 20) on the valid, unsaturated, not isolated sensors */
    for (i = 0; i < n; ++i) {
        int good = rimu_flag(((valid == NULL) || (valid[i] != 0u)) && (isfinite(y[i]) != 0));
        int sat = rimu_flag((good != 0) && (u->range != NULL) && (RIMU_FABS(y[i]) >= u->range[i]));
        inv[i] = (good == 0) ? 1u : 0u;
        use_y[i] = ((good != 0) && (sat == 0)) ? 1u : 0u;
        use[i] = ((use_y[i] != 0u) && (m->iso[i] == 0u)) ? 1u : 0u;
        z[i] = (use[i] != 0u) ? (u->sf[i] * y[i] - u->b[i]) : 0.0;
        excl[i] = 0u;
        notiso[i] = (m->iso[i] == 0u) ? 1u : 0u;
    }
    rimu_fit_set(u, u->w, use, z, &f);
    if ((m->started == 0) || (rimu_same(use, m->prev, n) == 0)) {  /* a new set: the episode ends */
        m->started = 1;
        for (i = 0; i < n; ++i) {
            m->prev[i] = use[i];
        }
        if (m->ep_n != 0L) {
            rimu_new_episode(m, n);
        }
    }
    if ((rimu_same(use, notiso, n) == 0) || (m->invalid_pending != 0)) {
        changed = rimu_invalid(u, m, inv);
    }
    if (f.dof >= 1) {
        if (stat_ext != NULL) {
            stat = *stat_ext;
        } else if (u->wdet != u->w) {
            rimu_fit_set(u, u->wdet, use, z, &g);
            stat = g.chi2;
        } else {
            stat = f.chi2;
        }
        thr = u->thr_det[RIMU_DOFC(f.dof)];
    }
    alarm = rimu_flag((f.dof >= 1) && (stat > thr));
    if (alarm != 0) {
        m->quiet = 0L;
        rimu_fit_q(u, u->w, use, &f);  /* the isolation test's P a_i, q_i */
        if (rimu_on_alarm(u, m, &f, use, inv, excl) != 0) {
            changed = 1;
        }
    } else {
        if (m->ep_n != 0L) {
            long gap = RIMU_FDI_EPISODE_GAP;
            if (m->not_isolable != 0) {
                gap = RIMU_FDI_CLEAR_AFTER;  /* an unresolved fault: keep pooling */
            }
            m->ep_quiet += 1L;
            if ((m->ep_quiet >= gap) || (f.dof < 1)) {
                rimu_new_episode(m, n);
            } else {
                rimu_accumulate(m, n, &f);
                m->streak = 0L;
            }
        }
        if (m->not_isolable != 0) {
            m->quiet += 1L;
            if (m->quiet >= RIMU_FDI_CLEAR_AFTER) {
                m->not_isolable = 0;
                m->quiet = 0L;
            }
        }
        if (m->suspects_on != 0) {
            int any = 0;
            rimu_set_suspects(m, n, inv);
            for (i = 0; i < n; ++i) {
                if (m->sensor[i] == RIMU_SUSPECT) {
                    any = 1;
                }
            }
            m->suspects_on = any;
        }
    }
    if (changed != 0) {
        for (i = 0; i < n; ++i) {
            excl[i] = ((m->iso[i] != 0u) && (use[i] != 0u)) ? 1u : 0u;
        }
    }
    /* the output: the sample's set, or that set without the excluded sensors (x, P, dof together) */
    for (i = 0; i < n; ++i) {
        if (excl[i] != 0u) {
            ++nex;
        }
        if (use[i] == 0u) {
            code_full = 0;
        }
    }
    o = &f;
    for (i = 0; i < n; ++i) {
        out->active[i] = use[i];
    }
    if ((nex != 0) && (f.observable != 0)) {
        unsigned char act1[RIMU_NMAX] = {0};
        for (i = 0; i < n; ++i) {
            act1[i] = ((use[i] != 0u) && (excl[i] == 0u)) ? 1u : 0u;
        }
        rimu_fit_set(u, u->w, act1, z, &g);
        o = &g;
        for (i = 0; i < n; ++i) {
            out->active[i] = act1[i];
        }
    }
    for (i = 0; i < 3; ++i) {
        out->x[i] = (o->observable != 0) ? o->x[i] : NAN;  /* no estimate: not a number */
    }
    for (i = 0; i < 9; ++i) {
        out->P[i] = o->P[i];
    }
    out->dof = o->dof;
    out->alarm = alarm;
    out->statistic = stat;
    out->threshold = thr;
    out->fault_not_isolable = m->not_isolable;
    if (o->observable == 0) {
        out->validity = RIMU_UNOBSERVABLE;
        out->state = RIMU_STATE_UNOBSERVABLE;
    } else {
        out->state = rimu_state_of(u, m, out->active);  /* the state of the set in x, P and dof */
        if ((code_full != 0) && (nex == 0) && (alarm == 0) && (m->not_isolable == 0) && (m->ep_alarms == 0L)) {
            out->validity = RIMU_NOMINAL;
        } else {
            out->validity = RIMU_DEGRADED;
        }
    }
    /* re-admission of isolated sensors that agree with the estimate of the others */
    if ((RIMU_FDI_READMIT_AFTER > 0) && (o->observable != 0) && (alarm == 0) && (m->not_isolable == 0)
        && (m->ep_alarms == 0L)) {
        int back = 0;
        for (i = 0; i < n; ++i) {
            const rimu_real *a = u->ax + 3 * i;
            const rimu_real *P = o->P;
            rimu_real r, v;
            if ((m->iso[i] == 0u) || (m->sensor[i] == RIMU_FAILED)) {
                continue;
            }
            if (use_y[i] == 0u) {  /* no measurement (invalid, non-finite, clipped): the clean period restarts */
                rimu_unclean(m, i);
                continue;
            }
            r = (u->sf[i] * y[i] - u->b[i]) - (a[0] * o->x[0] + a[1] * o->x[1] + a[2] * o->x[2]);
            v = u->sig2[i] + a[0] * (P[0] * a[0] + P[1] * a[1] + P[2] * a[2])
                + a[1] * (P[3] * a[0] + P[4] * a[1] + P[5] * a[2]) + a[2] * (P[6] * a[0] + P[7] * a[1] + P[8] * a[2]);
            if (rimu_clean_sample(m, i, r / RIMU_SQRT(v)) != 0) {
                back = 1;
            }
        }
        if (back != 0) {
            rimu_apply(m, n);
        }
    }
}
"""


def fdi_header(settings: FdiSettings) -> str:
    return _FDI_HEADER.format(settings=", ".join(f"{k}={v!r}" for k, v in settings.__dict__.items()))


def fdi_defines(settings: FdiSettings, num: Any, nmax: int) -> str:
    """The configuration as #defines, the re-admission tables and the set test's thresholds for units of up to
    ``nmax`` sensors (``num`` formats a number for the real type)."""
    s = settings
    req = s.required()
    thr = s.set_thresholds(nmax)
    lines = [
        f"#define RIMU_FDI_CONFIRM {s.confirm}",
        f"#define RIMU_FDI_INVALID_PERSIST {s.invalid_persist}",
        f"#define RIMU_FDI_READMIT_AFTER {s.readmit_after or 0}  /* 0: never automatically */",
        f"#define RIMU_FDI_FAIL_AFTER {s.fail_after}",
        f"#define RIMU_FDI_CLEAR_AFTER {s.clear_after}",
        f"#define RIMU_FDI_EPISODE_GAP {s.gap}",
        f"#define RIMU_FDI_K {s.max_size}  /* largest sensor set the isolation test names */",
        f"#define RIMU_FDI_MAX_SETS {s.max_sets}L",
        f"#define RIMU_FDI_COLLINEAR_TOL {num(s.collinear_tol)}",
        f"#define RIMU_FDI_ALPHA {float(s.alpha)!r}  /* level of the consistency test of a sensor set */",
        f"#define RIMU_FDI_WINDOW {s.scatter_window}L  /* the most samples the set test's scatter pools */",
        f"#define RIMU_FDI_BLOCK {s.scatter_window // 2}L  /* in two blocks of this many */",
        f"#define RIMU_FDI_NU {len(thr) - 1}L  /* the largest nu = samples (dof - k) of its thresholds */",
        f"#define RIMU_FDI_MEAN_THR {num(s.mean_threshold())}  /* chi2_(1-p_fa)(1): mean residual, re-admission */",
        f"#define RIMU_FDI_SAMPLE_THR {num(float(chdtri(1, 1e-6)))}  /* chi2_(1-1e-6)(1): each clean sample */",
        f"#define RIMU_FDI_NREQ {len(req)}",
        "/* clean samples before re-admission after the 1st, 2nd, ... isolation, and the energy threshold */",
        f"static const long rimu_fdi_required[RIMU_FDI_NREQ] = {{{', '.join(f'{r}L' for r in req)}}};",
        f"static const rimu_real rimu_fdi_energy[RIMU_FDI_NREQ] = {{{', '.join(num(e) for e in s.energy())}}};",
        "/* the set test's consistency thresholds chi2_(1-alpha)(nu), nu = samples (dof - k) = 0 .. RIMU_FDI_NU (entry 0",
        " * unused; rimu.fdi.FdiSettings.set_thresholds) */",
        f"static const rimu_real rimu_fdi_chi2[RIMU_FDI_NU + 1] = {{{_table(thr, num)}}};",
    ]
    return "\n".join(lines) + "\n"


def _table(values: np.ndarray, num: Any, per_line: int = 6) -> str:
    flat = [num(float(v)) for v in values]
    return "\n    " + ",\n    ".join(", ".join(flat[i:i + per_line]) for i in range(0, len(flat), per_line)) + "\n"


def fdi_tables(settings: FdiSettings, nmax: int) -> np.ndarray:
    """Detection thresholds by dof (0..nmax-3; the set test's are :meth:`FdiSettings.set_thresholds`)."""
    r = max(nmax - 3, 0)
    return np.array([0.0] + [float(chdtri(d, settings.p_fa)) for d in range(1, r + 1)])
