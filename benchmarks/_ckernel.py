"""C references of the runtime kernels for the runtime benchmarks (not a benchmark itself: ``dev.py bench`` skips
``_`` files).

The C functions do the arithmetic of ``rimu/fusion/_kernels.py`` operation by operation, in the same order, on the
same arrays (the compiled program's F, L, W: the same effects, Newton steps and fixed-point rounds), so that a
ratio to them measures the implementation, not a different computation. The C code keeps the plain shape of one
static function per step (gcc inlines the small ones); the numba code differs only in how it is arranged for numba (its
epoch is one loop over the fixed-point rounds and the instruments, so that the inlined Newton solve appears once). They are
built at run time with the system compiler, ``-O3 -march=native`` (no fast-math: IEEE arithmetic, as numba's);
``build()`` returns None where no compiler is found (the benchmark then reports no C reference).
"""

from __future__ import annotations

import ctypes
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

FLAGS = ["-O3", "-march=native", "-std=c99", "-shared", "-fPIC"]

SOURCE = r"""
#include <math.h>
#include <stdint.h>
typedef int64_t i64;

/* rimu.fusion._kernels.project_block */
static int project_block(i64 N, i64 n, i64 m, const double *Y, const double *R, const double *off,
                         const double *rng, double *out) {
    for (i64 k = 0; k < N; k++) {
        const double *y = Y + k * n;
        for (i64 i = 0; i < n; i++)
            if (!(fabs(y[i]) < rng[i])) return 0;
        double s = 0.0;
        for (i64 j = 0; j < m; j++) {
            double acc = 0.0;
            for (i64 i = 0; i < n; i++) acc += R[j * n + i] * y[i];
            acc -= off[j];
            out[k * m + j] = acc;
            s += acc;
        }
        if (!(s - s == 0.0)) return 0;
    }
    return 1;
}

int project_block_repeat(i64 reps, i64 N, i64 n, i64 m, const double *Y, const double *R, const double *off,
                         const double *rng, double *out) {
    int ok = 1;
    for (i64 r = 0; r < reps; r++) ok &= project_block(N, n, m, Y, R, off, rng, out);
    return ok;
}

/* rimu.fusion._kernels: the compensation of every effect, on the program's F, L, W */
enum {M = 22, W_F = M, W_W = M + 3, W_U = M + 6};
enum {H_NSLOT, H_CYCLIC, H_ROUNDS, H_ACC, H_GYR, H_WORK, H_SIZE = 8};
enum {S_N, S_M, S_MODE, S_KIND, S_OUT, S_NEEDU, S_STEPS, S_SCALE, S_BIAS, S_RANGE, S_C, S_HX, S_H, S_G, S_R, S_OFF,
      S_OBS, S_PRESENT, S_DYN, S_RAWEXO, S_COLS, S_WY, S_WRAW, S_WOUT, S_SIZE};
enum {MODE_NONE, MODE_RAWEXO, MODE_FULL};

static void monomials(double t, double dT, int have_f, int have_w, double *W) {
    W[0] = 1.0; W[1] = t; W[2] = dT; W[3] = dT * dT;
    for (int b = 0; b < 2; b++) {
        int j = 4 + 9 * b, v = b == 0 ? W_F : W_W;
        if (b == 0 ? have_f : have_w) {
            double x = W[v], y = W[v + 1], z = W[v + 2];
            W[j] = x; W[j + 1] = y; W[j + 2] = z;
            W[j + 3] = x * x; W[j + 4] = x * y; W[j + 5] = x * z;
            W[j + 6] = y * y; W[j + 7] = y * z; W[j + 8] = z * z;
        } else {
            for (int a = 0; a < 9; a++) W[j + a] = 0.0;
        }
    }
}

static void coefs(const double *F, const i64 *L, i64 base, double *W, i64 k0) {
    i64 n = L[base + S_N], present = L[base + S_PRESENT], dyn = L[base + S_DYN], cols = L[base + S_COLS];
    i64 c_base = L[base + S_C];
    for (int blk = 0; blk < 5; blk++) {
        i64 nc = L[cols++];
        if ((present >> blk) & 1) {
            i64 c0 = c_base + blk * M * n, o = k0 + blk * n;
            for (i64 i = 0; i < n; i++) W[o + i] = F[c0 + i];
            if ((dyn >> blk) & 1)
                for (i64 a = 0; a < nc; a++) {
                    i64 j = L[cols + a];
                    double mj = W[j];
                    i64 cj = c0 + j * n;
                    for (i64 i = 0; i < n; i++) W[o + i] += F[cj + i] * mj;
                }
        }
        cols += nc;
    }
}

static int estimate(const double *F, const i64 *L, i64 base, double *W, i64 q0, i64 u0) {
    i64 n = L[base + S_N], g0 = L[base + S_G];
    double s = 0.0;
    for (i64 i = 0; i < n; i++) s += W[q0 + i];
    if (!(s - s == 0.0)) return 0;
    for (int j = 0; j < 3; j++) {
        double acc = 0.0;
        for (i64 i = 0; i < n; i++) acc += F[g0 + j * n + i] * W[q0 + i];
        W[u0 + j] = acc;
    }
    return 1;
}

static int solve(const double *F, const i64 *L, i64 base, double *W) {
    i64 n = L[base + S_N], sc = L[base + S_SCALE], bi = L[base + S_BIAS], y0 = L[base + S_WY];
    i64 q0 = L[H_WORK], z0 = q0 + n, n0 = z0 + n, k0 = n0 + n, present = L[base + S_PRESENT];
    coefs(F, L, base, W, k0);
    for (i64 i = 0; i < n; i++) {
        double z = W[y0 + i] * F[sc + i] - F[bi + i];
        if (present & 1) z = z - W[k0 + i];
        W[z0 + i] = z;
        W[q0 + i] = z;
    }
    if (!L[base + S_OUT]) return 1;
    i64 needs_u = L[base + S_NEEDU], hx = L[base + S_HX], h0 = L[base + S_H];
    int has1 = (present >> 1) & 1, has2 = (present >> 2) & 1, has3 = (present >> 3) & 1, hasa = (present >> 4) & 1;
    for (i64 st = 0; st < L[base + S_STEPS]; st++) {
        if (needs_u && !estimate(F, L, base, W, q0, W_U)) return 0;
        for (i64 i = 0; i < n; i++) {
            double s = W[q0 + i], lin = has1 ? W[k0 + 1 * n + i] : 0.0, quad, slope2;
            if (has3) {
                double a = W[k0 + 3 * n + i] * s;
                if (has2) { double k2 = W[k0 + 2 * n + i]; quad = a + k2; slope2 = 2.0 * k2 + 3.0 * a; }
                else { quad = a; slope2 = 3.0 * a; }
            } else if (has2) {
                double k2 = W[k0 + 2 * n + i]; quad = k2; slope2 = 2.0 * k2;
            } else { quad = 0.0; slope2 = 0.0; }
            double c = (lin + quad * s) * s, dc = lin + slope2 * s;
            if (hasa) {
                double ka = W[k0 + 4 * n + i];
                c = c + ka * fabs(s);
                dc = dc + ka * (s > 0.0 ? 1.0 : (s < 0.0 ? -1.0 : 0.0 * s));
            }
            if (needs_u) {
                double hu = F[h0 + 3 * i] * W[W_U] + F[h0 + 3 * i + 1] * W[W_U + 1] + F[h0 + 3 * i + 2] * W[W_U + 2];
                double xu = F[hx + 3 * i] * W[W_U] + F[hx + 3 * i + 1] * W[W_U + 1] + F[hx + 3 * i + 2] * W[W_U + 2];
                c = c + hu * xu;
            }
            W[n0 + i] = s - (s + c - W[z0 + i]) / (1.0 + dc);
        }
        for (i64 i = 0; i < n; i++) W[q0 + i] = W[n0 + i];
    }
    return 1;
}

static int raw_out(const double *F, const i64 *L, i64 base, double *W) {
    i64 n = L[base + S_N], mode = L[base + S_MODE], y0 = L[base + S_WY], r0 = L[base + S_WRAW];
    if (mode == MODE_NONE) { for (i64 i = 0; i < n; i++) W[r0 + i] = W[y0 + i]; return 1; }
    if (mode == MODE_RAWEXO) {
        i64 e0 = L[base + S_RAWEXO], cols = L[base + S_COLS];
        for (i64 i = 0; i < n; i++) W[r0 + i] = F[e0 + i];
        for (i64 a = 0; a < L[cols]; a++) {
            i64 j = L[cols + 1 + a], ej = e0 + j * n;
            double mj = W[j];
            for (i64 i = 0; i < n; i++) W[r0 + i] += F[ej + i] * mj;
        }
        for (i64 i = 0; i < n; i++) W[r0 + i] = W[y0 + i] - W[r0 + i];
        return 1;
    }
    if (!solve(F, L, base, W)) return 0;
    i64 sc = L[base + S_SCALE], bi = L[base + S_BIAS], q0 = L[H_WORK];
    for (i64 i = 0; i < n; i++) W[r0 + i] = (W[q0 + i] + F[bi + i]) / F[sc + i];
    return 1;
}

static int project(const double *F, const i64 *L, i64 base, double *W) {
    i64 n = L[base + S_N], m = L[base + S_M];
    if (!L[base + S_OBS]) return 0;
    i64 rg = L[base + S_RANGE], x0 = L[base + S_WRAW], r0 = L[base + S_R], o0 = L[base + S_OFF], w0 = L[base + S_WOUT];
    for (i64 i = 0; i < n; i++) if (!(fabs(W[x0 + i]) < F[rg + i])) return 0;
    double s = 0.0;
    for (i64 j = 0; j < m; j++) {
        double acc = 0.0;
        for (i64 i = 0; i < n; i++) acc += F[r0 + j * n + i] * W[x0 + i];
        acc -= F[o0 + j];
        W[w0 + j] = acc;
        s += acc;
    }
    return s - s == 0.0;
}

static int epoch(const double *F, const i64 *L, double *W, double t, double dT) {
    if (!(t - t == 0.0 && dT - dT == 0.0)) return 0;
    int have_f = 0, have_w = 0;
    if (L[H_CYCLIC]) {
        i64 ba = H_SIZE + S_SIZE * L[H_ACC], bg = H_SIZE + S_SIZE * L[H_GYR], q0 = L[H_WORK];
        for (int a = 0; a < 3; a++) W[W_W + a] = 0.0;
        for (i64 r = 0; r < L[H_ROUNDS]; r++) {
            monomials(t, dT, 0, 1, W);
            if (!solve(F, L, ba, W) || !estimate(F, L, ba, W, q0, W_F)) return 0;
            monomials(t, dT, 1, 0, W);
            if (!solve(F, L, bg, W) || !estimate(F, L, bg, W, q0, W_W)) return 0;
        }
        have_w = 1;
    }
    for (i64 s = 0; s < L[H_NSLOT]; s++) {
        i64 base = H_SIZE + S_SIZE * s;
        if (L[base + S_MODE] != MODE_NONE) monomials(t, dT, have_f, have_w, W);
        if (!raw_out(F, L, base, W) || !project(F, L, base, W)) return 0;
        i64 w0 = L[base + S_WOUT], v = L[base + S_KIND] == 0 ? W_F : W_W;
        W[v] = W[w0]; W[v + 1] = W[w0 + 1]; W[v + 2] = W[w0 + 2];
        if (L[base + S_KIND] == 0) have_f = 1; else have_w = 1;
    }
    return 1;
}

/* rimu.fusion._kernels.epoch_block without the compensated raw outputs (as Pipeline.process) */
i64 epoch_block_repeat(i64 reps, const double *F, const i64 *L, double *W, i64 N, const double *Y0,
                       const double *Y1, const double *t, const double *dT, double *O0, double *O1) {
    i64 bad = -1;
    for (i64 r = 0; r < reps; r++)
        for (i64 k = 0; k < N; k++) {
            for (i64 s = 0; s < L[H_NSLOT]; s++) {
                i64 base = H_SIZE + S_SIZE * s, a = L[base + S_WY], n = L[base + S_N];
                const double *Y = s == 0 ? Y0 : Y1;
                for (i64 i = 0; i < n; i++) W[a + i] = Y[k * n + i];
            }
            if (!epoch(F, L, W, t[k], dT[k])) { bad = k; break; }
            for (i64 s = 0; s < L[H_NSLOT]; s++) {
                i64 base = H_SIZE + S_SIZE * s, w0 = L[base + S_WOUT], m = L[base + S_M];
                double *O = s == 0 ? O0 : O1;
                for (i64 j = 0; j < m; j++) O[k * m + j] = W[w0 + j];
            }
        }
    return bad;
}
"""

_P = ctypes.POINTER(ctypes.c_double)
_PL = ctypes.POINTER(ctypes.c_int64)
_I = ctypes.c_int64


def _p(a: np.ndarray) -> ctypes.c_void_p:
    return a.ctypes.data_as(_PL if a.dtype == np.int64 else _P)


class CKernels:
    """The built library; each method runs its kernel ``reps`` times and returns the seconds per run."""

    def __init__(self, lib: ctypes.CDLL, compiler: str) -> None:
        self.lib = lib
        self.compiler = compiler
        lib.project_block_repeat.restype = ctypes.c_int
        lib.epoch_block_repeat.restype = ctypes.c_int64

    def project_block(self, Y: np.ndarray, R: np.ndarray, off: np.ndarray, rng: np.ndarray, out: np.ndarray,
                      reps: int) -> tuple[float, bool]:
        N, n = Y.shape
        m = R.shape[0]
        args = [_I(N), _I(n), _I(m), _p(Y), _p(np.ascontiguousarray(R)), _p(np.ascontiguousarray(off)), _p(rng),
                _p(out)]
        t0 = time.perf_counter()
        ok = self.lib.project_block_repeat(_I(reps), *args)
        return (time.perf_counter() - t0) / reps, bool(ok)

    def epoch_block(self, F: np.ndarray, L: np.ndarray, W: np.ndarray, Y0: np.ndarray, Y1: np.ndarray,
                    t: np.ndarray, dT: np.ndarray, O0: np.ndarray, O1: np.ndarray, reps: int) -> tuple[float, int]:
        t0 = time.perf_counter()
        bad = self.lib.epoch_block_repeat(_I(reps), _p(F), _p(L), _p(W), _I(len(Y0)), _p(Y0), _p(Y1), _p(t), _p(dT),
                                          _p(O0), _p(O1))
        return (time.perf_counter() - t0) / reps, int(bad)


def build() -> CKernels | None:
    """Compile :data:`SOURCE` with the system compiler (``cc``, else gcc or clang); None without one."""
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        return None
    d = Path(tempfile.mkdtemp(prefix="rimu_cref_"))
    (d / "k.c").write_text(SOURCE)
    subprocess.run([cc, *FLAGS, "k.c", "-o", "k.so", "-lm"], cwd=d, check=True)
    return CKernels(ctypes.CDLL(str(d / "k.so")), f"{Path(cc).name} {' '.join(FLAGS[:2])}")
