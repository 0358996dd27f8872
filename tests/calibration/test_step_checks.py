"""Every estimator checks its misalignment steps on held-out segments (issue 27), through one mechanism
(:mod:`rimu.calibration.steps`): Cho & Park (each static position, each +/- rate pair left out), de Oliveira (each
+/- pair), Zhang (each static position, each CW/CCW pair). On a truth that contains misalignment the step is applied
and lowers the held-out residual; on a nominal truth with few segments and much noise it raises the held-out
residual and is refused, the axes stay nominal, and the note says why with the figures in their unit.
"""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np

from rimu.calibration.cho_park import ChoPark
from rimu.calibration.oliveira import Oliveira
from rimu.calibration.steps import StepCheck
from rimu.calibration.zhang import Zhang
from rimu.geometry import tetrad4, triad3
from rimu.sim import Simulator, cho_park_procedure, oliveira_table1, zhang_scheme
from rimu.sim.procedures import CHO_PARK_TABLE2, rotation, static
from rimu.sim.truth import cho_park_table3, default_truth
from rimu.units import DEG_TO_RAD, FIELD_UNITS


def _nominal(truth, geometries):
    """The truth with every misalignment removed (each sensor on its nominal axis)."""
    return dataclasses.replace(truth, instruments_cal={
        k: dataclasses.replace(v, misalignment=geometries[k].nominal_rows()) for k, v in truth.instruments_cal.items()})


_UNITS = {u: f for q in ("specific_force", "rate", "angle") for u, f in FIELD_UNITS[q]}


def _figures(note: str) -> list[float]:
    """The four figures of a step note, back in SI."""
    pat = "|".join(re.escape(u) for u in sorted(_UNITS, key=len, reverse=True))
    return [float(v) / _UNITS[u] for v, u in re.findall(rf"(-?[\d.e+-]+) ({pat})(?=[ ,;]|$)", note)]


def _check(res, inst: str) -> tuple[dict, str]:
    step = next(s for s in res.extra["steps"] if s["instrument"] == inst)
    note = next(n for n in res.notes if n.startswith(f"{inst}: the misalignment step"))
    # the note's figures are the check's, in the unit it states
    np.testing.assert_allclose(_figures(note), step["in_sample"] + step["held_out"], rtol=1e-3)
    assert ("not applied" in note) is (not step["applied"]), note
    return step, note


def _cho_park_doubled(duration: float):
    """Cho & Park's Tables 1 and 2, the rate test twice (each +/- pair about an axis has a twin to leave out)."""
    rate = 30.0 * DEG_TO_RAD
    return cho_park_procedure(rate, duration) + [rotation(f"R{k}b", np.array(r) * rate, duration)
                                                 for k, r in enumerate(CHO_PARK_TABLE2, start=1)]


def test_the_note_rule_and_units():
    c = StepCheck("gyro", "misalignment", "scale alone", "rate", (2e-4, 1e-4), (3e-4, 2.9e-4), "pairs", "nominal")
    assert c.applied and "not applied" not in c.note()
    np.testing.assert_allclose(_figures(c.note()), [2e-4, 1e-4, 3e-4, 2.9e-4], rtol=1e-3)
    worse = dataclasses.replace(c, held_out=(3e-4, 3.1e-4))
    assert not worse.applied and worse.note().endswith("not the sensor): nominal")


def test_cho_park_applies_the_steps_of_a_misaligned_unit_and_refuses_them_on_a_nominal_one():
    run = Simulator(seed=1).run(_cho_park_doubled(2.0))  # truth: Cho & Park Table 3 (misaligned, ~mrad)
    res = ChoPark().fit(run.session)
    for inst in ("accel", "gyro"):   # held out: 12.55 -> 0.146 mg, 916.3 -> 109.8 deg/h
        step, note = _check(res, inst)
        assert step["applied"] and step["held_out"][1] < 0.5 * step["held_out"][0], note
        assert step["in_sample"][1] <= step["in_sample"][0]
    # the paper's procedure (one pair per axis) cannot leave a pair out: said so, the step kept
    paper = ChoPark().fit(Simulator(seed=1).run(cho_park_procedure(duration=2.0)).session)
    assert any(n.startswith("gyro: the misalignment step could not be checked") for n in paper.notes)
    g = run.truth["gyro"].geometry
    run = Simulator(truth=_nominal(cho_park_table3(g), {"gyro": g, "accel": g}), seed=3, vrw_ug_sqrt_hz=20000.0,
                    arw_deg_sqrt_h=300.0).run(_cho_park_doubled(1.0))
    res = ChoPark().fit(run.session)
    cal = res.to_calibration()
    for inst in ("accel", "gyro"):   # held out: 22.39 -> 23.85 mg, 3.19 -> 3.664 deg/s
        step, note = _check(res, inst)
        assert not step["applied"] and step["held_out"][1] > step["held_out"][0], note
        np.testing.assert_allclose(cal[inst].misalignment, run.truth[inst].geometry.nominal_rows(), atol=1e-12)


def test_oliveira_applies_the_step_of_a_misaligned_tetrad_and_refuses_it_on_a_nominal_one():
    geo = {"gyro": tetrad4(), "accel": triad3()}
    res = Oliveira().fit(Simulator(geo, seed=1).run(oliveira_table1(turns=1)).session)
    step, note = _check(res, "gyro")
    assert step["applied"] and step["held_out"][1] < step["held_out"][0], note   # held out 33.91 -> 22.37 deg/h
    truth = _nominal(default_truth(geo, 1), geo)
    run = Simulator(geo, truth=truth, seed=1).run(oliveira_table1(turns=1))
    res = Oliveira().fit(run.session)
    step, note = _check(res, "gyro")
    assert not step["applied"] and step["held_out"][1] > step["held_out"][0], note   # held out 20.59 -> 22.37 deg/h
    np.testing.assert_allclose(res.to_calibration()["gyro"].misalignment, geo["gyro"].nominal_rows(), atol=1e-12)


def _zhang_more(static_s: float = 5.0):
    """Zhang's scheme with three more static positions and three more CW/CCW pairs (12 and 9: one can be left out)."""
    out = zhang_scheme(static_duration=static_s, rotation_duration=36.0)
    r = math.sqrt(0.5)
    out += [static(f"A{k}", u, static_s, report="static_unknown")
            for k, u in enumerate([(-r, r, 0), (r, 0, -r), (0, -r, r)], start=10)]
    for k, a in enumerate([(r, -r, 0), (r, 0, -r), (0, r, -r)], start=7):
        for sgn, tag in ((1, "cw"), (-1, "ccw")):
            spec = rotation(f"W{k}{tag}", sgn * 10 * DEG_TO_RAD * np.array(a), 36.0, axis_direction_ln=(0, 1, 0),
                            report="angle")
            spec.meta["pair"] = k
            out.append(spec)
    return out


def test_zhang_applies_the_steps_of_a_misaligned_triad_and_refuses_them_on_a_nominal_one():
    g = triad3()
    geo = {"gyro": g, "accel": g}
    res = Zhang().fit(Simulator(geo, arw_deg_sqrt_h=0.01, seed=0).run(_zhang_more()).session)
    for inst in ("accel", "gyro"):   # held out: 994.6 -> 128.2 ug, 0.3768 -> 0.0017 deg
        step, note = _check(res, inst)
        assert step["applied"] and step["held_out"][1] < 0.5 * step["held_out"][0], note
    run = Simulator(geo, truth=_nominal(default_truth(geo, 0), geo), arw_deg_sqrt_h=0.3, vrw_ug_sqrt_hz=2000.0,
                    seed=2).run(_zhang_more())
    res = Zhang().fit(run.session)
    cal = res.to_calibration()
    np.testing.assert_allclose(cal["accel"].misalignment, np.eye(3), atol=1e-12)
    for inst in ("accel", "gyro"):   # held out: 1.30 -> 2.04 mg, 307 -> 449 arcsec
        step, note = _check(res, inst)
        assert not step["applied"] and step["held_out"][1] > step["held_out"][0], note
    # the gyro axes are the nominal ones turned by the inter-triad rotation alone (orthonormal rows)
    M = cal["gyro"].misalignment
    np.testing.assert_allclose(M @ M.T, np.eye(3), atol=1e-9)
    # the paper's scheme (9 positions, 6 pairs) leaves nothing to hold out: said so, the steps kept
    paper = Zhang().fit(Simulator(geo, arw_deg_sqrt_h=0.01, seed=2).run(
        zhang_scheme(static_duration=5.0, rotation_duration=36.0)).session)
    assert sum(n.endswith("leaves it unidentifiable); applied") for n in paper.notes) == 2


def test_the_console_and_the_report_say_the_same(tmp_path, capsys):
    """`rimu calibrate --method oliveira` on the nominal tetrad: the refusal note, word for word, on the console and
    in the report's cautions."""
    import html

    from rimu.cli import main
    from rimu.session import save_session

    geo = {"gyro": tetrad4(), "accel": triad3()}
    run = Simulator(geo, truth=_nominal(default_truth(geo, 1), geo), seed=1).run(oliveira_table1(turns=1))
    save_session(run.session, tmp_path / "s.npz")
    assert main(["calibrate", str(tmp_path / "s.npz"), "--method", "oliveira", "-o", str(tmp_path / "c.json"),
                 "--report", str(tmp_path / "rep")]) == 0
    out = capsys.readouterr().out
    line = next(x.strip() for x in out.splitlines() if "gyro: the misalignment step" in x)
    assert "not applied" in line
    page = next((tmp_path / "rep").glob("*.html")).read_text()
    assert html.escape(line.removeprefix("note: ")) in page or line.removeprefix("note: ") in page
