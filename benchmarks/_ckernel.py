"""C references of the runtime kernels for the runtime benchmarks (not a benchmark itself: ``dev.py bench`` skips
``_`` files).

* :func:`build_fixed`: the block path as a C programmer writes it for one unit: the sizes of each instrument fixed
  at compile time (``#define``), ``restrict`` pointers, ``O = Y R^T - off`` with the range and finiteness test once
  per block (a running maximum of ``|y|`` per sensor and a running sum of each output, tested at the end), built
  with ``-O3 -march=native``: gcc unrolls and vectorises it. The reference of ``Pipeline.process``.
* :func:`build_exported`: rimu's own exported C (:func:`rimu.export.export_c`) of the same calibration, ``rimu_step``
  per epoch over the block, its estimates copied out; it computes more per sample (the weighted least-squares
  solve, covariance, chi-square and isolation statistics), so it is a second, weaker reference.
* :func:`build` (``epoch_block``): the compensation of every effect (``runtime_effects.py``).

The effects' C functions do the arithmetic of ``rimu/fusion/_kernels.py`` operation by operation, in the same order, on the
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
        lib.epoch_block_repeat.restype = ctypes.c_int64

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


FIXED_INSTRUMENT = r"""
#define N_IN @N@
#define M_OUT @M@
static int inst@S@(int64_t N, const double *restrict Y, const double *restrict R, const double *restrict off,
                   const double *restrict lim, double *restrict out) {
    double s[M_OUT] = {0}, a[N_IN] = {0};
    for (int64_t k = 0; k < N; k++) {
        const double *y = Y + k * N_IN;
        double *o = out + k * M_OUT;
        for (int i = 0; i < N_IN; i++) { double v = fabs(y[i]); a[i] = a[i] > v ? a[i] : v; }
        for (int j = 0; j < M_OUT; j++) {
            double acc = -off[j];
            for (int i = 0; i < N_IN; i++) acc += R[j * N_IN + i] * y[i];
            o[j] = acc;
            s[j] += acc;
        }
    }
    int ok = 1;
    double t = 0.0;
    for (int i = 0; i < N_IN; i++) ok &= a[i] < lim[i];
    for (int j = 0; j < M_OUT; j++) t += s[j];
    return ok && t - t == 0.0;
}
#undef N_IN
#undef M_OUT
"""


class FixedKernel:
    """The fixed-size C block kernel of a unit (:func:`build_fixed`)."""

    def __init__(self, lib: ctypes.CDLL, compiler: str, k: int) -> None:
        self.lib, self.compiler, self.k = lib, compiler, k
        self.clock = time.perf_counter  # the clock of the timing (time.thread_time: CPU time of the thread)
        lib.unit_block_repeat.restype = ctypes.c_int

    def block(self, Ys: list[np.ndarray], Rs: list[np.ndarray], offs: list[np.ndarray], lims: list[np.ndarray],
              outs: list[np.ndarray], reps: int) -> tuple[float, bool]:
        """Run the unit's block ``reps`` times; (seconds per run, whether every block was clean)."""
        args = [_I(reps), _I(len(Ys[0]))]
        for Y, R, off, lim, out in zip(Ys, Rs, offs, lims, outs):
            args += [_p(Y), _p(R), _p(off), _p(lim), _p(out)]
        t0 = self.clock()
        ok = self.lib.unit_block_repeat(*args)
        return (self.clock() - t0) / reps, bool(ok)


def _compile(src: str, extra: list[str] | None = None, cwd: Path | None = None) -> tuple[ctypes.CDLL, str] | None:
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        return None
    d = cwd or Path(tempfile.mkdtemp(prefix="rimu_cref_"))
    (d / "k.c").write_text(src)
    subprocess.run([cc, *FLAGS, "-I", str(d), "k.c", *(extra or []), "-o", "k.so", "-lm"], cwd=d, check=True)
    return ctypes.CDLL(str(d / "k.so")), f"{Path(cc).name} {' '.join(FLAGS[:2])}"


def build_fixed(sizes: list[tuple[int, int]]) -> FixedKernel | None:
    """The fixed-size kernel of a unit whose instruments have ``(n inputs, m outputs)``; None without a compiler."""
    src = "#include <math.h>\n#include <stdint.h>\n"
    for s, (n, m) in enumerate(sizes):
        src += FIXED_INSTRUMENT.replace("@N@", str(n)).replace("@M@", str(m)).replace("@S@", str(s))
    params = ", ".join(f"const double *Y{s}, const double *R{s}, const double *f{s}, const double *l{s}, double *O{s}"
                       for s in range(len(sizes)))
    calls = " & ".join(f"inst{s}(N, Y{s}, R{s}, f{s}, l{s}, O{s})" for s in range(len(sizes)))
    src += (f"int unit_block_repeat(int64_t reps, int64_t N, {params}) {{\n    int ok = 1;\n"
            f"    for (int64_t r = 0; r < reps; r++) ok &= {calls};\n    return ok;\n}}\n")
    built = _compile(src)
    return None if built is None else FixedKernel(built[0], built[1], len(sizes))


EXPORTED_DRIVER = r"""
#include <string.h>
#include <stdint.h>
#include "rimu_unit.h"
/* every epoch of the block through rimu_step, the estimates copied into Og, Oa (N, 3) */
int export_block_repeat(int64_t reps, int64_t N, const double *Yg, const double *Ya, double *Og, double *Oa) {
    rimu_state sg, sa;
    rimu_output og, oa;
    int obs = 1;
    memset(&sg, 0, sizeof sg);
    memset(&sa, 0, sizeof sa);
    for (int64_t r = 0; r < reps; r++)
        for (int64_t k = 0; k < N; k++) {
            rimu_step(0.0, 25.0, &sg, Yg + k * RIMU_GYRO_N, 0, &og, &sa, Ya + k * RIMU_ACCEL_N, 0, &oa);
            memcpy(Og + 3 * k, og.x, sizeof og.x);
            memcpy(Oa + 3 * k, oa.x, sizeof oa.x);
            obs &= og.observable & oa.observable;
        }
    return obs;
}
"""


class ExportedKernel:
    """rimu's exported C of a gyro + accelerometer unit, ``rimu_step`` per epoch (:func:`build_exported`)."""

    def __init__(self, lib: ctypes.CDLL, compiler: str) -> None:
        self.lib, self.compiler = lib, compiler
        self.clock = time.perf_counter
        lib.export_block_repeat.restype = ctypes.c_int

    def block(self, Yg: np.ndarray, Ya: np.ndarray, Og: np.ndarray, Oa: np.ndarray, reps: int) -> tuple[float, bool]:
        t0 = self.clock()
        ok = self.lib.export_block_repeat(_I(reps), _I(len(Yg)), _p(Yg), _p(Ya), _p(Og), _p(Oa))
        return (self.clock() - t0) / reps, bool(ok)


def build_exported(calibration: object) -> ExportedKernel | None:
    """Export ``calibration`` (gyro + accel, with noise_sigma) with :func:`rimu.export.export_c` and build it with
    the driver above (``-O3 -march=native``); None without a compiler."""
    from rimu.export import export_c

    if not (shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")):
        return None
    d = Path(tempfile.mkdtemp(prefix="rimu_export_"))
    export_c(calibration, d)  # type: ignore[arg-type]
    built = _compile(EXPORTED_DRIVER, ["rimu_unit.c"], d)
    return None if built is None else ExportedKernel(built[0], built[1])
