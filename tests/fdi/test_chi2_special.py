"""The runtime's chi-square quantiles come from scipy.special (no scipy.stats import: ~40 MB of the replay's
memory): the same values as scipy.stats to 1e-12; the runtime's import does not bring scipy.stats."""

import subprocess
import sys

import numpy as np
from scipy.stats import chi2

from rimu.fdi.glt import glt_threshold
from rimu.fdi.health import SensorHealth
from rimu.fdi.multiple import FaultSetGlt


def test_thresholds_equal_scipy_stats() -> None:
    for p in (1e-2, 1e-3, 1e-6, 1e-9):
        for d in range(1, 40):
            np.testing.assert_allclose(glt_threshold(p, d), chi2.isf(p, d), rtol=1e-12)
    iso = FaultSetGlt(alpha=1e-4)
    for d in range(2, 20):
        for size in (0, 1, 2):
            if d > size:
                np.testing.assert_allclose(iso.threshold(d, size, 3), chi2.isf(1e-4, 3 * (d - size)), rtol=1e-12)
    h = SensorHealth(6, 100, 2.0, 3, glt_threshold(1e-3, 1), glt_threshold(1e-6, 1))
    for N in (1, 10, 100):
        np.testing.assert_allclose(h._energy_threshold(N), chi2.isf(chi2.sf(h.mean_threshold, 1), N), rtol=1e-12)


def test_runtime_import_leaves_scipy_stats_out() -> None:
    code = ("import sys, rimu.cli.replay, rimu.export, rimu.fdi, rimu.fusion, rimu.session; "
            "print(sorted(m for m in ('scipy.stats', 'scipy.optimize', 'scipy.signal') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]", out
