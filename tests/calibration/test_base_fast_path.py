"""LeastSquares' fast base path (issue 28) gives the answer of the general path: the one-pass statistics (numpy's
stacked sums of short segments, the compiled kernel of long ones or of any once numba is loaded) equal exactly
rounded per-sample sums; the fit of every sensor of every instrument at once equals the per-sensor design path
(values and covariances) on imucal's real Ferraris recording and on a simulated Ferraris session with long
segments; the pandas parser of the Ferraris loader reads the numbers numpy's reader reads."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rimu.calibration import LeastSquares
from rimu.calibration.model import ErrorModel
from rimu.geometry import triad3
from rimu.session import SessionStatistics, load_ferraris
from rimu.session import stats as stats_mod
from rimu.sim import Simulator, rotation, static
from rimu.units import DEG_TO_RAD
from tests.conftest import shared_data

REL = 1e-10  # the brief of issue 28: parameters and uncertainties within 1e-10 (relative) of the general path


def _fsum_moments(y):
    """Column sums, sums of squares, and squared deviations of the first differences from their mean, each
    exactly rounded (math.fsum), the reference of SegmentSums."""
    n = y.shape[0]
    tot = np.array([math.fsum(y[:, j]) for j in range(y.shape[1])])
    sq = np.array([math.fsum(y[:, j] ** 2) for j in range(y.shape[1])])
    if n < 3:
        return tot, sq, np.zeros(y.shape[1]), 0
    d = np.diff(y, axis=0)
    dd = np.array([math.fsum(d[:, j] ** 2) for j in range(y.shape[1])]) - (y[-1] - y[0]) ** 2 / (n - 1)
    return tot, sq, dd, n - 2


def _ferraris_session(static_s: float, seed: int = 7):
    """Six static positions and one full turn about each axis (imucal's Ferraris procedure), reported as angles."""
    ups = {"x_p": (1, 0, 0), "x_a": (-1, 0, 0), "y_p": (0, 1, 0), "y_a": (0, -1, 0), "z_p": (0, 0, 1),
           "z_a": (0, 0, -1)}
    steps = [static(k, up, static_s) for k, up in ups.items()]
    for k, ax in {"x_rot": (1, 0, 0), "y_rot": (0, 1, 0), "z_rot": (0, 0, 1)}.items():
        steps.append(rotation(k, np.array(ax) * 36.0 * DEG_TO_RAD, 10.0, report="angle"))
    g = triad3()
    return Simulator({"gyro": g, "accel": g}, latitude_deg=None, seed=seed).run(steps).session


@pytest.mark.parametrize("compiled,stack_rows", [(False, 1 << 16), (False, 200), (True, 1 << 16)])
def test_stacked_and_compiled_sums_equal_exact_sums(monkeypatch, compiled, stack_rows):
    """SessionStatistics.sums_of (short segments stacked: numpy's reduceat, in one stack or in chunks of at most
    ``stack_rows`` rows, or the compiled kernel; a long one alone) against exactly rounded per-sample sums, 1e-12
    relative, segments of 1 to 3000 samples."""
    monkeypatch.setattr(stats_mod, "STACK_ROWS", stack_rows)
    if compiled:
        pytest.importorskip("numba")
        import numba  # noqa: F401 - loaded: short segments take the kernel too
    else:
        monkeypatch.setattr(stats_mod, "_kernels", lambda: None)
        monkeypatch.setattr(stats_mod, "_KERNELS", [])
    s = _ferraris_session(2.0)
    rng = np.random.default_rng(1)
    segs = []
    from rimu.session import Segment, Session

    for k, n in enumerate((1, 2, 3, 5, 250, 3000)):  # 3000 >= KERNEL_MIN_SAMPLES: the long path
        y = rng.normal(size=(n, 3)) * [1e-3, 2.0, 1.0] + [0.1, -9.8, 3.0]
        segs.append(Segment(f"s{k}", "static", np.arange(n) / 100.0, {"accel": y}, specific_force_mb=[0, 0, 9.8]))
    sess = Session(segs, {"accel": s.geometries["accel"]}, 100.0, None, s.gravity)
    st = SessionStatistics(sess, "numba" if compiled else "numpy")
    got = st.sums_of(segs, "accel", full=True)
    for seg, g in zip(segs, got):
        tot, sq, dd, dof = _fsum_moments(seg.raw["accel"])
        scale = np.abs(seg.raw["accel"]).max() * seg.n_samples
        np.testing.assert_allclose(g.total, tot, rtol=1e-12, atol=1e-15 * scale)
        np.testing.assert_allclose(g.sumsq, sq, rtol=1e-12)
        assert g.diff[1] == dof
        np.testing.assert_allclose(g.diff[0], dd, rtol=1e-10, atol=1e-12 * max(float(np.abs(dd).max()), 1e-300))


def _same(a, b, what):
    for inst in a.instruments:
        for sa, sb in zip(a[inst].sensors, b[inst].sensors):
            p = [sb.theta_names.index(n) for n in sa.theta_names]
            np.testing.assert_allclose(sa.theta, sb.theta[p], rtol=REL, atol=1e-13, err_msg=what)
            c = sb.theta_cov[np.ix_(p, p)]
            np.testing.assert_allclose(sa.theta_cov, c, rtol=REL, atol=REL * np.abs(c).max(), err_msg=what)
            assert sa.sigma == pytest.approx(sb.sigma, rel=1e-12)


@pytest.mark.parametrize("data", ["ferraris", "simulated"])
def test_fast_path_equals_the_general_path_with_either_backend(data):
    """The base model's array path (statistics by numpy or by the compiled kernel) against the general per-sensor
    design path of the same model (its effects listed the other way round), and the two backends against each
    other: every physical value and its covariance within 1e-10 relative, on the real recording (short segments)
    and on a simulated Ferraris session whose statics are longer than KERNEL_MIN_SAMPLES."""
    if data == "ferraris":
        session = load_ferraris(shared_data("imucal_ferraris_session", "example_ferraris_session.csv"))
    else:
        session = _ferraris_session(1.05 * stats_mod.KERNEL_MIN_SAMPLES / 100.0)
    general = LeastSquares(model=ErrorModel.from_names("bias,scale_misalignment")).fit(session)
    fast_np = LeastSquares(backend="numpy").fit(session)
    _same(fast_np, general, f"{data}: numpy statistics against the per-sensor path")
    if pytest.importorskip("numba", reason="the compiled kernel needs numba") is not None:
        fast_nb = LeastSquares(backend="numba").fit(session)
        _same(fast_nb, general, f"{data}: compiled statistics against the per-sensor path")
        _same(fast_nb, fast_np, f"{data}: compiled against numpy statistics")
    ca, cb = fast_np.to_calibration(), general.to_calibration()
    for inst in ("gyro", "accel"):
        np.testing.assert_allclose(ca[inst].scale, cb[inst].scale, rtol=REL)
        np.testing.assert_allclose(ca[inst].bias, cb[inst].bias, rtol=REL, atol=1e-13)


def test_pandas_parser_reads_what_numpy_reads(monkeypatch):
    """The Ferraris loader's pandas path (taken where pandas is loaded) gives the numbers of numpy's reader, bit for
    bit, and each instrument's samples contiguous."""
    pytest.importorskip("pandas")
    import pandas  # noqa: F401 - loaded: the loader takes its parser

    from rimu.session.loaders import ferraris

    folder = shared_data("imucal_ferraris_session", "example_ferraris_session.csv")
    fast = load_ferraris(folder)
    assert ferraris._parse_fast(folder / "example_ferraris_session.csv") is not None
    monkeypatch.setattr(ferraris, "_parse_fast", lambda path: None)
    ref = load_ferraris(folder)
    for a, b in zip(fast.segments, ref.segments):
        for inst in ("gyro", "accel"):
            np.testing.assert_array_equal(a.raw[inst], b.raw[inst])
            assert a.raw[inst].flags["C_CONTIGUOUS"]
