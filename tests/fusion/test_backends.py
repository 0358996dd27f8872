"""The compiled backend (numba) gives the numbers of the numpy reference (issues 11, 15), and the backend choice
is explicit: ``backend=`` / ``RIMU_BACKEND``, a named error when numba is asked for and missing.

The reference is the numpy path of the same pipeline; "equal" is 1e-12 relative to the size of what is compared:
estimates against the largest input; parity (a difference of terms of the size of the input in units of the noise,
~1e4 here, that cancel to ~1) against the largest input over the smallest sigma. That is far below any effect
(~1e-6) and above the rounding of another summation order (~1e-16).
"""

from __future__ import annotations

import numpy as np
import pytest

import rimu.fusion.backend as backend
from rimu.calibration import Calibration, InstrumentCalibration
from rimu.calibration.model import RuntimeInputs
from rimu.epoch import EpochBlock
from rimu.errors import BackendUnavailableError, OptionError
from rimu.fusion import EffectCompensation, InstrumentPipeline, Pipeline
from rimu.geometry import cone, cone6
from rimu.sim import cho_park_table3
from rimu.sim.typical import with_effects
from rimu.units import DEG_TO_RAD, G0

INSTS = ("gyro", "accel")
REL = 1e-12


# ---------------------------------------------------------------------------------------------- choice of backend
def test_backend_names_and_environment(monkeypatch):
    assert backend.resolve_backend("numpy") == "numpy"
    assert backend.resolve_backend(" NumPy ") == "numpy"
    with pytest.raises(OptionError, match="auto, numpy, numba.*'fortran'"):
        backend.resolve_backend("fortran")
    monkeypatch.setenv("RIMU_BACKEND", "numpy")
    assert backend.resolve_backend() == "numpy"
    assert Pipeline(cho_park_table3()).backend == "numpy"
    monkeypatch.setenv("RIMU_BACKEND", "cuda")
    with pytest.raises(OptionError, match="RIMU_BACKEND"):
        Pipeline(cho_park_table3())
    monkeypatch.delenv("RIMU_BACKEND")
    expected = "numba" if backend.numba_available() else "numpy"
    assert backend.resolve_backend() == backend.resolve_backend("auto") == expected


def test_numba_asked_for_and_missing_is_named(monkeypatch):
    """Without numba: 'auto' falls back to numpy silently, 'numba' raises and names the extra."""
    monkeypatch.setattr(backend, "_KERNELS", [None])
    assert backend.resolve_backend("auto") == "numpy"
    assert InstrumentPipeline(cho_park_table3()["gyro"], backend="auto").backend == "numpy"
    with pytest.raises(BackendUnavailableError, match=r"pip install rimu\[fast\]") as exc:
        Pipeline(cho_park_table3(), backend="numba")
    assert isinstance(exc.value, ImportError)
    monkeypatch.setenv("RIMU_BACKEND", "numba")
    with pytest.raises(BackendUnavailableError, match="RIMU_BACKEND"):
        InstrumentPipeline(cho_park_table3()["gyro"])


# ---------------------------------------------------------------------------------------------- same numbers
numba = pytest.importorskip("numba")


def _misaligned(instrument: str, g, rng) -> InstrumentCalibration:
    """A unit of geometry g with misalignments of ~1 deg, scale ~0.01 and biases, noise 1e-3 per sensor."""
    n = g.n
    M = g.nominal_rows() + rng.normal(0, 0.3 * DEG_TO_RAD, (n, 3))
    M /= np.linalg.norm(M, axis=1)[:, None]
    return InstrumentCalibration(instrument, g, 0.01 * (1 + rng.normal(0, 1e-3, n)), M,
                                 rng.normal(0, 0.02, n), np.full(n, 1e-3))


def _unit(g, seed: int, effects: bool = True) -> Calibration:
    rng = np.random.default_rng(seed)
    cal = Calibration({k: _misaligned(k, g, rng) for k in INSTS})
    return with_effects(cal) if effects else cal


def _stream(cal: Calibration, N: int, seed: int, noise: float = 0.5) -> EpochBlock:
    """Raw outputs of the calibrated model with every effect (plus noise) for random rates and forces."""
    rng = np.random.default_rng(seed)
    t = 50.0 + np.arange(N) * 0.01
    T = 30.0 + 15.0 * rng.uniform(-1, 1, N)
    U = {"gyro": rng.standard_normal((N, 3)) * 150 * DEG_TO_RAD, "accel": rng.standard_normal((N, 3)) * 0.8 * G0}
    inputs = RuntimeInputs(t=t - t[0], temperature=T, specific_force=U["accel"], angular_rate=U["gyro"])
    raw = {k: EffectCompensation(cal[k]).forward(U[k], inputs) for k in INSTS}
    raw = {k: v + rng.standard_normal(v.shape) * noise for k, v in raw.items()}
    return EpochBlock(t, raw, temperature=T)


def _close(a, b, what, scale=None):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert np.array_equal(np.isnan(a), np.isnan(b)), (what, "NaN (no estimate) on one side only")
    a, b = np.nan_to_num(a), np.nan_to_num(b)
    if scale is None:
        scale = max(1.0, float(np.abs(b).max()) if b.size else 1.0)
    err = float(np.abs(a - b).max()) / scale if b.size else 0.0
    assert err <= REL, (what, err)


def _parity_scale(x, sigma):
    return max(1.0, float(np.abs(x).max()) / float(np.min(sigma)))


def _same_block(a, b, what, sigma=1e-3):
    for k in INSTS:
        _close(a[k].x, b[k].x, f"{what} {k} x")
        _close(a[k].parity, b[k].parity, f"{what} {k} parity", _parity_scale(b[k].x, sigma))
        for name in ("entry", "dof", "active", "invalid", "observable", "saturated", "validity"):
            np.testing.assert_array_equal(getattr(a[k], name), getattr(b[k], name), err_msg=f"{what} {k} {name}")


def _same_step(a, b, what, sigma=1e-3):
    for k in INSTS:
        _close(a[k].x, b[k].x, f"{what} {k} x")
        _close(a[k].parity, b[k].parity, f"{what} {k} parity", _parity_scale(b[k].x, sigma))
        assert (a[k].entry, a[k].dof, a[k].observable, a[k].validity) == (b[k].entry, b[k].dof, b[k].observable,
                                                                           b[k].validity), what
        for name in ("active", "invalid", "saturated", "P"):
            np.testing.assert_array_equal(getattr(a[k], name), getattr(b[k], name), err_msg=f"{what} {k} {name}")


def _spy(pipe):
    """Record whether each call of the compiled path did the work (True) or handed it to numpy (False)."""
    done = []
    step, block = pipe._step_compiled, pipe._compensate_block_compiled
    pipe._step_compiled = lambda ep, f=step: _record(done, f(ep))
    pipe._compensate_block_compiled = lambda *a, f=block: _record(done, f(*a))
    return done


def _record(done, r):
    done.append(r is not None)
    return r


def _pair(cal, **kw):
    a, b = Pipeline(cal, backend="numba", **kw), Pipeline(cal, backend="numpy", **kw)
    assert a.backend == "numba" and b.backend == "numpy"
    return a, b


def _same_block_step_and_stream(cal, block, label):
    """A compiled (numba) and a numpy pipeline of ``cal`` (temperature read) on ``block``: the same block results,
    the same step results epoch by epoch (each on fresh pipelines), every block and epoch done by the compiled
    path with every sample counted once, and the same compensated stream (what the FDI managers get). Returns the
    step-run pair."""
    a, b = _pair(cal, temperature=True)
    done = _spy(a)
    _same_block(a.process(block), b.process(block), label)
    a, b = _pair(cal, temperature=True)
    done_step = _spy(a)
    for j, ep in enumerate(block.epochs()):
        _same_step(a.step(ep), b.step(ep), f"{label} epoch {j}")
    assert done == [True] and len(done_step) == len(block) and all(done_step)  # all on the compiled path
    for k in INSTS:
        assert a[k].samples == b[k].samples == len(block)
    ca, cb = a.compensate(block), b.compensate(block)
    for k in INSTS:
        _close(ca.raw[k], cb.raw[k], f"{label} compensate {k}")
    return a, b


@pytest.mark.parametrize("geometry", ["cone6", "cone24"])
def test_numba_equals_numpy_with_every_effect(geometry):
    """Every compensable effect on both instruments of a misaligned unit (the fixed point between them
    included): block and step of the compiled path equal the numpy path; the compiled path did the work."""
    g = cone6() if geometry == "cone6" else cone(24)
    cal = _unit(g, seed=3)
    block = _stream(cal, 40, seed=4)
    _, b = _same_block_step_and_stream(cal, block, geometry)
    # and the check above can fail: the same stream without compensation is off by the effects
    plain = Pipeline(_unit(g, seed=3, effects=False), backend="numba").process(block)
    assert np.abs(plain["gyro"].x - b.process(block)["gyro"].x).max() > 1e3 * REL * np.abs(plain["gyro"].x).max()


#: subsets of the effects that reach every branch of the compiled stage: exogenous effects only (the raw-domain
#: product, no inversion), output-side effects only (the inversion without the fixed point), one instrument
#: without effects (its slot copies its raw input), and the accelerometers needing the rate while the gyros need
#: nothing (gyros first)
SUBSETS = {
    "exogenous": {"gyro": ["g_sensitivity", "g2_sensitivity", "bias_temperature", "bias_drift"],
                  "accel": ["bias_temperature", "bias_temperature2", "bias_drift"]},
    "output_side": {"gyro": ["sf_quadratic", "sf_cubic", "sf_asymmetry", "scale_temperature", "cross_coupling"],
                    "accel": ["sf_quadratic", "sf_asymmetry", "scale_temperature2", "cross_coupling"]},
    "gyro_only": {"gyro": ["sf_cubic", "g_sensitivity", "bias_temperature2"], "accel": []},
    "size_effect_only": {"gyro": [], "accel": ["size_effect", "sf_quadratic"]},
}


@pytest.mark.parametrize("subset", sorted(SUBSETS))
def test_numba_equals_numpy_with_subsets_of_effects(subset):
    """Each branch of the compiled compensation (raw-domain exogenous product, inversion without the fixed
    point, a slot without effects, either instrument first) gives the numbers of the numpy path, block and
    step, and did the work (every sample counted once); the compensated stream is the same too."""
    cal = with_effects(_unit(cone6(), seed=11, effects=False), SUBSETS[subset])
    block = _stream(cal, 25, seed=12)
    assert _pair(cal, temperature=True)[0]._program is not None
    _, b = _same_block_step_and_stream(cal, block, subset)
    # the check can fail: without compensation the estimates are off by the effects
    plain = Pipeline(_unit(cone6(), seed=11, effects=False), backend="numpy").process(block)
    k = "accel" if subset == "size_effect_only" else "gyro"
    assert np.abs(plain[k].x - b.process(block)[k].x).max() > 1e3 * REL * np.abs(plain[k].x).max()


def test_numba_equals_numpy_on_96_axes_without_effects():
    g = cone(96)
    cal = _unit(g, seed=5, effects=False)
    block = _stream(cal, 30, seed=6)
    a, b = _pair(cal)
    _same_block(a.process(block), b.process(block), "cone96")
    for k in INSTS:
        ia, ib = a[k], b[k]
        for y in block.raw[k][:10]:
            ra, rb = ia.step(y), ib.step(y)
            _close(ra.x, rb.x, "cone96 step x")
            _close(ra.parity, rb.parity, "cone96 step parity", _parity_scale(rb.x, 1e-3))


@pytest.mark.parametrize("effects", [True, False])
def test_invalid_saturated_and_isolated_samples(effects):
    """Samples off the common path (non-finite, marked invalid, at the range limit) and isolation masks: both
    backends route around the same sensors and give the same numbers, counters and validity."""
    cal = _unit(cone6(), seed=7, effects=effects)
    block = _stream(cal, 30, seed=8)
    rng_lim = {k: float(np.abs(block.raw[k]).max()) * 0.99 for k in INSTS}  # a few samples saturate
    raw = {k: v.copy() for k, v in block.raw.items()}
    raw["gyro"][3, 1] = np.nan
    raw["accel"][5, 4] = np.inf
    valid = {k: np.ones_like(v, bool) for k, v in raw.items()}
    valid["gyro"][9, 0] = False
    bad = EpochBlock(block.t, raw, valid, block.temperature)
    a, b = _pair(cal, temperature=True, range_raw=rng_lim)
    _same_block(a.process(bad), b.process(bad), "block")
    a, b = _pair(cal, temperature=True, range_raw=rng_lim)
    active = None
    for j, ep in enumerate(bad.epochs()):
        if j == 12:
            active = {"gyro": np.arange(6) != 2, "accel": ~np.array([0, 0, 0, 1, 1, 0], bool)}
        if j == 20:
            active = {"accel": ~np.array([1, 1, 1, 1, 0, 0], bool)}  # unobservable: x is no estimate (NaN)
        _same_step(a.step(ep, active), b.step(ep, active), f"epoch {j}")
    for k in INSTS:
        np.testing.assert_array_equal(a[k].invalid_count, b[k].invalid_count)
        np.testing.assert_array_equal(a[k].saturated_count, b[k].saturated_count)
        assert a[k].samples == b[k].samples
    assert a["gyro"].invalid_count.sum() >= 2 and a["accel"].saturated_count.sum() >= 1


def test_fdi_manager_active_set_changes_are_followed():
    """The redundancy manager isolates a failing gyro (and its active set changes under the pipeline): the same
    events, estimates and states with either backend."""
    from rimu.fdi import RedundancyManager

    cal = _unit(cone6(), seed=9)
    block = _stream(cal, 400, seed=10, noise=0.05)
    runs = []
    for be in ("numba", "numpy"):
        pipe = Pipeline(cal, temperature=True, backend=be)
        comp = pipe.compensate(block)
        Y = comp.raw["gyro"].copy()
        Y[150:, 4] += 2000.0  # a step fault in sensor 4 from sample 150
        runs.append(RedundancyManager(pipe["gyro"], p_fa=1e-3, confirm=3).run(Y, None, comp.t))
    a, b = runs
    assert [(e.kind, e.sensor, e.sample) for e in a.events] == [(e.kind, e.sensor, e.sample) for e in b.events]
    assert any(e.kind == "isolated" for e in a.events)
    _close(a.x, b.x, "manager x")
    np.testing.assert_array_equal(a.active, b.active)
    np.testing.assert_array_equal(a.validity, b.validity)


def test_instrument_step_writes_into_its_buffers_and_refuses_bad_shapes():
    from rimu.errors import ShapeError

    cal = cho_park_table3()["gyro"]
    p = InstrumentPipeline(cal, backend="numba")
    r = p.step(cal.raw_output(np.array([0.1, -0.2, 0.3])))
    x = r.x
    np.testing.assert_allclose(x, [0.1, -0.2, 0.3], atol=1e-12)
    r2 = p.step(cal.raw_output(np.array([0.2, 0.0, 0.0])))
    assert r2 is r and r2.x is x  # the same buffers, rewritten
    np.testing.assert_allclose(x, [0.2, 0.0, 0.0], atol=1e-12)
    with pytest.raises(ShapeError, match=r"shape \(6,\)"):
        p.step(np.zeros(5))
    with pytest.raises(ShapeError):
        p.process(np.zeros((4, 5)))
    np.testing.assert_allclose(p.step([float(v) for v in cal.raw_output(np.array([0.0, 0.0, 1.0]))]).x, [0, 0, 1],
                               atol=1e-12)  # a list takes the careful path


def test_cycle_rounds_changed_on_the_pipeline_are_followed():
    """``Pipeline.cycle_rounds`` (the gyro <-> accelerometer fixed point) set after construction: the compiled
    path uses it as the numpy path does (one round leaves ~1e-5 of the size effect's rate error: visibly different)."""
    cal = _unit(cone6(), seed=11)
    block = _stream(cal, 5, seed=12)
    outs = {}
    for rounds in (1, 2):
        a, b = _pair(cal, temperature=True)
        a.cycle_rounds = b.cycle_rounds = rounds
        for ep in block.epochs():
            _same_step(a.step(ep), b.step(ep), f"rounds {rounds}")
        outs[rounds] = a.step(next(block.epochs()))["accel"].x.copy()
    assert np.abs(outs[1] - outs[2]).max() > 1e3 * REL * np.abs(outs[2]).max()


# ---------------------------------------------------------------------------------------------- the block path (issue 28)
def _spy_block(pipe):
    """Record whether each call of the unit's compiled block path did the work (True) or handed it to numpy."""
    done = []
    f = pipe._process_compiled
    pipe._process_compiled = lambda *a: _record(done, f(*a))
    return done


@pytest.mark.parametrize("N", [1, 7, 513, 20_000])
def test_block_path_equals_numpy_for_every_block_length_and_writes_into_out(N):
    """The compiled block path (every block length, sizes fixed per unit) gives the numpy path's numbers, did the
    work, counts every sample once, and writes into the buffers ``out=`` gives it (the same result objects next
    block); the numbers can differ: the other unit's estimates are off."""
    cal = _unit(cone6(), seed=21, effects=False)
    block = _stream(cal, N, seed=22)
    a, b = _pair(cal)
    done = _spy_block(a)
    out = {k: np.empty((N, 6)) for k in INSTS}
    ra = a.process(block, out)
    _same_block(ra, b.process(block), f"N={N}")
    assert done == [True]
    for k in INSTS:
        assert np.shares_memory(ra[k].x, out[k]) and np.shares_memory(ra[k].parity, out[k])
        assert a[k].samples == b[k].samples == N
    rb = a.process(block, out)
    assert all(rb[k] is ra[k] for k in INSTS) and done == [True, True]
    _same_block(a.process(block), b.process(block), f"N={N} fresh")  # and without out=: new arrays
    other = Pipeline(_unit(cone6(), seed=23, effects=False), backend="numba").process(block)
    assert np.abs(other["gyro"].x - ra["gyro"].x).max() > 1e3 * REL * np.abs(ra["gyro"].x).max()
    ip, iq = InstrumentPipeline(cal["gyro"], backend="numba"), InstrumentPipeline(cal["gyro"], backend="numpy")
    o = np.empty((N, 6))
    r1 = ip.process(block.raw["gyro"], out=o)
    _close(r1.x, iq.process(block.raw["gyro"]).x, "instrument x")
    assert ip._bpath and np.shares_memory(r1.x, o) and ip.process(block.raw["gyro"], out=o) is r1


@pytest.mark.parametrize("bad", ["nan", "inf", "range", "huge", "isolated"])
def test_block_path_hands_off_what_it_cannot_do(bad):
    """A long block with one value off the common path (non-finite, at its range limit, finite but large enough
    to overflow the projection, or an isolation between blocks): the compiled path hands the block to numpy (or
    repacks the new set) and the numbers, counters and flags equal the numpy path's."""
    N = 3000
    cal = _unit(cone6(), seed=24, effects=False)
    block = _stream(cal, N, seed=25)
    raw = {k: v.copy() for k, v in block.raw.items()}
    lim = {k: float(np.abs(raw[k]).max()) * 1.01 for k in INSTS}
    j = 2345  # far into the block: a kernel that tested only the start would pass it
    if bad == "nan":
        raw["gyro"][j, 3] = np.nan
    elif bad == "inf":
        raw["accel"][j, 0] = -np.inf
    elif bad == "range":
        raw["gyro"][j, 5] = -lim["gyro"]
    elif bad == "huge":
        raw["accel"][j, 2] = 1e306
        lim = {}
    blk = EpochBlock(block.t, raw)
    a, b = _pair(cal, range_raw=lim or None)
    done = _spy_block(a)
    active = None
    if bad == "isolated":  # a new active set between blocks (the set is an argument of every call)
        a.process(blk), b.process(blk)
        active = {"gyro": np.arange(6) != 2}
    with np.errstate(over="ignore", invalid="ignore"):
        _same_block(a.process(blk, active=active), b.process(blk, active=active), bad)
    assert done[-1] is (bad == "isolated")
    for k in INSTS:
        np.testing.assert_array_equal(a[k].invalid_count, b[k].invalid_count)
        np.testing.assert_array_equal(a[k].saturated_count, b[k].saturated_count)
        assert a[k].samples == b[k].samples


def test_block_stream_with_out_allocates_nothing_and_bad_buffers_are_refused():
    """A stream of 1e5-sample blocks through out= buffers: no allocation of the size of a result (tracemalloc's
    peak stays under 10 kB where one fresh result is 4.8 MB); a buffer of the wrong shape or layout is refused
    with ShapeError."""
    import tracemalloc

    from rimu.errors import ShapeError

    N = 100_000
    cal = _unit(cone6(), seed=26, effects=False)
    block = _stream(cal, N, seed=27)
    for pipe in (Pipeline(cal, backend="numba"), Pipeline(cal, backend="numpy")):
        out = {k: np.empty((N, 6)) for k in INSTS}
        pipe.process(block, out)
        tracemalloc.start()
        for _ in range(3):
            pipe.process(block, out)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        if pipe.backend == "numba":
            assert peak < 10_000, peak
        for wrong in (np.empty((N, 5)), np.empty((6, N)).T, np.empty((N, 6), np.float32)):
            with pytest.raises(ShapeError, match="C-ordered float64"):
                pipe.process(block, {"gyro": wrong})


def test_block_path_takes_any_layout_and_keeps_no_fresh_result():
    """Blocks that are not C-ordered writable float64 (Fortran order, read-only, a strided view) go through the
    compiled path as copies, with the numpy path's numbers; a buffer the stream used before, now of the wrong
    length, is refused with ShapeError (the kernel's shape check); and a result made without out= is the caller's
    alone: the pipeline keeps no reference to its arrays once the caller lets go."""
    import gc
    import weakref

    from rimu.errors import ShapeError

    N = 257
    cal = _unit(cone6(), seed=28, effects=False)
    block = _stream(cal, 2 * N, seed=29)
    a, b = _pair(cal)
    done = _spy_block(a)
    ro = block.raw["accel"][:N].copy()
    ro.setflags(write=False)
    kinds = {"fortran": {"gyro": np.asfortranarray(block.raw["gyro"][:N]), "accel": block.raw["accel"][:N]},
             "read-only": {"gyro": block.raw["gyro"][:N], "accel": ro},
             "strided": {k: block.raw[k][::2] for k in INSTS}}
    out = {k: np.empty((N, 6)) for k in INSTS}
    for name, raw in kinds.items():
        blk = EpochBlock(block.t[:N], raw)
        _same_block(a.process(blk, out), b.process(blk), name)
        assert done[-1] is True, name
    with pytest.raises(ShapeError, match="C-ordered float64"):
        a.process(EpochBlock(block.t[:N - 1], {k: block.raw[k][:N - 1] for k in INSTS}), out)
    r = a.process(EpochBlock(block.t, block.raw))
    ref = weakref.ref(r["gyro"].x.base)
    del r
    gc.collect()
    assert ref() is None


def test_block_stream_steady_state_keeps_every_check():
    """A stream through the same out= buffers (the short Python path of the compiled block path): a block with a
    NaN, one at the range limit, and an isolation are handed on and give the numpy path's numbers and counters; a
    block of the wrong width is refused with ShapeError naming the shape; a clean block after them is compiled
    again into the same buffers."""
    from rimu.errors import ShapeError

    N = 300
    cal = _unit(cone6(), seed=30, effects=False)
    block = _stream(cal, N, seed=31)
    lim = {k: float(np.abs(block.raw[k]).max()) * 1.01 for k in INSTS}
    a, b = _pair(cal, range_raw=lim)
    done = _spy_block(a)
    out = {k: np.empty((N, 6)) for k in INSTS}
    a.process(block, out), b.process(block)
    for what in ("nan", "range", "isolated", "clean"):
        raw = {k: v.copy() for k, v in block.raw.items()}
        active = None
        if what == "nan":
            raw["accel"][123, 4] = np.nan
        elif what == "range":
            raw["gyro"][77, 1] = lim["gyro"]
        elif what == "isolated":
            active = {"accel": np.arange(6) != 4}
        blk = EpochBlock(block.t, raw)
        with np.errstate(invalid="ignore"):
            _same_block(a.process(blk, out, active=active), b.process(blk, active=active), what)
        assert done[-1] is (what in ("isolated", "clean")), what
        for k in INSTS:
            np.testing.assert_array_equal(a[k].invalid_count, b[k].invalid_count)
            np.testing.assert_array_equal(a[k].saturated_count, b[k].saturated_count)
            assert a[k].samples == b[k].samples
    with pytest.raises(ShapeError, match=r"\(N, 6\)"):
        a.process(EpochBlock(block.t, {"gyro": block.raw["gyro"][:, :5], "accel": block.raw["accel"]}), out)
