"""For every effect of the library: hidden in a simulated session, absent from the starting model, the
diagnosis ranks it first on the right sensors; adding it brings chi2/dof into [0.8, 1.25] and recovers its
parameters within 3 sigma of the truth."""

import numpy as np
import pytest
from scenarios import SCENARIOS, simulate, known_sigma

from rimu.calibration.diagnostics import diagnose

CASES = [(e, g, 0) for e in SCENARIOS for g in ("cone6", "tetrad4", "triad3")]
CASES += [(e, "cone6", s) for e in SCENARIOS for s in (1, 2)]


@pytest.mark.parametrize("name,geometry,seed", CASES)
def test_hidden_effect_found_and_recovered(name, geometry, seed):
    run, truth, sc = simulate(name, geometry, seed=seed)
    inst = sc.instrument
    d = diagnose(run.session, sigma={inst: known_sigma(run, inst)}, **sc.diagnose)
    idg = d[inst]
    assert not idg.nothing_missing
    first = idg.findings[0]
    assert first.effects == [name], idg.lines()
    names = run.session.geometries[inst].names
    assert set(idg.test(name).detected_sensors()) == {names[i] for i in truth}
    comp = d.add(name, instrument=inst)[inst]
    assert comp.chi2_before > comp.chi2_after
    assert 0.8 <= comp.chi2_after <= 1.25
    eff = comp.after.model.effects[-1]
    assert eff.name == name
    for i, th in truth.items():
        s = comp.after.sensors[i]
        for p, v in zip(eff.physical_parameters(s.ctx), th):
            val, sd, _ = s.parameter(p.name)
            assert abs(val - v) <= 3 * sd, (s.name, p.name, val, v, sd)
    # the sensors without the effect: their new parameters are consistent with zero
    others = [s for k, s in enumerate(comp.after.sensors) if k not in truth and eff.applies_to(s.ctx)]
    z = [s.parameter(p.name)[0] / s.parameter(p.name)[1] for s in others for p in eff.physical_parameters(s.ctx)]
    assert all(abs(x) < 4.5 for x in z), z
