"""Many sensors (issue 19, item 2): active sets computed when they occur, bounded cache, same numbers as the
former table of every exclusion set, a 96-axis unit in well under 200 MB."""

from __future__ import annotations

import tracemalloc
from itertools import combinations

import numpy as np
import pytest

from rimu.calibration import InstrumentCalibration
from rimu.fdi import RedundancyManager, glt_snapshot
from rimu.fusion import InstrumentPipeline, ProjectionTable, bits_mask, mask_bits
from rimu.fusion.reference import FullProjectionTable
from rimu.fusion.validity import Validity
from rimu.geometry import cone6, dodecahedron6, tetrad4
from rimu.sim import cho_park_table3
from rimu.sim.multitriad import random_multitriad, triad_array


def _axes(g, seed):
    """Calibrated axes: the nominal ones tilted by up to ~20 mrad, and unequal noise."""
    rng = np.random.default_rng(seed)
    A = g.H + 0.02 * rng.standard_normal(g.H.shape)
    return A / np.linalg.norm(A, axis=1)[:, None], rng.uniform(0.005, 0.02, g.n)


@pytest.mark.parametrize("geom", [cone6, tetrad4, dodecahedron6])
def test_every_set_and_isolation_equal_the_full_table(geom):
    g = geom()
    A, sig = _axes(g, 7)
    old = FullProjectionTable(A, sig)
    new = ProjectionTable(A, sig)
    rng = np.random.default_rng(3)
    n = g.n
    for k in range(n - 2):
        for excl in combinations(range(n), k):
            act = np.ones(n, bool)
            act[list(excl)] = False
            eo, en = old.entry_for(act), new.entry_for(act)
            assert int(new.dof[en]) == int(old.dof[eo]) and bool(new.observable[en]) == bool(old.observable[eo])
            for name in ("G", "Vz", "P"):
                np.testing.assert_allclose(getattr(new, name)[en], getattr(old, name)[eo], rtol=0, atol=1e-12)
            d = int(old.dof[eo])
            if d < 1:
                continue
            # GLT decisions on a 10 sigma bias on each active sensor plus noise: same statistic, ratios, sensor
            for j in np.flatnonzero(act):
                z = sig * rng.standard_normal(n)
                z[j] += 10 * sig[j]
                po, pn = old.Vz[eo] @ z, new.Vz[en] @ z
                do = glt_snapshot(po, old.Vz[eo], d, 1e-3, act)
                dn = glt_snapshot(pn, new.Vz[en], d, 1e-3, act)
                assert abs(do.statistic - dn.statistic) <= 1e-12 * max(1.0, do.statistic)
                np.testing.assert_allclose(dn.ratios, do.ratios, rtol=1e-12, atol=1e-12)
                assert dn.isolated == do.isolated
    assert new.computed == len(new) == len(old)  # each set computed once, when first asked for


def test_manager_isolates_successive_faults_like_before():
    """cone6, Cho & Park Table 3: two successive 10 sigma biases are isolated, in order, sets made on the way."""
    cal = cho_park_table3(gyro_sigma=0.001)["gyro"]
    pipe = InstrumentPipeline(cal)
    mgr = RedundancyManager(pipe, confirm=3)
    rng = np.random.default_rng(5)
    u = np.array([0.1, -0.2, 0.3])
    for k in range(60):
        z = cal.axes_mb() @ u + 0.001 * rng.standard_normal(6)
        z[4] += 0.01 if k >= 10 else 0.0
        z[1] += 0.01 if k >= 30 else 0.0
        mgr.step((z + cal.bias) / cal.scale)
    iso = [e.sensor for e in mgr.events if e.kind == "isolated"]
    assert iso == [cal.geometry.names[4], cal.geometry.names[1]]
    assert mgr.state.value == "detection_only"  # four sensors left
    # the full set, without y2, without y2 and y1, and the few sets that alarm samples leave suspects out of
    assert 3 <= pipe.table.computed <= 8


def test_masks_of_any_size_round_trip():
    rng = np.random.default_rng(0)
    for n in (3, 8, 63, 64, 65, 96, 200):
        m = rng.random(n) < 0.5
        c = mask_bits(m)
        assert c == sum(1 << int(i) for i in np.flatnonzero(m))
        assert np.array_equal(bits_mask(c, n), m)


def test_cache_is_bounded_and_evicted_entries_are_not_reused():
    g = triad_array(8)
    A = g.H
    tab = ProjectionTable(A, 0.01, cache_size=4)
    entries = [tab.lookup(tab.full_code & ~(1 << i)) for i in range(10)]
    assert len(tab) == 5 and tab.evictions == 6  # the full set plus the 4 most recent
    assert entries == list(range(1, 11))
    with pytest.raises(KeyError, match="evicted"):
        tab.set(entries[0])
    again = tab.lookup(tab.full_code & ~1)
    assert again == 11  # a new number: an old entry never points at another set
    ref = FullProjectionTable(A, 0.01, max_excluded=1)
    np.testing.assert_allclose(tab.Vz[again], ref.Vz[ref.lookup(ref.full_code & ~1)], atol=1e-12)
    assert tab.memory_bytes() < 5 * 2 * 24 * 24 * 8 + 5 * 2048  # five sets of O(n^2)


def test_96_axes_build_runtime_and_manager_in_under_200_mb():
    g = triad_array(32)
    cal = random_multitriad(g, seed=1).calibration()
    tracemalloc.start()
    try:
        pipe = InstrumentPipeline(cal)
        mgr = RedundancyManager(pipe, confirm=2)
        # run it through ten isolations and samples with invalid values: sets made as they occur
        rng = np.random.default_rng(2)
        y0 = cal.raw_output(np.array([0.3, -0.1, 0.2]))
        faulty = rng.choice(g.n, 10, replace=False)
        for k in range(200):
            y = y0 + cal.noise_sigma * rng.standard_normal(g.n)
            y[faulty[: k // 20 + 1]] += 50 * cal.noise_sigma[0]
            if k % 7 == 0:
                y[rng.integers(g.n)] = np.nan
            mgr.step(y)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200e6, peak
    assert sorted(np.flatnonzero(mgr.isolated)) == sorted(faulty.tolist())
    assert pipe.result.validity == Validity.DEGRADED and len(pipe.table) <= pipe.table.cache_size + 1


def test_step_and_block_identical_with_many_distinct_sets():
    """96 axes, invalid values scattered so that a block holds more distinct sets than the cache."""
    g = triad_array(32)
    cal = InstrumentCalibration.nominal("gyro", g, 0.5, 0.1, 0.003)
    rng = np.random.default_rng(4)
    Y = cal.raw_output(rng.standard_normal((400, 3))) + 0.006 * rng.standard_normal((400, 96))
    Y[rng.integers(0, 400, 300), rng.integers(0, 96, 300)] = np.nan
    Y[10, :94] = np.inf  # unobservable sample
    a, b = InstrumentPipeline(cal, cache_size=8), InstrumentPipeline(cal, cache_size=8)
    keep = np.arange(96) != 5
    blk = b.process(Y, active=keep)
    P = blk.covariance()
    for k, y in enumerate(Y):
        r = a.step(y, active=keep)
        assert r.validity == blk.validity[k] and r.dof == blk.dof[k] and np.array_equal(r.active, blk.active[k])
        np.testing.assert_allclose(r.x, blk.x[k], atol=1e-12)
        np.testing.assert_allclose(r.parity, blk.parity[k], atol=1e-12)
        np.testing.assert_array_equal(np.isinf(np.diag(r.P)), np.isinf(np.diag(P[k])))
    assert blk.validity[10] == Validity.UNOBSERVABLE and np.all(np.isnan(blk.x[10]))
    assert np.all(np.isfinite(np.delete(blk.x, 10, 0))) and np.all(np.isfinite(blk.parity))
    assert len(b.table) <= 9 and b.table.evictions > 0


def test_max_excluded_is_deprecated_and_without_effect():
    g = cone6()
    with pytest.warns(DeprecationWarning, match="max_excluded"):
        tab = ProjectionTable(g.H, 0.01, max_excluded=1)
    e = tab.lookup(tab.full_code & ~0b111)  # three excluded: computed anyway
    assert bool(tab.observable[e]) and int(tab.dof[e]) == 0


def test_isolability_report_of_many_axes():
    """Every pair at once: 32 skewed triads isolate two successive faults; two parallel triads (a dual-IMU
    autopilot) detect but cannot isolate; the report is plain JSON."""
    import json

    from rimu.fdi import isolability

    g = triad_array(32)
    rep = isolability(ProjectionTable(g.H, 0.01), g.names, g.name)
    assert rep.full.dof == 93 and rep.full.detect_two and rep.faults_isolable == 2
    lo, hi = rep.full.wrong_isolation_10sigma
    assert 0.0 <= lo <= hi < 1e-3
    json.dumps(rep.to_dict())
    g2 = triad_array(2, "parallel")
    rep2 = isolability(ProjectionTable(g2.H, 0.01), g2.names, g2.name)
    assert rep2.full.detect_one and not rep2.full.isolate_one and rep2.faults_isolable == 0
    assert rep2.full.max_abs_correlation == pytest.approx(1.0)


def test_single_dropouts_of_any_sensor_are_computed_once():
    """96 axes, one random sensor invalid in every other sample: the default cache holds every single exclusion,
    so each set is decomposed once, not once per sample."""
    g = triad_array(32)
    cal = InstrumentCalibration.nominal("gyro", g, 1.0, 0.0, 0.01)
    pipe = InstrumentPipeline(cal)
    rng = np.random.default_rng(6)
    y0 = cal.raw_output(np.array([0.1, 0.2, 0.3]))
    for k in range(1000):
        y = y0.copy()
        if k % 2:
            y[rng.integers(96)] = np.nan
        pipe.step(y)
    seen = 1 + len({int(i) for i in np.flatnonzero(pipe.invalid_count)})
    assert pipe.table.computed == seen and pipe.table.evictions == 0 and pipe.table.cache_size == 192
