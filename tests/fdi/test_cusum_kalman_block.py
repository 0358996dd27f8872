"""The vectorised block paths of the CUSUM bank and the Kalman detector against their per-sample paths (equal to
1e-12, alarms on the same samples) and against independent references (Page's recursion written out, filterpy).
The block paths of both detectors for each backend (numpy, and numba where installed): the same bits as update()."""

import numpy as np
import pytest
from scipy.stats import norm

import rimu.fusion.backend as backend_mod
from rimu.errors import BackendUnavailableError, NonFiniteError, ShapeError
from rimu.fdi import CusumBank, ParityKalman
from rimu.fdi.cusum import markov_arl
from rimu.geometry import cone6, dodecahedron6

V6 = cone6().parity_matrix()

#: the CUSUM bank's block backends: numpy (the reference) always, numba where it is installed
BACKENDS = ["numpy", pytest.param("numba", marks=pytest.mark.skipif(not backend_mod.numba_available(),
                                                                     reason="numba not installed"))]


def faulted_parity(N: int, V: np.ndarray, seed: int) -> np.ndarray:
    """Unit-noise parity with a sequence of faults: a 1 sigma bias, a 3 sigma bias on another sensor, a ramp,
    a sign-alternating fault and a 30 sigma step (an alarm every sample)."""
    rng = np.random.default_rng(seed)
    P = rng.standard_normal((N, V.shape[0]))
    q = N // 8
    P[q:2 * q] += 1.0 * V[:, 1]
    P[3 * q:4 * q] += 3.0 * V[:, 4]
    P[5 * q:6 * q] += np.linspace(0, 4, q)[:, None] * V[:, 0]
    P[6 * q:7 * q] += 2.0 * np.where(np.arange(q) % 50 < 25, 1, -1)[:, None] * V[:, 2]
    P[7 * q:7 * q + 300] += 30.0 * V[:, 5]
    return P


def cusum_steps(bank: CusumBank, P: np.ndarray, V: np.ndarray, dof: int) -> tuple[np.ndarray, np.ndarray]:
    """update() per sample with reset() after each alarm (the block path's renewal); (ratio, isolated at alarms)."""
    bank.configure(V, dof)
    out, iso = np.zeros(len(P)), np.full(len(P), -1)
    for k, p in enumerate(P):
        out[k] = bank.update(p)[0]
        if out[k] > 1.0:
            iso[k] = bank.isolate(p)[0]
            bank.reset()
    return out, iso


def page_reference(P: np.ndarray, V: np.ndarray, dof: int, bias: float, arl0: float) -> tuple[np.ndarray, np.ndarray]:
    """Page's CUSUM as the textbook writes it, S = max(0, S + delta (X - delta / 2)), restart after each alarm."""
    U, d, thr, act = CusumBank(bias, arl0).design(V, dof)
    X = P[:, :dof] @ U
    S = np.zeros((2, V.shape[1]))
    out, iso = np.zeros(len(P)), np.full(len(P), -1)
    for k in range(len(P)):
        S[0] = np.maximum(S[0] + d * (X[k] - d / 2), 0.0)
        S[1] = np.maximum(S[1] + d * (-X[k] - d / 2), 0.0)
        r = np.where(act, S / np.where(act, thr, 1.0), 0.0)
        out[k] = r.max()
        if out[k] > 1.0:
            iso[k] = int(np.argmax(r)) % V.shape[1] if dof >= 2 else -1
            S[:] = 0.0
    return out, iso


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("rebase", [4096, 208])
def test_cusum_block_equals_steps_with_faults(rebase, backend):
    """30 000 samples with five kinds of fault, several hundred alarms, across many origin moves (REBASE)."""
    P = faulted_parity(30_000, V6, 11)
    bank = CusumBank(1.0, 1e4, backend=backend)
    assert bank.backend == backend
    bank.REBASE = rebase
    blk, thr, iso_b = bank.block(P, V6, 3)
    step, iso_s = cusum_steps(bank, P, V6, 3)
    assert thr == 1.0
    np.testing.assert_allclose(blk, step, rtol=0, atol=1e-12)
    assert np.array_equal(blk, step)           # the same operations in the same order: the same bits
    alarms = np.flatnonzero(blk > 1.0)
    assert np.array_equal(alarms, np.flatnonzero(step > 1.0)) and len(alarms) > 300
    assert np.array_equal(iso_b, iso_s)
    assert np.any(np.diff(alarms) == 1)        # consecutive alarms (the 30 sigma step)
    assert np.any(alarms % rebase == rebase - 1) or rebase > 300  # an alarm on the last sample of a chunk


@pytest.mark.parametrize("backend", BACKENDS)
def test_cusum_block_without_restart_equals_update_alone(backend):
    """restart=False: the manager's semantics within one active set (no reset at alarms), bit for bit."""
    P = faulted_parity(20_000, V6, 17)
    bank = CusumBank(1.0, 1e4, backend=backend)
    bank.REBASE = 1024
    blk, _, iso = bank.block(P, V6, 3, restart=False)
    bank.configure(V6, 3)
    step = np.zeros(len(P))
    iso_s = np.full(len(P), -1)
    for k, p in enumerate(P):
        step[k] = bank.update(p)[0]
        if step[k] > 1.0:
            iso_s[k] = bank.isolate(p)[0]
    assert np.array_equal(blk, step) and np.array_equal(iso, iso_s)
    assert (blk > 1.0).sum() > (bank.block(P, V6, 3)[0] > 1.0).sum() > 100   # no renewal: longer alarm runs


@pytest.mark.parametrize("backend", BACKENDS)
def test_cusum_block_equals_page_recursion(backend):
    """The closed form against Page's recursion written independently: same alarms, same isolations, values
    to rounding (the recursion adds in another order)."""
    P = faulted_parity(16_000, V6, 12)
    blk, _, iso = CusumBank(1.0, 1e4, backend=backend).block(P, V6, 3)
    ref, iso_ref = page_reference(P, V6, 3, 1.0, 1e4)
    np.testing.assert_allclose(blk, ref, rtol=1e-9, atol=1e-9)
    assert np.array_equal(blk > 1.0, ref > 1.0)
    assert np.array_equal(iso, iso_ref)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("dof, drop", [(3, None), (2, 4), (1, (2, 5))])
def test_cusum_block_equals_steps_reduced_sets(dof, drop, backend):
    """Active sets with isolated sensors (zero parity columns) and one parity dimension (alarms, no isolation)."""
    from rimu.fusion import ProjectionTable

    H = dodecahedron6().H
    keep = np.ones(6, bool)
    if drop is not None:
        keep[list(np.atleast_1d(drop))] = False
    tab = ProjectionTable(H, 1.0)
    Vz = tab.Vz[tab.entry_for(keep)] if drop is not None else tab.Vz[0]
    assert int(np.linalg.matrix_rank(Vz)) == dof
    P = faulted_parity(12_000, Vz, 13)
    P[:, dof:] = 0.0
    bank = CusumBank(1.0, 1e3, backend=backend)
    blk, _, iso_b = bank.block(P, Vz, dof)
    step, iso_s = cusum_steps(bank, P, Vz, dof)
    assert np.array_equal(blk, step) and np.array_equal(iso_b, iso_s)
    assert np.any(blk > 1.0)
    if drop is not None:
        assert not np.isin(iso_b, np.flatnonzero(~keep)).any()   # an isolated sensor is never named
    if dof < 2:
        assert np.all(iso_b == -1)
    ref, iso_ref = page_reference(P, Vz, dof, 1.0, 1e3)
    assert np.array_equal(blk > 1.0, ref > 1.0) and np.array_equal(iso_b, iso_ref)


@pytest.mark.parametrize("backend", BACKENDS)
def test_cusum_block_dense_alarms_and_split_calls(backend):
    """An alarm on every sample (30 sigma) and one every ~10 (3 sigma) across origin moves every 100 samples;
    the block is causal (a block cut inside an alarm episode is the prefix of the whole one, bit for bit) and
    the rest, in a call of its own, is a fresh configure() + update() with restarts."""
    rng = np.random.default_rng(21)
    P = rng.standard_normal((3000, 3))
    P[500:900] += 30.0 * V6[:, 5]
    P[1500:2600] += 3.0 * V6[:, 2]
    bank = CusumBank(1.0, 1e4, backend=backend)
    bank.REBASE = 96
    whole, _, iso = bank.block(P, V6, 3)
    step, iso_s = cusum_steps(bank, P, V6, 3)
    assert np.array_equal(whole, step) and np.array_equal(iso, iso_s)
    alarms = np.flatnonzero(whole > 1.0)
    assert np.all(whole[500:900] > 1.0) and np.all(iso[500:900] == 5)      # dense: every sample restarts
    episode = alarms[(alarms > 1500) & (alarms < 2600)]
    assert 3 < np.median(np.diff(episode)) < 30 and np.mean(iso[episode] == 2) > 0.95
    wide = np.asfortranarray(np.hstack([P, rng.standard_normal((len(P), 2))]))
    assert np.array_equal(bank.block(wide, V6, 3)[0], whole)                # any layout, extra columns unread
    for m in (700, 701, 1997, 2016, 2017):                                   # inside the episodes
        head, _, iso_h = bank.block(P[:m], V6, 3)
        assert np.array_equal(head, whole[:m]) and np.array_equal(iso_h, iso[:m])
        tail, _, iso_t = bank.block(P[m:], V6, 3)
        ref, iso_r = cusum_steps(bank, P[m:], V6, 3)
        assert np.array_equal(tail, ref) and np.array_equal(iso_t, iso_r)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("where, value", [(10, np.nan), (700, np.nan), (2999, np.inf), (1800, -np.inf)])
def test_cusum_block_non_finite_is_named(backend, where, value):
    """A NaN or inf in the parity (in control, inside alarm episodes, last sample) raises NonFiniteError,
    never a NaN statistic; a block of the wrong shape raises ShapeError."""
    rng = np.random.default_rng(22)
    P = rng.standard_normal((3000, 3))
    P[500:900] += 30.0 * V6[:, 5]
    P[1500:2600] += 3.0 * V6[:, 2]
    P[where, 1] = value
    bank = CusumBank(1.0, 1e4, backend=backend)
    bank.REBASE = 96
    for restart in (True, False):
        with pytest.raises(NonFiniteError, match="non-finite.*leave invalid samples out"):
            bank.block(P, V6, 3, restart=restart)
    P[where, 1] = 0.0                           # as the campaign leaves an invalid sample out
    assert np.isfinite(bank.block(P, V6, 3)[0]).all()
    with pytest.raises(ShapeError, match=r"\(N, >= dof = 3\)"):
        bank.block(P[:, :2], V6, 3)


def test_cusum_update_non_finite_is_named_and_changes_nothing():
    """The step path as the block path: a NaN or inf parity raises NonFiniteError (it used to make every later
    statistic 0, silently), and the bank is left as it was: the samples after it give the statistics of a bank
    that never saw it."""
    rng = np.random.default_rng(23)
    P = rng.standard_normal((400, 3))
    P[200:] += 2.0 * V6[:, 1]
    a, b = CusumBank(1.0, 1e4), CusumBank(1.0, 1e4)
    a.REBASE = b.REBASE = 96
    for bank in (a, b):
        bank.configure(V6, 3)
    for k, p in enumerate(P):
        if k in (50, 250, 251):
            for bad in (np.nan, np.inf):
                q = p.copy()
                q[2] = bad
                with pytest.raises(NonFiniteError, match="non-finite"):
                    a.update(q)
        assert a.update(p) == b.update(p)


def test_block_backend_choice(monkeypatch):
    """``backend=`` as the runtime's (rimu.fusion.backend): numba asked for and missing is named, auto falls
    back to numpy, RIMU_BACKEND decides without an argument."""
    monkeypatch.setenv("RIMU_BACKEND", "numpy")
    assert CusumBank(1.0).backend == ParityKalman(20).backend == "numpy"
    monkeypatch.setattr(backend_mod, "_KERNELS", [None])
    monkeypatch.delenv("RIMU_BACKEND")
    assert CusumBank(1.0, backend="auto").backend == "numpy"
    with pytest.raises(BackendUnavailableError, match=r"pip install rimu\[fast\]"):
        CusumBank(1.0, backend="numba")
    assert ParityKalman(20, backend="auto").backend == "numpy"
    with pytest.raises(BackendUnavailableError, match=r"pip install rimu\[fast\]"):
        ParityKalman(20, backend="numba")


@pytest.mark.parametrize("backend", BACKENDS)
def test_cusum_block_run_length_matches_brook_evans(backend):
    """Mean samples between alarms of one member (one active sensor's bank of 2, in one parity dimension)
    against the Markov-chain ARL of its own threshold (Brook & Evans 1972): the renewal block path counts it."""
    rng = np.random.default_rng(14)
    V = np.array([[1.0]])
    bank = CusumBank(1.0, 200.0, backend=backend)
    _U, d, thr, _ = bank.design(V, 1)
    P = rng.standard_normal((400_000, 1))
    s, _, _ = bank.block(P, V, 1)
    k = d[0] / 2
    arl_member = markov_arl(thr[0] / d[0], lambda x: norm.cdf(x + k), states=400)
    # two one-sided members, nearly independent rare events: the bank's rate is twice one member's
    measured = len(P) / (s > 1.0).sum()
    assert measured == pytest.approx(arl_member / 2, rel=0.08)


@pytest.mark.parametrize("backend", BACKENDS)
def test_block_paths_empty_and_no_parity(backend):
    bank = CusumBank(1.0, 1e4, backend=backend)
    s, _, iso = bank.block(np.zeros((0, 3)), V6, 3)
    assert s.shape == (0,) and iso.shape == (0,)
    s, _, iso = bank.block(np.ones((5, 3)), V6, 0)
    assert np.all(s == 0) and np.all(iso == -1)
    for test in ("estimate", "innovation"):
        s, _, iso = ParityKalman(20, 1e-3, test=test).block(np.zeros((0, 3)), V6, 3)
        assert s.shape == (0,) and iso.shape == (0,)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("test", ["estimate", "innovation"])
def test_kalman_block_equals_steps_and_filterpy(test, backend):
    P = faulted_parity(30_000, V6, 15)
    kf = ParityKalman(20, 1e-3, test=test, backend=backend)
    assert kf.engine == "steady" and kf.backend == backend
    blk, thr, iso = kf.block(P, V6, 3)
    kf.configure(V6, 3)
    step = np.array([kf.update(p)[0] for p in P])
    np.testing.assert_allclose(blk, step, rtol=1e-12, atol=1e-12 * thr)
    assert np.array_equal(blk, step)            # the same operations in the same order: the same bits
    assert np.array_equal(blk > thr, step > thr) and (blk > thr).sum() > 100
    alarms = np.flatnonzero(blk > thr)[::97]
    kf.configure(V6, 3)
    for k in range(len(P)):                     # isolation at alarm samples: the block's choice is the step's
        kf.update(P[k])
        if k in set(alarms.tolist()):
            assert kf.isolate(P[k])[0] == iso[k]
        if k > alarms[-1]:
            break
    ref = ParityKalman(20, 1e-3, test=test, engine="filterpy")
    ref.configure(V6, 3)
    fp = np.array([ref.update(p)[0] for p in P[:6000]])
    np.testing.assert_allclose(fp, step[:6000], rtol=1e-11, atol=1e-12 * thr)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("test", ["estimate", "innovation"])
def test_kalman_block_non_finite_and_shape_are_named(test, backend):
    P = faulted_parity(4000, V6, 18)
    kf = ParityKalman(20, 1e-3, test=test, backend=backend)
    for where, value in ((0, np.nan), (1234, np.inf), (3999, -np.inf)):
        Q = P.copy()
        Q[where, 2] = value
        with pytest.raises(NonFiniteError, match="non-finite.*leave invalid samples out"):
            kf.block(Q, V6, 3)
    with pytest.raises(ShapeError, match=r"\(N, >= dof = 3\)"):
        kf.block(P[:, :2], V6, 3)


@pytest.mark.skipif(not backend_mod.numba_available(), reason="numba not installed")
@pytest.mark.parametrize("test", ["estimate", "innovation"])
@pytest.mark.parametrize("dof, drop", [(3, None), (2, (2, 5)), (1, (2, 5))])
def test_kalman_numba_equals_numpy_everywhere(test, dof, drop):
    """The compiled filter, statistic and isolation against the numpy path (lfilter, block_isolate): the same
    statistics and the same isolated sensor on every sample, alarm or not, also with isolated sensors."""
    from rimu.fusion import ProjectionTable

    tab = ProjectionTable(dodecahedron6().H, 1.0)
    keep = np.ones(6, bool)
    if drop is not None:
        keep[list(drop)] = False
    Vz = tab.Vz[tab.entry_for(keep)]
    P = faulted_parity(12_000, Vz, 19)
    a = ParityKalman(20, 1e-3, test=test, backend="numpy").block(P, Vz, dof)
    b = ParityKalman(20, 1e-3, test=test, backend="numba").block(P, Vz, dof)
    assert np.array_equal(a[0], b[0]) and a[1] == b[1] and np.array_equal(a[2], b[2])
    assert (a[0] > a[1]).sum() > 10 and (np.all(a[2] == -1) if dof < 2 else len(np.unique(a[2])) >= 3)
    if drop is not None and dof >= 2:
        assert not np.isin(b[2], list(drop)).any()


def test_kalman_block_with_noise_model_equals_steps():
    from rimu.fdi.whitening import NoiseSettings
    from rimu.noise import InstrumentNoise

    sig = 0.01
    m = InstrumentNoise.from_terms("gyro", cone6().names, 100.0, white=sig / 10.0, bias_instability=sig / 20)
    from rimu.noise.parity import normalised_parity_matrix

    Vz = normalised_parity_matrix(cone6().H, np.full(6, sig))
    P = faulted_parity(8000, Vz, 16)
    kf = ParityKalman(20, 1e-3, noise=NoiseSettings(m, horizon_s=300.0))
    blk, thr, _ = kf.block(P, Vz, 3)
    kf.configure(Vz, 3)
    step = np.array([kf.update(p)[0] for p in P])
    np.testing.assert_allclose(blk, step, rtol=1e-12, atol=1e-12 * thr)
    assert np.array_equal(blk > thr, step > thr)
