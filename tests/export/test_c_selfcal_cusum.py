"""The exported detector of the self-calibration (``<prefix>_glt_*``: :class:`rimu.fdi.selfcal.TrackedGltWindow`, the
window GLT whose thresholds carry the tracker's covariance and the CUSUM bank beside it) against Python, sample for
sample: the same statistic (1e-12 relative) and threshold, so the same alarms, through a covariance that switches a
sensor's CUSUM off and back on, one whose threshold falls (the bank restarts those statistics), an active set with a
sensor left out, and faults that the CUSUM finds alone (a small step) and that the window GLT finds (a large one).
"""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

from rimu.calibration import InstrumentCalibration
from rimu.export.c_selfcal import selfcal_c
from rimu.fdi.selfcal import SelfCalSettings, SelfCalTracker, TrackedGltWindow
from rimu.geometry import cone6

CC = shutil.which("cc") or shutil.which("gcc")
CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2"]

_MAIN = r"""
#include <stdio.h>
#include "rimu_sc.h"

static rimu_sc_glt G;

int main(void)
{
    char op[2];
    int i, a;
    double v[RIMU_SC_N * RIMU_SC_N], thr, st;
    unsigned char act[RIMU_SC_N];
    while (scanf("%1s", op) == 1) {
        if (op[0] == 'C') {
            for (i = 0; i < RIMU_SC_N * RIMU_SC_N; ++i) { if (scanf("%lf", &v[i]) != 1) return 1; }
            rimu_sc_glt_set_covariance(&G, v);
        } else if (op[0] == 'A') {
            for (i = 0; i < RIMU_SC_N; ++i) { if (scanf("%d", &a) != 1) return 1; act[i] = (unsigned char)a; }
            rimu_sc_glt_configure(&G, act);
        } else {
            for (i = 0; i < RIMU_SC_N; ++i) { if (scanf("%lf", &v[i]) != 1) return 1; }
            st = rimu_sc_glt_update(&G, v, &thr);
            printf("%.17g %.17g\n", st, thr);
        }
    }
    return 0;
}
"""


@pytest.mark.skipif(CC is None, reason="no C compiler on this machine")
def test_exported_detector_decides_as_tracked_glt_window(tmp_path):
    n, sigma, W, p_fa = 6, 0.01, 20, 1e-4
    cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=sigma)
    trk = SelfCalTracker(cal, SelfCalSettings(bias_rw=1e-8))
    h, c = selfcal_c(trk, "rimu_sc", 100.0, W, p_fa, cusum=True)
    (tmp_path / "rimu_sc.h").write_text(h)
    (tmp_path / "rimu_sc.c").write_text(c)
    (tmp_path / "main.c").write_text(_MAIN)
    made = subprocess.run([CC, *CFLAGS, "-o", str(tmp_path / "glt"), str(tmp_path / "main.c"),
                           str(tmp_path / "rimu_sc.c"), "-lm"], capture_output=True, text=True)
    assert made.returncode == 0, made.stderr
    rng = np.random.default_rng(4)
    det = TrackedGltWindow(W, p_fa, cusum=True)
    lines, ref, parts, offs, restarts = [], [], [], 0, 0
    act = np.ones(n, bool)

    def cov(s):                       # the tracker's error, s sigma per sensor
        C = (s * sigma) ** 2 * (np.eye(n) + 0.3 * np.ones((n, n)))
        lines.append("C " + " ".join(repr(float(x)) for x in C.ravel()))
        nodes = det._node.copy()
        det.set_tracker_covariance(C)
        return int(np.sum(det._node < nodes))

    def configure(a):
        lines.append("A " + " ".join(str(int(x)) for x in a))
        Vz = trk.parity_rows(a)
        det.configure(Vz, Vz.shape[0])

    def samples(N, fault=None):
        for _ in range(N):
            z = rng.standard_normal(n) * sigma
            if fault is not None:
                z[fault[0]] += fault[1] * sigma
            z[~act] = 0.0
            lines.append("Z " + " ".join(repr(float(x)) for x in z))
            ref.append(det.update(trk.parity_rows(act) @ z))
            parts.append(det.last_parts)

    configure(act)
    samples(60)                                     # no covariance yet: the plain window GLT, a white CUSUM
    cov(0.02)
    samples(200)
    samples(80, (1, 1.3))                           # a small step: the CUSUM's
    samples(60)
    cov(2.0)                                        # the tracker knows little: every CUSUM off
    offs = int(np.sum(det._inv_h == 0.0))
    samples(40)
    restarts = cov(0.05) + cov(0.02)                # back on, then a lower threshold: those statistics restart
    samples(100)
    act[4] = False                                  # y2 left out: two parity dimensions
    configure(act)
    samples(100)
    samples(40, (0, 6.0))                           # a large step: the window GLT's too
    out = subprocess.run([str(tmp_path / "glt")], input="\n".join(lines) + "\n", capture_output=True, text=True,
                         check=True).stdout.split("\n")
    got = np.array([[float(v) for v in line.split()] for line in out if line])
    want = np.array(ref)
    assert got.shape == want.shape
    assert np.all(np.abs(got[:, 0] - want[:, 0]) <= 1e-12 * np.maximum(1.0, np.abs(want[:, 0])))
    assert np.array_equal(got[:, 1], want[:, 1])
    assert np.array_equal(got[:, 0] > got[:, 1], want[:, 0] > want[:, 1])
    P = np.array(parts)
    by_cusum = int(np.sum((P[:, 1] > want[:, 1]) & (P[:, 0] <= want[:, 1])))
    by_glt = int(np.sum(P[:, 0] > want[:, 1]))
    print(f"\n{len(want)} samples: alarms by the CUSUM alone {by_cusum}, by the window GLT {by_glt}; CUSUMs off "
          f"{offs} of {n}; statistics restarted on a lower threshold {restarts}")
    assert by_cusum >= 1 and by_glt >= 1 and offs == n and restarts >= 1
