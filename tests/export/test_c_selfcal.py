"""The generated C of the self-calibration tracker's Kalman filter (rimu.export.c_selfcal) against
rimu.fdi.selfcal.SelfCalTracker, window by window: cone6 with bias, scale and three temperature orders tracked
(30 states) and three parallel triads with the bias only; biases drifting, a temperature ramp, flight-like motion, a
window with a sensor inactive, windows with a frozen sensor (Schmidt, Joseph form) and a step the gate rejects.
The state, its covariance, the innovation's chi-square, the gate decision, the correction, its covariance and
the tracked terms with their sigmas agree to 1e-12 (relative to each quantity's scale). Skips without a C
compiler.
"""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from rimu.calibration import InstrumentCalibration
from rimu.export.c_selfcal import selfcal_c
from rimu.fdi import RedundancyManager
from rimu.fdi.health import SensorState
from rimu.fdi.selfcal import SelfCalLoop, SelfCalSettings, SelfCalTracker, TrackedGltWindow
from rimu.fusion import InstrumentPipeline
from rimu.geometry import cone6, triads

CC = shutil.which("cc") or shutil.which("gcc")
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2"]

_MAIN = r"""
#include <stdio.h>
#include <stdlib.h>
#include "rimu_sc.h"

static rimu_sc s;
static double z[4000 * RIMU_SC_N], g[4000 * RIMU_SC_S];

static void dump(const double *v, int k)
{
    int i;
    for (i = 0; i < k; ++i) {
        printf("%.17g ", v[i]);
    }
}

int main(void)
{
    char cmd;
    double t, vals[RIMU_SC_S], sig[RIMU_SC_S], c[RIMU_SC_N], C[RIMU_SC_N * RIMU_SC_N], gg[RIMU_SC_S];
    rimu_sc_init(&s, 0.0);
    while (scanf(" %c", &cmd) == 1) {
        if (cmd == 'P') {
            if (scanf("%lf", &t) != 1) return 1;
            printf("%d\n", rimu_sc_predict(&s, t));
        } else if (cmd == 'U') {
            long M, k;
            int i, a;
            unsigned char act[RIMU_SC_N], fr[RIMU_SC_N];
            rimu_sc_update_info info;
            if (scanf("%ld", &M) != 1) return 1;
            for (i = 0; i < RIMU_SC_N; ++i) { if (scanf("%d", &a) != 1) return 1; act[i] = (unsigned char)a; }
            for (i = 0; i < RIMU_SC_N; ++i) { if (scanf("%d", &a) != 1) return 1; fr[i] = (unsigned char)a; }
            for (k = 0; k < M * RIMU_SC_N; ++k) { if (scanf("%lf", &z[k]) != 1) return 1; }
            for (k = 0; k < M * RIMU_SC_S; ++k) { if (scanf("%lf", &g[k]) != 1) return 1; }
            rimu_sc_update(&s, z, g, M, act, fr, &info);
            printf("%d %.17g %.17g %d\n", info.accepted, info.d2, info.gate, info.dof);
        } else if (cmd == 'R') {
            double u[3], T;
            if (scanf("%lf %lf %lf %lf", &u[0], &u[1], &u[2], &T) != 4) return 1;
            rimu_sc_regressors(u, T, gg);
            dump(gg, RIMU_SC_S);
            rimu_sc_correction(&s, gg, c);
            dump(c, RIMU_SC_N);
            rimu_sc_correction_covariance(&s, gg, C);
            dump(C, RIMU_SC_N * RIMU_SC_N);
            rimu_sc_terms(&s, vals, sig);
            dump(vals, RIMU_SC_S);
            dump(sig, RIMU_SC_S);
            dump(s.theta, RIMU_SC_S);
            dump(s.P, RIMU_SC_S * RIMU_SC_S);
            printf("%ld %ld\n", s.updates, s.rejected);
        } else {
            return 2;
        }
    }
    return 0;
}
"""


def _build(trk: SelfCalTracker, d) -> str:
    h, c = selfcal_c(trk, "rimu_sc")
    (d / "rimu_sc.h").write_text(h)
    (d / "rimu_sc.c").write_text(c)
    (d / "main.c").write_text(_MAIN)
    res = subprocess.run([CC, *CFLAGS, "-o", str(d / "sc"), str(d / "main.c"), str(d / "rimu_sc.c"), "-lm"],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr  # -Wall -Wextra -Werror -pedantic clean
    return str(d / "sc")


def _f(v) -> str:
    return " ".join(repr(float(x)) for x in np.ravel(v))


def _script(trk: SelfCalTracker, seed: int, n_win: int = 40, M: int = 25):
    """Windows of a drifting unit (the tracker's own model, plus noise): (commands, Python's answers)."""
    rng = np.random.default_rng(seed)
    n, m = trk.n, trk.m
    A = trk.axes
    theta = rng.standard_normal(n * m) * np.sqrt(trk.p0)   # the truth: drawn from the tracker's own model
    st = trk.initial_state(0.0)
    cmds, ref = [], []
    t, dt = 0.0, M * 0.01
    for w in range(n_win):
        t += dt
        theta = theta + rng.standard_normal(n * m) * np.sqrt(trk.q * dt)
        tt = t - dt + 0.01 * np.arange(M)
        u = np.column_stack([np.sin(3 * tt + i) for i in range(3)]) * 2.0
        T = 10.0 + 30.0 * tt / (n_win * dt)                              # a 30 K ramp
        g = trk.regressors(M, u, T)
        z = u @ A.T + np.einsum("kbn,bn->kn", g, theta.reshape(m, n))
        z += rng.standard_normal((M, n)) * trk.sigma
        act = np.ones(n, bool)
        fr = np.zeros(n, bool)
        if w in (12, 13):
            act[1] = False
        if 20 <= w < 26:
            fr[n - 2] = True
        if w == 30:
            z[:, 0] += 50 * trk.sigma[0]                     # a step: the gate refuses it
        st = trk.predict(st, t)
        cmds.append(f"P {float(t)!r}")
        ref.append(("predict",))
        st, info = trk.update(st, z, g, act, fr)
        cmds.append(f"U {M} {' '.join(str(int(a)) for a in act)} {' '.join(str(int(f)) for f in fr)} {_f(z)} {_f(g)}")
        ref.append(("update", info))
        ui, Ti = u[-1], T[-1]
        gi = trk.regressors(1, ui[None], np.array([Ti]))[0]
        cmds.append(f"R {_f(ui)} {float(Ti)!r}")
        terms = trk.terms(st)
        ref.append(("state", gi, trk.correction(st, gi[None])[0], trk.correction_covariance(st, gi),
                    np.concatenate([terms[b][0] for b in trk.blocks]),
                    np.concatenate([terms[b][1] for b in trk.blocks]), st.theta, st.P, st.updates, st.rejected))
    return cmds, ref


def _close(c: np.ndarray, p: np.ndarray, what: str, rel: float = 1e-12) -> float:
    p = np.asarray(p, dtype=float).ravel()
    scale = max(float(np.abs(p).max()), 1e-300)
    err = float(np.abs(c - p).max()) / scale
    assert err <= rel, f"{what}: C and Python differ by {err:.3g} of the largest value"
    return err


def _compare(trk: SelfCalTracker, exe: str, seed: int) -> dict:
    cmds, ref = _script(trk, seed)
    out = subprocess.run([exe], input="\n".join(cmds) + "\n", capture_output=True, text=True, check=True)
    lines = out.stdout.strip().splitlines()
    assert len(lines) == len(ref)
    n, S = trk.n, trk.n * trk.m
    worst = {"accepted": 0, "rejected": 0, "frozen_windows": 0, "err": 0.0}
    for line, r in zip(lines, ref, strict=True):
        v = line.split()
        if r[0] == "predict":
            assert v == ["0"]
        elif r[0] == "update":
            info = r[1]
            assert int(v[0]) == int(info.accepted) and int(v[3]) == info.dof
            if info.dof >= 1:
                worst["err"] = max(worst["err"], _close(np.array([float(v[1])]), [info.d2], "d2"))
                assert float(v[2]) == pytest.approx(info.gate, rel=1e-14)
            worst["accepted" if info.accepted else "rejected"] += 1
        else:
            x = np.array([float(s) for s in v[:-2]])
            parts = np.split(x, np.cumsum([S, n, n * n, S, S, S]))
            names = ("regressors", "correction", "correction covariance", "terms", "sigmas", "theta", "P")
            for name, c, p in zip(names, parts, r[1:8], strict=True):
                if name in ("terms", "sigmas"):  # per block: each block's own scale (SI/K^3 is tiny beside SI)
                    for b in range(trk.m):
                        worst["err"] = max(worst["err"], _close(c[b * n:(b + 1) * n], p[b * n:(b + 1) * n],
                                                                f"{name}[{trk.blocks[b]}]"))
                else:
                    worst["err"] = max(worst["err"], _close(c, p, name))
            assert (int(v[-2]), int(v[-1])) == (r[8], r[9])
    return worst


@needs_cc
def test_tracker_c_matches_python_cone6_full_model(tmp_path):
    cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=np.linspace(0.01, 0.015, 6))
    st = SelfCalSettings(bias_rw=1e-6, bias_sigma0=0.005, scale_rw=1e-8, scale_sigma0=1e-3,
                         temperature_sigma=[1e-4, 1e-5, 1e-6], reference_temperature=25.0)
    trk = SelfCalTracker(cal, st)
    w = _compare(trk, _build(trk, tmp_path), seed=1)
    assert w["accepted"] >= 35 and w["rejected"] >= 1   # the step was gated out, the rest absorbed
    assert w["err"] <= 1e-12


@needs_cc
def test_tracker_c_matches_python_triads_bias_only(tmp_path):
    cal = InstrumentCalibration.nominal("accel", triads(3), 1.0, noise_sigma=0.02)
    trk = SelfCalTracker(cal, SelfCalSettings(bias_rw=1e-5, bias_sigma0=0.01, gate_p=1e-3))
    w = _compare(trk, _build(trk, tmp_path), seed=2)
    assert w["accepted"] >= 35 and w["rejected"] >= 1


_LOOP_MAIN = r"""
#include <stdio.h>
#include <string.h>
#include "rimu_sc.h"

static rimu_sc_loop L;
static rimu_sc ahead;
static rimu_sc_glt G;

static void dump(const double *v, int k)
{
    int i;
    for (i = 0; i < k; ++i) {
        printf("%.17g ", v[i]);
    }
}

int main(void)
{
    double t, T, y[RIMU_SC_N], out[RIMU_SC_N], C[RIMU_SC_N * RIMU_SC_N], stat, vals[RIMU_SC_S], sig[RIMU_SC_S];
    int i, a, alarm, dof, cfg;
    unsigned char valid[RIMU_SC_N], iso[RIMU_SC_N], act[RIMU_SC_N];
    rimu_sc_loop_reset(&L);
    while (scanf("%lf %lf", &t, &T) == 2) {
        for (i = 0; i < RIMU_SC_N; ++i) { if (scanf("%lf", &y[i]) != 1) return 1; }
        for (i = 0; i < RIMU_SC_N; ++i) { if (scanf("%d", &a) != 1) return 1; valid[i] = (unsigned char)a; }
        if (scanf("%d %lf %d", &alarm, &stat, &dof) != 3) return 1;
        for (i = 0; i < RIMU_SC_N; ++i) { if (scanf("%d", &a) != 1) return 1; iso[i] = (unsigned char)a; }
        if (scanf("%d", &cfg) != 1) return 1;
        for (i = 0; i < RIMU_SC_N; ++i) { if (scanf("%d", &a) != 1) return 1; act[i] = (unsigned char)a; }
        if (rimu_sc_loop_correct(&L, y, valid, t, &T, out, C) != 0) {
            printf("C ");
            dump(C, RIMU_SC_N * RIMU_SC_N);
            printf("\n");
            rimu_sc_glt_set_covariance(&G, C);
        }
        if (cfg != 0) {
            rimu_sc_glt_configure(&G, act);
        }
        {
            double zz[RIMU_SC_N], thr, st;
            for (i = 0; i < RIMU_SC_N; ++i) {
                zz[i] = (act[i] != 0u) ? out[i] : 0.0;  /* nominal calibration: SF = 1, B = 0 */
            }
            st = rimu_sc_glt_update(&G, zz, &thr);
            printf("S %.17g %.17g\n", st, thr);
        }
        printf("Y ");
        dump(out, RIMU_SC_N);
        printf("\n");
        rimu_sc_loop_observe(&L, alarm, stat, dof, iso);
        if (L.k == 0L) {
            memcpy(&ahead, &L.s, sizeof ahead);
            if (t > ahead.t) {
                (void)rimu_sc_predict(&ahead, t);
            }
            rimu_sc_terms(&ahead, vals, sig);
            printf("W ");
            dump(vals, RIMU_SC_S);
            dump(sig, RIMU_SC_S);
            dump(L.s.theta, RIMU_SC_S);
            printf("%ld %ld %ld ", L.accepted, L.rejected, L.discarded);
            for (i = 0; i < RIMU_SC_NG; ++i) { printf("%d %.17g %.17g ", L.applied[i], L.gain_total[i], L.var_total[i]); }
            printf("\n");
        }
    }
    return 0;
}
"""


class _Spy(TrackedGltWindow):
    """The runtime's detector, remembering the tracker covariances it is given."""

    def __init__(self, *a, **k) -> None:
        super().__init__(*a, **k)
        self.given: list[np.ndarray] = []

    def set_tracker_covariance(self, sigma_c):
        self.given.append(np.array(sigma_c, dtype=float))
        super().set_tracker_covariance(sigma_c)

    def configure(self, Vz, dof):
        self.configured = np.abs(np.asarray(Vz)[:max(dof, 0)]).sum(axis=0) > 0
        super().configure(Vz, dof)

    def update(self, parity):
        self.last = super().update(parity)
        return self.last


@needs_cc
def test_loop_c_matches_selfcalloop_with_a_step_fault(tmp_path):
    """SelfCalLoop around a real manager (window GLT with the tracker's covariance) on a cone6 flight: drifting
    biases, a 30 K ramp with first- to third-order coefficients, a step on sensor 3 at 40 s (alarm, windows thrown
    away, isolation, the sensor frozen). The C loop is fed the manager's decisions and must give the same corrected
    outputs, the same covariance to the detector at every window's start, the same held/absorbed/discarded windows
    and the same tracked terms, sigmas and state after every window (1e-12)."""
    fs, N, n = 100.0, 6000, 6
    sig = np.full(n, 0.01)
    cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=sig)
    st = SelfCalSettings(bias_rw=4e-7, bias_sigma0=0.004, scale_rw=1e-9, scale_sigma0=5e-4,
                         temperature_sigma=[1e-4, 5e-6, 2e-7], window_s=0.5, hold_s=2.0,
                         guard_s=10.0)       # the held-out check, with a memory short enough to switch groups
    trk = SelfCalTracker(cal, st)
    M = int(round(st.window_s * fs))
    det = _Spy(M, 1e-4)
    mgr = RedundancyManager(InstrumentPipeline(cal), det, p_fa=1e-4, sample_rate=fs)
    loop = SelfCalLoop(trk, fs, det, history=True)
    rng = np.random.default_rng(5)
    t = np.arange(N) / fs
    T = 10.0 + 30.0 * t / t[-1]
    u = np.column_stack([0.5 * np.sin(0.7 * t + i) for i in range(3)])
    drift = np.cumsum(rng.standard_normal((N, n)) * np.sqrt(3 * 4e-7 / fs), axis=0) + rng.normal(0, 0.004, n)
    coef = np.array([rng.normal(0, s, n) for s in st.temperature_sigma])
    Y = u @ cal.axes_mb().T + drift + sum(((T - 25.0) ** (k + 1))[:, None] * coef[k] for k in range(3))
    Y += rng.standard_normal((N, n)) * sig
    Y[t >= 40.0, 2] += 0.08                                           # the step fault, 8 sigma
    valid = np.ones((N, n), bool)
    valid[1000:1003, 4] = False                                       # a glitch: invalid for 3 samples
    lines, ref_y, ref_c, ref_w, ref_s = [], [], [], [], []
    det.configured = None
    act = np.zeros(n, bool)
    for k in range(N):
        given = len(det.given)
        yk = loop.correct(Y[k], valid[k], float(t[k]), float(T[k]))
        if len(det.given) > given:
            ref_c.append(det.given[-1])
        det.last = None
        r = mgr.step(yk, valid[k], float(t[k]))
        cfg, det.configured = det.configured, None
        if cfg is not None:
            act = cfg
        ref_s.append(det.last)
        iso = mgr.sensors.state >= SensorState.ISOLATED
        h0 = len(loop.history)
        loop.observe(r, iso)
        ref_y.append(yk)
        if len(loop.history) > h0:
            ref_w.append(loop.history[-1] + (loop._applied.copy(), loop._gain_total.copy(), loop._var_total.copy()))
        lines.append(f"{float(t[k])!r} {float(T[k])!r} {_f(Y[k])} {' '.join(str(int(v)) for v in valid[k])} "
                     f"{int(r.alarm)} {float(r.statistic)!r} {int(r.dof)} {' '.join(str(int(v)) for v in iso)} "
                     f"{int(cfg is not None)} {' '.join(str(int(v)) for v in act)}")
    assert np.flatnonzero(mgr.sensors.state >= SensorState.ISOLATED).tolist() == [2] and loop.discarded >= 1 and loop.accepted >= 50
    h, c = selfcal_c(trk, "rimu_sc", fs, M, 1e-4)
    (tmp_path / "rimu_sc.h").write_text(h)
    (tmp_path / "rimu_sc.c").write_text(c)
    (tmp_path / "main.c").write_text(_LOOP_MAIN)
    res = subprocess.run([CC, *CFLAGS, "-o", str(tmp_path / "loop"), str(tmp_path / "main.c"),
                          str(tmp_path / "rimu_sc.c"), "-lm"], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    out = subprocess.run([str(tmp_path / "loop")], input="\n".join(lines) + "\n", capture_output=True, text=True,
                         check=True).stdout.splitlines()
    got = {"Y": [], "C": [], "W": [], "S": []}
    for line in out:
        got[line[0]].append(np.array([float(v) for v in line[2:].split()]))
    # the window GLT: the same statistic (1e-12 relative) and threshold, so the same alarms, on every sample
    n_stat = alarms = 0
    for (stat_c, thr_c), ref in zip(got["S"], ref_s, strict=True):
        if ref is None:
            continue
        n_stat += 1
        assert abs(stat_c - ref[0]) <= 1e-12 * max(1.0, abs(ref[0])) and thr_c == pytest.approx(ref[1], rel=1e-14)
        assert (stat_c > thr_c) == (ref[0] > ref[1])
        alarms += ref[0] > ref[1]
    assert n_stat >= N - 10 and alarms >= 3
    assert len(got["Y"]) == N and len(got["C"]) == len(ref_c) == N // M and len(got["W"]) == len(ref_w) == N // M
    err_y = max(float(np.abs(a - b).max()) for a, b in zip(got["Y"], ref_y, strict=True))
    assert err_y <= 1e-12 * 0.01                                      # SI (rad/s): 1e-12 of the noise
    for a, b in zip(got["C"], ref_c, strict=True):
        _close(a, b, "the detector's covariance")
    S = trk.m * n
    G = len(loop._applied)
    switched = set()
    for a, (_, vals, sigs, theta, app, gain, var) in zip(got["W"], ref_w, strict=True):
        tail = a[3 * S + 3:].reshape(G, 3)
        assert tail[:, 0].astype(bool).tolist() == app.tolist()        # the held-out check decides alike
        _close(tail[:, 1], gain, "held-out gain")
        _close(tail[:, 2], var, "held-out gain variance")
        switched |= {(j, bool(v)) for j, v in enumerate(app)}
        for b in range(trk.m):
            blk = slice(b * n, (b + 1) * n)
            _close(a[:S][blk], vals[b], f"terms[{trk.blocks[b]}]")
            _close(a[S:2 * S][blk], sigs[b], f"sigmas[{trk.blocks[b]}]")
            _close(a[2 * S:3 * S][blk], theta[blk], f"theta[{trk.blocks[b]}]")
    assert tuple(int(v) for v in a[3 * S:3 * S + 3]) == (loop.accepted, loop.rejected, loop.discarded)
    assert len(switched) >= G + 1          # some group both applied and suspended over the run: the check acted


def _full_kernel() -> tuple[str, str]:
    cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)
    trk = SelfCalTracker(cal, SelfCalSettings(bias_rw=4e-7, scale_rw=1e-9, temperature_sigma=[1e-4, 5e-6, 2e-7],
                                              window_s=0.5, hold_s=2.0))
    return selfcal_c(trk, "rimu_sc", 100.0, 50, 1e-4)


def test_kernel_has_no_dynamic_memory_and_no_recursion():
    h, c = _full_kernel()
    assert not re.search(r"\b(malloc|calloc|realloc|free|alloca)\s*\(", c + h)
    bodies = re.split(r"\n(?=(?:static )?(?:void|int|double) rimu_sc_\w+\()", c)
    names = 0
    for body in bodies[1:]:
        name = re.match(r"(?:static )?(?:void|int|double) (rimu_sc_\w+)\(", body).group(1)
        names += 1
        assert not re.search(rf"\b{name}\(", body.split("{", 1)[1]), f"{name} calls itself"
    assert names >= 14


@pytest.mark.skipif(shutil.which("cppcheck") is None, reason="cppcheck is not installed")
def test_kernel_misra_nothing_outside_the_documented_deviations(tmp_path):
    from rimu.export.misra import DEVIATIONS, misra_check

    h, c = _full_kernel()
    (tmp_path / "rimu_sc.h").write_text(h)
    (tmp_path / "rimu_sc.c").write_text(c)
    found = misra_check(tmp_path, files=("rimu_sc.c", "rimu_sc.h"))
    assert sum(found["misra"].values()) > 0   # the addon ran and read the code
    assert set(found["misra"]) <= set(DEVIATIONS), set(found["misra"]) - set(DEVIATIONS)
    assert not found["other"], found["other"]


@pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None, reason="arm-none-eabi-gcc is not installed")
def test_kernel_builds_for_cortex_m4(tmp_path):
    h, c = _full_kernel()
    (tmp_path / "rimu_sc.h").write_text(h)
    (tmp_path / "rimu_sc.c").write_text(c)
    res = subprocess.run(["arm-none-eabi-gcc", "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Os",
                          "-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16", "-c", "rimu_sc.c"],
                         cwd=tmp_path, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
