"""Test design: Cho & Park Eq. 19 and Fig. 3, identifiability before any fit, greedy D-optimal selection."""

from __future__ import annotations

import numpy as np
import pytest

from rimu.calibration import ChoPark
from rimu.calibration.design import (
    ProcedureInputs,
    eq19,
    fig3_curve,
    greedy_d_optimal,
    log_det_information,
    predicted_std,
    procedure_inputs,
    turntable_candidates,
)
from rimu.errors import IdentifiabilityError
from rimu.geometry import cone6, tetrad4, triad3
from rimu.sim import Simulator, cho_park_procedure, cho_park_table1, zhang_scheme
from rimu.sim.procedures import CHO_PARK_TABLE1, CHO_PARK_TABLE2
from rimu.units import G0

T2 = np.array(CHO_PARK_TABLE2)
PAIRS = T2[0::2] - T2[1::2]


def test_eq19_predicts_the_estimator_covariance():
    """The design's prediction equals the covariance ChoPark reports after the fit (same noise; zero-bias
    truth so the physical bias does not inherit the scale uncertainty)."""
    sim = Simulator(seed=2)
    truth = sim.truth_calibration()
    from rimu.calibration import Calibration, InstrumentCalibration

    t0 = Calibration({k: InstrumentCalibration(k, c.geometry, c.scale, c.misalignment, np.zeros(6))
                      for k, c in ((k, truth[k]) for k in ("gyro", "accel"))})
    sim = Simulator(truth=t0, seed=2, latitude_deg=None)
    run = sim.run(cho_park_procedure(duration=20.0))
    sig = {k: sim.noise_sigma(k) / t0[k].scale for k in ("gyro", "accel")}
    res = ChoPark(sigma=sig).fit(run.session)
    pred = predicted_std(cone6(), procedure_inputs(cho_park_procedure()), sim.noise_sigma("accel"),
                         sim.noise_sigma("gyro"), 2000)
    for inst in ("accel", "gyro"):
        got = res.std(inst)
        for name, p in pred[inst].items():
            g = got[name] / (res.values(inst)[name] if name.endswith(".scale") else 1.0)
            assert abs(g / p - 1) < 0.03, (inst, name, g, p)


def test_fig3_standard_deviation_decreases_with_sequences():
    c = fig3_curve(cone6(), np.array(CHO_PARK_TABLE1), PAIRS)
    # Table 1's first four positions are coplanar: five are the first identifying set
    assert c["static_k"][0] == 5 and c["rate_k"][0] == 3
    for key in ("static_mis", "static_bias", "rate_mis"):
        d = np.diff(c[key], axis=0)
        assert np.all(d <= 1e-12), key
    # closed form for the first three orthogonal pairs: R = 2 I, (R^T R)^-1 = I/4 in the sub-unit basis
    assert np.allclose(c["rate_mis"][0], 0.5)


def test_three_static_positions_refused_before_fit():
    inp = procedure_inputs(cho_park_table1(positions=[1, 2, 5]))
    with pytest.raises(IdentifiabilityError) as exc:
        eq19(cone6(), ProcedureInputs(inp.forces, PAIRS), 0)
    assert exc.value.parameters and "cannot identify" in str(exc.value)


def test_greedy_d_optimal_beats_or_matches_the_papers():
    U, A = turntable_candidates()
    for geo in (cone6(), tetrad4(), triad3()):
        sel = greedy_d_optimal(geo, U, 10, "static")
        ld_greedy = log_det_information(geo, ProcedureInputs(U[sel] * G0, np.zeros((0, 3))), "static")
        ld_t1 = log_det_information(geo, ProcedureInputs(np.array(CHO_PARK_TABLE1) * G0, np.zeros((0, 3))), "static")
        assert ld_greedy >= ld_t1 - 1e-9
        z = procedure_inputs(zhang_scheme())
        sel9 = greedy_d_optimal(geo, U, 9, "static")
        assert log_det_information(geo, ProcedureInputs(U[sel9] * G0, np.zeros((0, 3))), "static") >= \
            log_det_information(geo, ProcedureInputs(z.forces, np.zeros((0, 3))), "static") - 1e-9
        selr = greedy_d_optimal(geo, A, 7, "rate")
        assert log_det_information(geo, ProcedureInputs(np.zeros((0, 3)), 2 * A[selr]), "rate") >= \
            log_det_information(geo, ProcedureInputs(np.zeros((0, 3)), PAIRS), "rate") - 1e-9
    # the D-criterion does not depend on the sub-unit bases (orthonormal): same choice for every geometry
    assert greedy_d_optimal(cone6(), U, 6, "static") == greedy_d_optimal(triad3(), U, 6, "static")
