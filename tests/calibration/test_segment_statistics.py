"""The per-segment statistics the estimators read the samples for (rimu.session.stats) equal the straightforward
per-sample computations, and the estimators built on them give the per-sample results.

References are written out sample by sample (math.fsum, one rotation matrix per sample, the stacked design), so
nothing here checks the statistics against themselves. Segments too short for the noise level (one and two
samples: the estimators count them out of the first-difference sums) and a non-uniformly sampled turn (which
takes the per-sample path of the rotation moments instead of the closed form) are part of the session.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rimu.calibration import ChoPark, LeastSquares, Oliveira
from rimu.calibration.estimate import estimate_noise_sigma
from rimu.calibration.lsq import fit_lsq
from rimu.calibration.model import ErrorModel, contexts
from rimu.geometry import tetrad4, triad3
from rimu.session import Segment, Session, SessionStatistics, column_sums, rotation_matrix
from rimu.sim import Simulator, cho_park_procedure, oliveira_table1

REL = 1e-12


def _fsum_cols(y):
    return np.array([math.fsum(y[:, j]) for j in range(y.shape[1])])


def _rel(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))


@pytest.fixture(scope="module")
def session():
    """A seeded Cho & Park session (latitude set: Earth rate in the rate segments) plus a jittered turn and
    segments of one and two samples."""
    s = Simulator(seed=11).run(cho_park_procedure(duration=3.0)).session
    rng = np.random.default_rng(3)
    rate = next(x for x in s.segments if x.kind == "rate")
    t = rate.t + rng.uniform(-2e-4, 2e-4, rate.n_samples)  # non-uniform sampling
    t[0] = rate.t[0]
    extra = [
        Segment("jitter", "rate", np.sort(t), {k: v.copy() for k, v in rate.raw.items()}, rate_mb=rate.rate_mb,
                mat_ln_mb=rate.mat_ln_mb),
        Segment("one", "static", s.segments[0].t[:1], {k: v[:1].copy() for k, v in s.segments[0].raw.items()},
                mat_ln_mb=s.segments[0].mat_ln_mb),
        Segment("two", "static", s.segments[1].t[:2], {k: v[:2].copy() for k, v in s.segments[1].raw.items()},
                mat_ln_mb=s.segments[1].mat_ln_mb),
    ]
    return Session(s.segments + extra, s.geometries, s.sample_rate, s.latitude, s.gravity)


def test_segment_sums_equal_per_sample_sums(session):
    """Column sums, sums of squares, the Gram matrix and the first-difference sums of every segment and
    instrument: within 1e-12 (relative) of exactly rounded per-sample sums."""
    st = SessionStatistics(session)
    for seg in session.segments:
        for inst in session.instruments:
            y = seg.raw[inst]
            sm = st.sums(seg, inst)
            assert sm.n == len(y)
            assert _rel(sm.total, _fsum_cols(y)) < REL
            assert _rel(column_sums(y), _fsum_cols(y)) < REL
            assert _rel(sm.mean, _fsum_cols(y) / len(y)) < REL
            assert _rel(sm.sumsq, _fsum_cols(y * y)) < REL
            gram = np.array([[math.fsum(y[:, i] * y[:, j]) for j in range(y.shape[1])] for i in range(y.shape[1])])
            assert _rel(sm.gram, gram) < REL
            ss, dof = sm.diff
            if len(y) < 3:
                assert dof == 0 and not np.any(ss)
                continue
            d = np.diff(y, axis=0)
            ref = _fsum_cols((d - _fsum_cols(d) / len(d)) ** 2)  # squared deviations from the mean difference
            assert dof == len(d) - 1
            assert _rel(ss, ref) < 1e-9  # (the one-pass form cancels the mean: 1e-9 of the spread)


def test_noise_sigma_is_the_pooled_first_difference_estimate(session):
    """estimate_noise_sigma = sqrt(pooled var(diff) / 2) over the static segments with three samples or more
    (the one- and two-sample segments add nothing), written out sample by sample."""
    for inst in session.instruments:
        num, den = np.zeros(session.geometries[inst].n), 0
        for seg in session.segments:
            if seg.kind != "static" or seg.n_samples < 3:
                continue
            d = np.diff(seg.raw[inst], axis=0)
            num += np.sum((d - d.mean(axis=0)) ** 2, axis=0)
            den += len(d) - 1
        assert _rel(estimate_noise_sigma(session, inst), np.sqrt(num / den / 2)) < 1e-10


def test_rotation_moments_equal_per_sample_angles(session):
    """B^T B of the angle basis [1, cos, sin] (closed form on uniform segments, per sample on the jittered one),
    B^T Y, and the mean of a fixed local-level vector seen in MB: equal to one rotation matrix per sample."""
    st = SessionStatistics(session)
    v = np.array([0.1, 7e-5, 9.8])
    seen = 0
    for seg in session.segments:
        rm = st.rotation(seg)
        if seg.kind != "rate":
            assert rm is None
            continue
        seen += 1
        w = seg.table_rate()
        th = np.linalg.norm(w) * (seg.t - seg.t[0])
        B = np.column_stack([np.ones_like(th), np.cos(th), np.sin(th)])
        gram = np.array([[math.fsum(B[:, i] * B[:, j]) for j in range(3)] for i in range(3)])
        assert np.max(np.abs(rm.gram - gram)) < REL * seg.n_samples
        for inst, P in st.basis_products(seg, session.instruments).items():
            y = seg.raw[inst]
            ref = np.array([[math.fsum(B[:, i] * y[:, j]) for j in range(y.shape[1])] for i in range(3)])
            assert _rel(P, ref) < 1e-11
        C = seg.mat_ln_mb @ rotation_matrix(np.outer(seg.t - seg.t[0], w))  # one matrix per sample
        per_sample = np.einsum("nji,j->ni", C, v)
        assert np.max(np.abs(rm.mean_vector(seg.mat_ln_mb.T @ v) - per_sample.mean(axis=0))) < REL * 10
        assert np.max(np.abs(B @ rm.coefficients(seg.mat_ln_mb.T @ v) - per_sample)) < 1e-12 * 10
    assert seen >= 13  # the 12 rate segments of Table 2 and the jittered one


@pytest.mark.parametrize("inst", ["gyro", "accel"])
def test_least_squares_from_moments_equals_the_stacked_design(session, inst):
    """LeastSquares' base statistics (turning segments from their rotation moments, Earth rate included for the
    gyros) against numpy's lstsq on the design stacked sample by sample (1e-10 relative)."""
    res = LeastSquares(sigma={inst: 1.0}, instruments=[inst]).fit(session)
    model = ErrorModel.base()
    for ctx, fit in zip(contexts(session, inst), res.instruments[inst].sensors):
        X, y = [], []
        for seg in session.segments:
            x = model.design(seg, ctx)
            if x is not None:
                X.append(x)
                y.append(seg.raw[inst][:, ctx.index])
        beta, *_ = np.linalg.lstsq(np.vstack(X), np.concatenate(y), rcond=None)
        assert _rel(fit.beta, beta) < 1e-10
        r = np.concatenate(y) - np.vstack(X) @ beta
        assert fit.rss == pytest.approx(float(r @ r), rel=1e-6)


def test_generic_path_with_per_sample_force(session):
    """A segment whose specific force is given sample by sample takes the per-sample path: same estimate as the
    generic design path (fit_lsq)."""
    segs = list(session.segments)
    s0 = next(s for s in segs if s.kind == "rate")
    f = s0.specific_force(session.gravity).copy()
    segs[segs.index(s0)] = Segment("given", "rate", s0.t, s0.raw, specific_force_mb=f, rate_mb=s0.rate_mb,
                                   mat_ln_mb=s0.mat_ln_mb)
    s = Session(segs, session.geometries, session.sample_rate, session.latitude, session.gravity)
    a = LeastSquares(sigma={"accel": 1.0}, instruments=["accel"]).fit(s)
    b = fit_lsq(s, ErrorModel.base(), "accel", sigma=1.0)
    for fa, fb in zip(a.instruments["accel"].sensors, b.sensors):
        assert _rel(fa.beta, fb.beta) < 1e-10


def test_oliveira_earth_rate_means_equal_per_sample_means():
    """de Oliveira's Eq. 20 with the Earth rate: the per-sequence mean Earth rate from the rotation moments gives
    the biases of the per-sample means (the straightforward Eq. 20, written out here)."""
    run = Simulator({"gyro": tetrad4(), "accel": triad3()}, latitude_deg=-23.2, seed=2).run(oliveira_table1(turns=1))
    s = run.session
    res = Oliveira().fit(s)
    seqs = [x for x in s.segments if x.kind == "rate"]
    N = np.array([x.n_samples for x in seqs], float)
    for fit in res.instruments["gyro"].sensors:
        i = fit.ctx.index
        w = fit.beta[:3]
        u = np.array([x.table_rate() + x.earth_rate(s.latitude).mean(axis=0) for x in seqs])  # per sample
        ybar = np.array([x.raw["gyro"][:, i].mean() for x in seqs])
        c = (N @ ybar) / N.sum() - w @ ((N @ u) / N.sum())
        assert fit.beta[3] == pytest.approx(c, rel=1e-11, abs=1e-12 * abs(ybar).max())


def test_statistics_are_read_afresh_by_each_fit(session):
    """The statistics live for one fit: samples changed in place between two fits are seen by the second."""
    segs = [Segment(x.label, x.kind, x.t, {k: v.copy() for k, v in x.raw.items()}, x.temperature,
                    x.specific_force_mb, x.rate_mb, x.angle_mb, x.mat_ln_mb) for x in session.segments]
    s = Session(segs, session.geometries, session.sample_rate, session.latitude, session.gravity)
    before = ChoPark().fit(s).values("accel")
    for seg in s.segments:
        seg.raw["accel"] *= 2.0  # every raw output doubled: every scale factor halves
    after = ChoPark().fit(s).values("accel")
    for name, v in before.items():
        if name.endswith(".scale"):
            assert after[name] == pytest.approx(v / 2, rel=1e-12)


@pytest.mark.parametrize("earth", [True, False])
def test_the_known_input_forms_are_the_contexts_input(session, earth):
    """``_known_input`` (no rotation per sample on static segments) and ``_input_form`` (a constant, or the
    [1, cos, sin] basis on turning segments) are ``SensorContext.input`` sample by sample, with the Earth rate
    in the gyro input or left out (``include_earth_rate=False``, as the diagnosis' --no-earth-rate), on static
    and turning segments alike."""
    from rimu.calibration.estimate import _input_form, _known_input

    n_static = 0
    for inst in ("gyro", "accel"):
        ctx = contexts(session, inst, include_earth_rate=earth)[0]
        for seg in session.segments:
            want = ctx.input(seg)
            if want is None:
                continue
            n_static += seg.kind == "static" and inst == "gyro"
            assert np.max(np.abs(_known_input(ctx, seg) - want)) <= 1e-15 * max(1.0, np.abs(want).max())
            kind, u = _input_form(ctx, seg)
            if kind == "constant":
                got = np.broadcast_to(u, want.shape)
            elif kind == "basis":
                th = np.linalg.norm(seg.table_rate()) * (seg.t - seg.t[0])
                got = np.column_stack([np.ones_like(th), np.cos(th), np.sin(th)]) @ u
            else:
                got = u
            assert np.max(np.abs(got - want)) <= 1e-12 * max(1.0, np.abs(want).max()), (inst, seg.label, kind)
    assert n_static >= 10


@pytest.mark.parametrize("latitude", [None, 45.0])
def test_the_fits_input_forms_are_input_form(latitude):
    """``_input_forms`` (the base fit's forms of every segment, the common cases without a context) gives what
    ``_input_form`` of the nominal context gives, array for array: on a Cho & Park session (static and turning
    segments with known attitude), a Ferraris-style session (static positions and turns of known angle) and imucal's
    real recording (known specific forces, turns without attitude), with and without a known latitude."""
    from rimu.calibration.estimate import _input_form, _input_forms
    from rimu.sim import rotation, static
    from rimu.units import DEG_TO_RAD

    fer = [static(k, up, 1.0) for k, up in (("x_p", (1, 0, 0)), ("z_a", (0, 0, -1)))]
    fer.append(rotation("z_rot", np.array([0, 0, 36.0]) * DEG_TO_RAD, 10.0, report="angle"))
    sessions = [Simulator(latitude_deg=latitude, seed=5).run(cho_park_procedure(duration=0.5)).session,
                Simulator(latitude_deg=latitude, seed=6).run(fer).session]
    from rimu.session import load_ferraris
    from tests.conftest import shared_data

    sessions.append(load_ferraris(shared_data("imucal_ferraris_session", "example_ferraris_session.csv")))
    for s in sessions:
        for inst in s.instruments:
            ctx = contexts(s, inst)[0]
            for seg, (kind, u) in zip(s.segments, _input_forms(s, inst, s.segments)):
                want_kind, want_u = _input_form(ctx, seg)
                assert kind == want_kind, (inst, seg.label)
                if want_u is None:
                    assert u is None
                else:
                    np.testing.assert_array_equal(u, want_u, err_msg=f"{inst} {seg.label}")
