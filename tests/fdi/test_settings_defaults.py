"""One default per setting: every consumer of the fault management's settings takes rimu.fdi.FdiSettings' defaults
(the manager, the runtime, the C export, validate, the campaigns, the scenarios, the detector factory, and the
command line options of monitor, replay, demo, campaign and export-c)."""

from __future__ import annotations

import argparse
import inspect
from dataclasses import fields

from rimu.calibration import InstrumentCalibration
from rimu.cli import build_parser
from rimu.cli._common import FDI_HELP_DEFAULTS, fdi_settings
from rimu.cli.export_c import fdi_settings as export_settings
from rimu.experiments.campaign import CampaignSpec
from rimu.experiments.scenarios import ScenarioSpec
from rimu.experiments.validate import validate
from rimu.fdi import FdiSettings, RedundancyManager, Runtime
from rimu.fdi.detectors import make_detector
from rimu.fdi.settings import DEFAULTS
from rimu.fusion import InstrumentPipeline
from rimu.geometry import cone6


def _defaults(fn) -> dict:
    return {k: p.default for k, p in inspect.signature(fn).parameters.items() if p.default is not p.empty}


def test_the_settings_object_has_the_documented_defaults():
    d = DEFAULTS
    # the manager's documented design (docs/fdi.md): GLT at 1e-3 per sample, 3 confirmations, the set test at 1e-4
    assert (d.p_fa, d.confirm, d.alpha, d.readmit_after, d.invalid_persist) == (1e-3, 3, 1e-4, 100, 10)
    assert d == FdiSettings()
    assert "1e-4" in RedundancyManager.__doc__ and "1e-6)" not in RedundancyManager.__doc__


def test_every_python_consumer_takes_the_one_default():
    m = _defaults(RedundancyManager.__init__)
    for f in fields(FdiSettings):
        if f.name in m:
            assert m[f.name] == getattr(DEFAULTS, f.name), ("RedundancyManager", f.name)
    assert {"p_fa", "confirm", "invalid_persist", "readmit_after", "fail_after", "backoff", "clear_after",
            "episode_gap"} <= set(m)
    v = _defaults(validate)
    assert (v["p_fa"], v["confirm"], v["readmit_after"]) == (DEFAULTS.p_fa, DEFAULTS.confirm, DEFAULTS.readmit_after)
    c, s = CampaignSpec(), ScenarioSpec()
    assert (c.p_fa, c.confirm) == (DEFAULTS.p_fa, DEFAULTS.confirm)
    assert (s.p_fa, s.confirm, s.readmit_after) == (DEFAULTS.p_fa, DEFAULTS.confirm, DEFAULTS.readmit_after)
    assert _defaults(make_detector)["p_fa"] == DEFAULTS.p_fa
    # the manager built without settings, and the runtime's, decide with the defaults (the set test's alpha too)
    cal = InstrumentCalibration.nominal("gyro", cone6(), 1.0, noise_sigma=0.01)
    mgr = RedundancyManager(InstrumentPipeline(cal))
    assert (mgr.p_fa, mgr.confirm, mgr.readmit_after, mgr.isolator.alpha) == (
        DEFAULTS.p_fa, DEFAULTS.confirm, DEFAULTS.readmit_after, DEFAULTS.alpha)
    from rimu.calibration import Calibration

    rt = Runtime(Calibration({"gyro": cal}))
    g = rt.managers["gyro"]
    assert rt.settings == DEFAULTS and (g.confirm, g.isolator.alpha, g.isolator.max_size) == (
        DEFAULTS.confirm, DEFAULTS.alpha, DEFAULTS.max_size)


def test_every_command_takes_the_one_default():
    parser = build_parser()
    base = {"monitor": ["--simulate"], "replay": ["d.npz", "--calibration", "c.json"], "demo": [],
            "campaign": [], "export-c": ["c.json", "-o", "out"]}
    for cmd, argv in base.items():
        args = parser.parse_args([cmd, *argv])
        assert args.p_fa is None and args.confirm is None, cmd          # not restated: resolved to the one default
        st = export_settings(args) if cmd == "export-c" else fdi_settings(args)
        assert (st.p_fa, st.confirm) == (DEFAULTS.p_fa, DEFAULTS.confirm), cmd
        assert st == (DEFAULTS if cmd != "export-c" else DEFAULTS.replace(readmit_after=st.readmit_after)), cmd
        given = parser.parse_args([cmd, *argv, "--confirm", "7", "--p-fa", "1e-4"])
        st = export_settings(given) if cmd == "export-c" else fdi_settings(given)
        assert (st.p_fa, st.confirm) == (1e-4, 7), cmd
    # the help texts state the one default
    assert float(FDI_HELP_DEFAULTS["p_fa"]) == DEFAULTS.p_fa and int(FDI_HELP_DEFAULTS["confirm"]) == DEFAULTS.confirm
    ns = argparse.Namespace(p_fa=None, confirm=None)
    assert fdi_settings(ns) == DEFAULTS and (ns.p_fa, ns.confirm) == (DEFAULTS.p_fa, DEFAULTS.confirm)
