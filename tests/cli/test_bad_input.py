"""The bad-input battery: every subcommand, fed the mistakes real users make, ends in one clear line.

For every case: the exit status (2 bad input, 1 a check that ran and failed), no Python traceback anywhere in the
output, exactly one error line on stderr, and the message names the problem. The generic cases iterate over the
registered subcommands (``rimu.cli.COMMANDS``), so a subcommand added later is covered by them at once; the
per-command table (``MINIMAL``, ``CASES``) is extended by hand when one is added (a test fails until it is).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rimu.cli import _common as common
from rimu.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------ files, made once
@pytest.fixture(scope="module")
def f(tmp_path_factory) -> dict[str, str]:
    d = tmp_path_factory.mktemp("bad")
    q = ["-q"]
    assert main(["simulate", "--duration", "3", "-o", str(d / "s.npz"), "--truth", str(d / "truth.json")] + q) == 0
    assert main(["simulate", "--duration", "3", "-o", str(d / "s.csv")] + q) == 0
    assert main(["calibrate", str(d / "s.npz"), "-o", str(d / "cal.json")] + q) == 0
    assert main(["simulate", "--duration", "3", "--geometry", "triad3", "-o", str(d / "tri.npz")] + q) == 0
    assert main(["calibrate", str(d / "tri.npz"), "-o", str(d / "trical.json")] + q) == 0
    assert main(["simulate", "--duration", "3", "--geometry", "dodecahedron6", "-o", str(d / "dd.npz")] + q) == 0
    assert main(["calibrate", str(d / "dd.npz"), "-o", str(d / "ddcal.json")] + q) == 0
    z = dict(np.load(d / "s.npz"))
    (d / "empty.npz").write_bytes(b"")
    (d / "trunc.npz").write_bytes((d / "s.npz").read_bytes()[:3000])
    (d / "text.npz").write_text("this is not an archive\n")
    np.save(d / "array.npy", np.zeros(3))
    os.replace(d / "array.npy", d / "array.npz")
    np.savez(d / "nometa.npz", **{k: v for k, v in z.items() if k != "meta"})
    np.savez(d / "zerogyro.npz", **dict(z, raw_gyro=np.zeros_like(z["raw_gyro"])))
    t = z["t"].copy()
    t[[100, 101]] = t[[101, 100]]
    np.savez(d / "nonmono.npz", **dict(z, t=t))
    g = z["raw_gyro"].copy()
    g[42, 3] = np.nan
    np.savez(d / "nan.npz", **dict(z, raw_gyro=g))
    np.savez(d / "shape.npz", **dict(z, raw_gyro=z["raw_gyro"][:, :5]))
    meta = json.loads(str(z["meta"]))
    np.savez(d / "rate.npz", **dict(z, meta=np.array(json.dumps(dict(meta, sample_rate_hz=250.0)))))
    np.savez(d / "units.npz", **dict(z, meta=np.array(json.dumps(dict(meta, raw_unit={"accel": "g"})))))
    # CSV mistakes
    (d / "nosidecar.csv").write_text((d / "s.csv").read_text())
    (d / "badjson.csv").write_text((d / "s.csv").read_text())
    (d / "badjson.json").write_text("{ not json")
    side = json.loads((d / "s.json").read_text())
    lines = (d / "s.csv").read_text().splitlines(keepends=True)
    cells = lines[3].split(",")
    cells[3] = "abc"
    for name, body in {"garbage": lines[:5] + ["#### garbage line ####\n"] + lines[5:],
                       "label": lines[:3] + [lines[3].replace(",P1,", ",P99,")] + lines[4:],
                       "cell": lines[:3] + [",".join(cells)] + lines[4:]}.items():
        (d / f"{name}.csv").write_text("".join(body))
        (d / f"{name}.json").write_text(json.dumps(dict(side, data=f"{name}.csv")))
    (d / "folder").mkdir()
    # calibration mistakes
    (d / "notjson.json").write_text("no json here")
    (d / "emptycal.json").write_text("")
    text = (d / "cal.json").read_text()
    i = text.index('"scale"') + 20
    digit = next(k for k in range(i, len(text)) if text[k] in "123456789")
    (d / "tampered.json").write_text(text[:digit] + ("2" if text[digit] != "2" else "3") + text[digit + 1:])
    (d / "afile").write_text("x")
    out = {}
    for p in d.iterdir():
        plain = p.suffix in (".npz", "") or (p.suffix == ".json" and not p.with_suffix(".npz").exists())
        out[p.stem if plain else f"{p.stem}_{p.suffix[1:]}"] = str(p)
    out.update(dir=str(d), s_csv=str(d / "s.csv"))
    return out


def run(argv: list[str], capsys) -> tuple[int, str, str]:
    code = main(argv)
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err, (argv, err)
    return code, out, err


def assert_one_error(err: str, command: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ": error:" in ln]
    assert len(errors) == 1, err
    assert errors[0].startswith(f"rimu {command}: error:") or errors[0].startswith("rimu: error:"), err
    return errors[0]


# ------------------------------------------------------------------ generic cases, every registered subcommand
def _subparsers() -> dict[str, argparse.ArgumentParser]:
    p = build_parser()
    sub = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


#: every registered subcommand, by its command-line name
COMMANDS = sorted(_subparsers())


#: an invocation that gets past argument parsing, per subcommand ({name} = a file of the fixture)
MINIMAL = {
    "demo": [],
    "simulate": ["--duration", "1"],
    "calibrate": ["{s}"],
    "design": [],
    "diagnose": ["{s}"],
    "monitor": ["--npz", "{s}", "--calibration", "{cal}"],
    "replay": ["{s}", "--calibration", "{cal}"],
    "campaign": ["--workers", "0", "--repetitions", "1", "--sizes", "6", "--duration", "1", "--fault-start", "0.5"],
    "check": ["{s}", "--calibration", "{cal}"],
    "export-c": ["{cal}", "-o", "{dir}/export"],
    "detect": ["{s}", "-o", "{dir}/detected.npz"],
    "array": ["{s}"],
    "noise": ["{s}", "--calibration", "{cal}", "-o", "{dir}/noise.json"],
    "import": ["{s}", "-o", "{dir}/rec.npz"],
    "setup": ["{s}", "-o", "{dir}/setupcal.json"],
    "apply": ["{s}", "--calibration", "{cal}", "-o", "{dir}/applied.npz"],
    "selfcal": ["{s}", "--calibration", "{cal}", "-o", "{dir}/selfcal.json"],
}

_VALIDATORS = {common.positive_float: ["0", "-1", "nan", "abc"], common.finite_float: ["nan", "inf", "x"], common.nonnegative_float: ["-1", "inf", "x"],
               common.probability: ["0", "1", "1.5", "-0.1", "p"], common.positive_int: ["0", "-3", "2.5", "x"],
               common.nonnegative_int: ["-1", "x"]}


def test_every_registered_command_has_a_minimal_invocation():
    from rimu.cli import COMMANDS as MODULES

    assert len(COMMANDS) == len(MODULES)
    missing = sorted(set(COMMANDS) - set(MINIMAL))
    assert not missing, f"add a MINIMAL invocation (and CASES) for {missing}"


@pytest.mark.parametrize("command", COMMANDS)
def test_unknown_option_and_help(command, f, capsys):
    base = [a.format(**f) for a in MINIMAL.get(command, [])]
    code, _, err = run([command, *base, "--no-such-option"], capsys)
    assert code == 2 and "--no-such-option" in assert_one_error(err, command)
    assert run([command, "--help"], capsys)[0] == 0


@pytest.mark.parametrize("command", COMMANDS)
def test_validated_options_refuse_out_of_range_values(command, f, capsys):
    """Every option declared with one of the validators refuses its bad values before any work, naming it."""
    p = _subparsers()[command]
    base = [a.format(**f) for a in MINIMAL.get(command, [])]
    n = 0
    for action in p._actions:
        bad = _VALIDATORS.get(action.type)
        if not bad or not action.option_strings:
            continue
        for value in bad:
            code, _, err = run([command, *base, action.option_strings[-1], value], capsys)
            line = assert_one_error(err, command)
            assert code == 2 and action.option_strings[-1] in line, (action.option_strings, value, err)
            n += 1
    if command not in ("demo",):
        assert n or command in MINIMAL, command


@pytest.mark.parametrize("command", COMMANDS)
def test_output_paths_are_checked_before_any_work(command, f, capsys):
    """-o, --json and --report that cannot be written are refused before the command starts."""
    p = _subparsers()[command]
    opts = {o for a in p._actions for o in a.option_strings}
    base = [a.format(**f) for a in MINIMAL[command]]
    tried = 0
    for opt in ("-o", "--json", "--report"):
        if opt not in opts:
            continue
        for target in (os.path.join(f["afile"], "x.json"), os.path.join(f["dir"], "missing", "deeper", "x.json")):
            is_dir = opt == "--report" or (opt == "-o" and p.get_default("output_is_dir"))
            if is_dir and "missing" in target:
                continue  # a report (or output) folder is created with its parents
            code, _, err = run([command, *base, opt, target], capsys)
            line = assert_one_error(err, command)
            assert code == 2 and ("not a folder" in line or "does not exist" in line or "is a file" in line), err
            tried += 1
    assert tried or not (opts & {"-o", "--json", "--report"})


# ------------------------------------------------------------------ the table: malformed files and option values
#: (command and arguments, exit status, words the one error line must contain)
CASES = [
    # logs (rimu.io.formats): not a log, a session given where a log is needed, counts never taken as SI
    (["import", "{text}", "-o", "{dir}/r.npz"], 2, ["text.npz", "--format"]),
    (["import", "{dir}/missing.bin", "-o", "{dir}/r.npz"], 2, ["missing.bin"]),
    (["setup", "{s}", "-o", "{dir}/c.json"], 2, ["s.npz"]),
    (["apply", "{s}", "--calibration", "{cal}", "-o", "{dir}/a.npz"], 2, ["s.npz", "counts"]),
    (["noise", "{dir}/missing.npz"], 2, ["missing.npz"]),
    (["noise", "{s}"], 2, ["scale factors", "--calibration"]),
    (["noise", "{s}", "--calibration", "{cal}", "--p-fa", "2"], 2, ["--p-fa"]),
    (["selfcal", "{dir}/missing.npz", "--calibration", "{cal}", "-o", "{dir}/o.json"], 2, ["missing.npz"]),
    (["selfcal", "{s}", "--calibration", "{cal}", "-o", "{dir}/o.json"], 2, ["noise model", "--bias-rw"]),
    (["selfcal", "{s}", "--calibration", "{cal}", "-o", "{dir}/o.json", "--gate", "1"], 2, ["--gate"]),
    # detect and array (raw recordings, array NPZ)
    (["detect", "{dir}/missing.csv", "-o", "{dir}/o.npz"], 2, ["missing.csv", "does not exist"]),
    (["detect", "{text}", "-o", "{dir}/o.npz"], 2, ["text.npz"]),
    (["detect", "{s}", "-o", "{dir}/o.npz", "--window", "-1"], 2, ["--window"]),
    (["array", "{dir}/missing.npz"], 2, ["missing.npz"]),
    (["array", "{text}"], 2, ["text.npz", "NPZ"]),
    (["array", "{s}", "--motion-threshold-deg-s", "0"], 2, ["--motion-threshold-deg-s"]),
    # session files
    (["calibrate", "{empty}"], 2, ["empty.npz", "not a readable NPZ"]),
    (["calibrate", "{trunc}"], 2, ["trunc.npz", "truncated"]),
    (["calibrate", "{text}"], 2, ["text.npz", "not a readable NPZ"]),
    (["calibrate", "{array}"], 2, ["array.npz", "not an .npz archive"]),
    (["calibrate", "{nometa}"], 2, ["no 'meta'"]),
    (["calibrate", "{zerogyro}"], 2, ["gyro_x1", "constant"]),
    (["calibrate", "{zerogyro}", "--accept-implausible"], 2, ["does not respond", "dead sensor"]),
    (["calibrate", "{nonmono}"], 2, ["t[101]", "does not increase"]),
    (["calibrate", "{nan}"], 2, ["raw_gyro row 42", "'x2'", "not finite"]),
    (["calibrate", "{shape}"], 2, ["raw_gyro", "shape", "(7200, 6)"]),
    (["calibrate", "{rate}"], 2, ["sample_rate_hz is 250 Hz", "100 Hz", "--accept-implausible"]),
    (["calibrate", "{units}"], 2, ["accel", "declared in 'g'"]),
    (["calibrate", "{nosidecar_csv}"], 2, ["nosidecar.json is missing"]),
    (["calibrate", "{badjson_csv}"], 2, ["badjson.json", "not valid JSON"]),
    (["calibrate", "{garbage_csv}"], 2, ["garbage.csv", "row 6"]),
    (["calibrate", "{label_csv}"], 2, ["row 4", "'P99'", "not a segment"]),
    (["calibrate", "{cell_csv}"], 2, ["row 4", "not a number"]),
    (["calibrate", "{folder}"], 2, ["folder"]),
    (["calibrate", "{cal}"], 2, ["cal.json is a calibration file, not a session"]),
    (["calibrate", "{dir}/nothing.npz"], 2, ["nothing.npz does not exist"]),
    (["calibrate", "{s}", "--instruments", "gyr"], 2, ["--instruments", "gyr"]),
    (["calibrate", "{s}", "--effects", "foo", "--method", "lsq"], 2, ["unknown effect 'foo'"]),
    (["calibrate", "{s}", "--effects", "bias", "--method", "cho"], 2, ["--effects applies to --method lsq"]),
    (["calibrate", "{s}", "--keep-worse-effects"], 2, ["--keep-worse-effects applies to --method lsq with --effects"]),
    (["calibrate", "{s}", "--method", "zhang"], 2, ["Zhang", "triad"]),
    (["calibrate", "{s_csv}", "-o", "{s_json}"], 2, ["would overwrite the input", "s.json"]),
    (["diagnose", "{empty}"], 2, ["empty.npz", "not a readable NPZ"]),
    (["diagnose", "{zerogyro}"], 2, ["constant"]),
    (["diagnose", "{s}", "--model", "foo"], 2, ["unknown effect 'foo'"]),
    (["diagnose", "{s}", "--add", "foo"], 2, ["unknown effect 'foo'"]),
    (["diagnose", "{dir}/missing.npz"], 2, ["does not exist"]),
    # calibration files
    (["check", "{s}", "--calibration", "{notjson}"], 2, ["notjson.json"]),
    (["check", "{s}", "--calibration", "{emptycal}"], 2, ["emptycal.json"]),
    (["check", "{s}", "--calibration", "{tampered}"], 2, ["checksum"]),
    (["check", "{s}", "--calibration", "{dir}/nocal.json"], 2, ["nocal.json"]),
    (["check", "{s}", "--calibration", "{ddcal}"], 2, ["dodecahedron6", "cone6"]),
    (["check", "{s}", "--calibration", "{s_json}"], 2, ["not a rimu calibration"]),
    (["check", "{s}", "--calibration", "{s_csv}"], 2, ["not valid JSON"]),
    (["check", "{tri}", "--calibration", "{trical}"], 2, ["not applicable", "no parity space"]),
    (["check", "{s}", "--calibration", "{trical}"], 2, ["triad3"]),
    (["check", "{trunc}", "--calibration", "{cal}"], 2, ["truncated"]),
    (["replay", "{s}", "--calibration", "{ddcal}"], 2, ["dodecahedron6", "cone6"]),
    (["replay", "{s}", "--calibration", "{tampered}"], 2, ["checksum"]),
    (["replay", "{nonmono}", "--calibration", "{cal}"], 2, ["does not increase"]),
    (["replay", "{s}", "--calibration", "{cal}", "--inject", "bias:gyro:x1:1000"], 2, ["1000 s", "outside the data"]),
    (["replay", "{s}", "--calibration", "{cal}", "--inject", "bias:gyro:x1:-5"], 2, ["outside the data"]),
    (["replay", "{s}", "--calibration", "{cal}", "--inject", "foo"], 2, ["TYPE:INSTRUMENT:SENSOR:START"]),
    (["replay", "{s}", "--calibration", "{cal}", "--inject", "bias:gyro:zz:1"], 2, ["no gyro sensor named 'zz'"]),
    (["replay", "{s}", "--calibration", "{cal}", "--inject", "bias:gyro:9:1"], 2, ["no gyro sensor 9"]),
    (["replay", "{s}", "--calibration", "{cal}", "--detector", "foo"], 2, ["--detector", "foo"]),
    (["replay", "{s}", "--calibration", "{cal}", "--json", "{s}"], 2, ["would overwrite the input"]),
    (["replay", "{s}", "--calibration", "{cal}", "--estimates", "{afile}/x.csv"], 2, ["--estimates", "not a folder"]),
    (["replay", "{s}", "--calibration", "{cal}", "--estimates", "{dir}/missing/x.csv"], 2, ["--estimates", "does not exist"]),
    (["replay", "{s}", "--calibration", "{cal}", "--estimates", "{dir}"], 2, ["--estimates", "is a folder"]),
    (["replay", "{s}", "--calibration", "{cal}", "--estimates", "{s}"], 2, ["--estimates", "would overwrite the input"]),
    (["replay", "{s}", "--calibration", "{cal}", "--estimates", "{dir}/e.csv", "--json", "{dir}/e.csv"], 2,
     ["--estimates", "would overwrite --json"]),
    # simulate, design, campaign options
    (["simulate", "--duration", "0"], 2, ["--duration", "> 0"]),
    (["simulate", "--duration", "-5"], 2, ["--duration"]),
    (["simulate", "--procedure", "zhang", "--duration", "5"], 2, ["--duration", "zhang"]),
    (["simulate", "--sample-rate", "0"], 2, ["--sample-rate"]),
    (["simulate", "--latitude", "95"], 2, ["--latitude", "[-90, 90]"]),
    (["simulate", "--geometry", "foo"], 2, ["unknown geometry 'foo'"]),
    (["simulate", "-o", "{dir}/x.txt"], 2, ["x.txt", ".csv", ".npz"]),
    (["simulate", "-o", "{dir}/a.csv", "--truth", "{dir}/a.json"], 2, ["a.json", "sidecar", "--truth"]),
    (["simulate", "-o", "{afile}/s.npz"], 2, ["--output", "not a folder"]),
    (["design", "--geometry", "foo"], 2, ["unknown geometry"]),
    (["design", "--duration", "0"], 2, ["--duration"]),
    (["design", "--procedure", "zhang", "--duration", "5"], 2, ["--duration", "zhang"]),
    (["design", "--greedy", "100000"], 2, ["--greedy", "candidate"]),
    (["campaign", "--faults", "foo", "--workers", "0"], 2, ["--faults", "foo"]),
    (["campaign", "--sizes", "a,b", "--workers", "0"], 2, ["--sizes"]),
    (["campaign", "--sensors", "99", "--workers", "0"], 2, ["--sensors", "0..5"]),
    (["campaign", "--fault-start", "20", "--duration", "10", "--workers", "0"], 2, ["--fault-start", "inside"]),
    (["campaign", "--geometry", "foo", "--workers", "0"], 2, ["unknown geometry"]),
    (["campaign", "--repetitions", "0"], 2, ["--repetitions"]),
    # monitor sources
    (["monitor", "--npz", "{empty}", "--calibration", "{cal}"], 2, ["empty.npz", "NPZ"]),
    (["monitor", "--npz", "{s}"], 2, ["--calibration"]),
    (["monitor", "--csv", "{s_csv}", "--calibration", "{cal}"], 2, ["s.csv", "line 1"]),
    (["monitor", "--can", "foo:bar", "--calibration", "{cal}"], 2, ["foo"]),
    (["monitor", "--serial", "{dir}/no-such-port", "--calibration", "{cal}"], 2, ["no-such-port"]),
    (["monitor", "--replay", "{dir}/nolog.asc", "--calibration", "{cal}"], 2, ["nolog.asc"]),
    (["monitor", "--replay", "{garbage_log}", "--calibration", "{cal}"], 2, ["no epoch", "--layout"]),
    (["monitor", "--simulate", "--fault", "gyro:zz:1:1"], 2, ["--fault", "INSTRUMENT:SENSOR"]),
    (["monitor", "--ulog", "{s}", "--calibration", "{cal}"], 2, ["ULog"]),
    (["monitor", "--can", "virtual:x", "--calibration", "{cal}", "--layout", "{notjson}"], 2, ["notjson.json"]),
    # --sample-rate is the stream's rate (noise of a unit set up on averages, motion terms, --selfcal; else measured)
    (["monitor", "--npz", "{s}", "--calibration", "{cal}", "--sample-rate", "0"], 2, ["--sample-rate"]),
    (["monitor", "--npz", "{s}", "--calibration", "{cal}", "--selfcal-temperature"], 2,
     ["--selfcal-temperature", "--selfcal"]),
    (["monitor", "--npz", "{s}", "--calibration", "{cal}", "--selfcal", "--sample-rate", "100"], 2,
     ["noise model", "--selfcal-bias-rw"]),
    (["monitor", "--npz", "{s}", "--calibration", "{cal}", "--selfcal", "--sample-rate", "100", "--selfcal-bias-rw",
      "1e-9", "--selfcal-window", "0.001"], 2, ["--selfcal-window", "one sample"]),
    # export-c
    (["export-c", "{tampered}", "-o", "{dir}/x"], 2, ["checksum"]),
    (["export-c", "{dir}/nocal.json", "-o", "{dir}/x"], 2, ["nocal.json"]),
    (["export-c", "{cal}", "-o", "{afile}"], 2, ["--output", "not a folder"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--real", "half"], 2, ["--real", "half"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--backoff", "0.5"], 2, ["--backoff", "between 1 and 100"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--max-set-size", "3"], 2, ["--max-set-size", "3"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--selfcal"], 2, ["--sample-rate"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--selfcal", "--sample-rate", "100"], 2, ["noise model", "--selfcal-bias-rw"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--selfcal", "--sample-rate", "100", "--selfcal-bias-rw", "1e-9",
      "--real", "float"], 2, ["--selfcal", "double"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--selfcal", "--sample-rate", "100", "--selfcal-bias-rw", "1e-9",
      "--target", "cortex-m4"], 2, ["--selfcal", "cortex-m4"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--sample-rate", "100"], 2, ["--sample-rate", "--selfcal"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--selfcal-detector-window", "30"], 2, ["--selfcal-detector-window",
                                                                                    "--selfcal"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--selfcal", "--sample-rate", "100", "--selfcal-bias-rw", "1e-9",
      "--selfcal-window", "0.001"], 2, ["--selfcal-window", "one sample"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--selfcal", "--sample-rate", "0"], 2, ["--sample-rate"]),
    (["export-c", "{cal}", "-o", "{dir}/x", "--selfcal", "--sample-rate", "100", "--selfcal-bias-rw", "1e-320"], 2,
     ["--selfcal-bias-rw", "1e-320"]),
    # demo
    (["demo", "--report", "{afile}"], 2, ["--report", "not a folder"]),
    (["demo", "--segment-duration", "0"], 2, ["--segment-duration"]),
]


def _fill(f: dict, args: list[str]) -> list[str]:
    if any("{garbage_log}" in a for a in args):
        log = Path(f["dir"]) / "garbage.asc"
        log.write_text("date Mon Nov 23 09:00:00 2026\nbase hex  timestamps absolute\nthis is garbage\n"
                       " 0.1 1 123 Rx d 8 00 11 22\n")
        f = dict(f, garbage_log=str(log))
    return [a.format(**f) for a in args]


@pytest.mark.parametrize("argv,code,words", CASES, ids=[" ".join(c[0][:3]) for c in CASES])
def test_bad_input_table(argv, code, words, f, capsys):
    args = _fill(f, argv)
    got, _, err = run(args, capsys)
    line = assert_one_error(err, args[0])
    assert got == code, (args, err)
    for w in words:
        assert w in line, (w, line)


def test_the_table_covers_every_command():
    covered = {c[0][0] for c in CASES}
    assert covered >= set(COMMANDS) - {"demo"} | {"demo"}, sorted(set(COMMANDS) - covered)


# ------------------------------------------------------------------ checks that can fail; silently-wrong cases
def test_check_fails_on_a_miscalibrated_accelerometer(f, capsys, tmp_path):
    from rimu.calibration import Calibration

    code, out, _ = run(["check", f["s"], "--calibration", f["cal"], "--instrument", "accel"], capsys)
    assert code == 0 and "verdict: GOOD" in out
    for i, (kind, size) in enumerate([("scale", 3e-4), ("bias", 1e-2)]):
        cal = Calibration.load(f["cal"])
        if kind == "scale":
            cal["accel"].scale[2] *= 1 + size       # 300 ppm on z1
        else:
            cal["accel"].bias[4] += size            # 10 mm/s^2 (1 mg) on y2
        bad = cal.save(tmp_path / f"bad{i}.json")
        code, out, err = run(["check", f["s"], "--calibration", str(bad), "--instrument", "accel",
                              "--json", str(tmp_path / f"bad{i}-check.json")], capsys)
        assert code == 1 and "verdict: BAD" in out and "rimu check: BAD" in out, (kind, out, err)
        doc = json.loads((tmp_path / f"bad{i}-check.json").read_text())
        assert doc["accel"]["verdict"] == "bad"


def test_check_on_a_triad_says_not_applicable(f, capsys):
    code, _, err = run(["check", f["tri"], "--calibration", f["trical"]], capsys)
    line = assert_one_error(err, "check")
    assert code == 2 and "gyro: not applicable" in line and "accel: not applicable" in line


def test_simulate_truth_cannot_overwrite_the_sidecar(f, capsys):
    d = Path(f["dir"])
    code, _, err = run(["simulate", "--duration", "1", "-o", str(d / "t1.csv"), "--truth", str(d / "t1.json")], capsys)
    assert "t1.json" in assert_one_error(err, "simulate")
    assert code == 2 and not (d / "t1.csv").exists() and not (d / "t1.json").exists()


def test_design_and_calibrate_agree_on_the_bias_at_zero_input(f, tmp_path, capsys):
    """``rimu design`` predicts the error of the compensated output at rest (Cho & Park Eq. 19); ``rimu calibrate``
    reports the marginal std of B = SF x raw offset, which is larger by the scale-factor uncertainty times the
    unit's raw offset; it now prints the zero-input figure, which matches the prediction."""
    code, _, _ = run(["design", "--duration", "3", "--json", str(tmp_path / "d.json")], capsys)
    assert code == 0
    pred = json.loads((tmp_path / "d.json").read_text())["predicted_std_si"]
    code, out, _ = run(["calibrate", f["s"], "-o", str(tmp_path / "c.json"), "--json", str(tmp_path / "c-sum.json")],
                       capsys)
    assert code == 0 and "bias std at zero input" in out and "marginal std of B" in out
    doc = json.loads((tmp_path / "c-sum.json").read_text())["instruments"]
    for k in ("gyro", "accel"):
        zero = doc[k]["bias_std_at_zero_input_si"]
        marg = doc[k]["std_si"]
        for name, z in zero.items():
            assert abs(z / pred[k][f"{name}.bias"] - 1) < 0.1, (k, name)       # the same figure
            assert marg[f"{name}.bias"] > 3 * z                                 # the other one, explained


def test_events_carry_time_and_sample(f, tmp_path, capsys):
    code, out, _ = run(["replay", f["s"], "--calibration", f["cal"], "--inject", "bias:gyro:y2:30:10sigma",
                        "--json", str(tmp_path / "ev.json")], capsys)
    assert code == 0 and "(sample" in out
    ev = next(e for e in json.loads((tmp_path / "ev.json").read_text())["gyro"]["events"] if e["kind"] == "isolated")
    assert ev["sensor"] == "y2" and 30.0 <= ev["t"] < 30.5 and ev["sample"] == int(round(ev["t"] * 100))


def test_deprecated_spellings_still_work(f, tmp_path, capsys):
    code, _, err = run(["check", f["s"], "--calibration", f["cal"], "--out", str(tmp_path / "chk")], capsys)
    assert code == 0 and "--out is deprecated" in err and (tmp_path / "chk" / "check.json").exists()
    code, out, err = run(["diagnose", f["s"], "--instrument", "accel", "--json"], capsys)
    assert code == 0 and "--json without a FILE is deprecated" in err and json.loads(out)["diagnosis"]
    code, _, err = run(["design", "--duration", "3", "--plot", str(tmp_path / "f3.png")], capsys)
    assert code == 0 and "--plot is deprecated" in err and (tmp_path / "f3.png").exists()


def test_accept_implausible_overrides_with_a_warning(f, tmp_path, capsys):
    code, _, err = run(["calibrate", f["rate"], "--accept-implausible", "-o", str(tmp_path / "c.json")], capsys)
    assert code == 0 and "warning: " in err and "sample_rate_hz is 250 Hz" in err
    code, _, err = run(["calibrate", f["rate"], "-q", "--accept-implausible", "-o", str(tmp_path / "c.json")], capsys)
    assert code == 0 and err == ""


def test_debug_shows_the_traceback(f):
    from rimu.errors import SessionFormatError

    with pytest.raises(SessionFormatError):
        main(["--debug", "calibrate", f["empty"]])
    with pytest.raises(SessionFormatError):
        main(["calibrate", f["empty"], "--debug"])


def test_ctrl_c_during_a_write_leaves_no_file(f, tmp_path, capsys, monkeypatch):
    """KeyboardInterrupt injected while the session file is being written: one line, exit 130, no file."""
    real = np.savez_compressed

    def interrupted(file, *a, **k):
        with open(file, "wb") as fh:
            fh.write(b"PK half an archive")
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", interrupted)
    code, _, err = run(["simulate", "--duration", "1", "-o", str(tmp_path / "s.npz")], capsys)
    assert code == 130 and err.strip() == "rimu simulate: interrupted; no partial output file was left behind"
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(np, "savez_compressed", real)
    # the calibration file too (json written through rimu.atomic)
    import rimu.calibration.result as result

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(result.os, "fsync", boom)
    code, _, err = run(["calibrate", f["s"], "-o", str(tmp_path / "c.json")], capsys)
    assert code == 130 and list(tmp_path.iterdir()) == []


def test_internal_errors_are_one_line_too(monkeypatch, f, capsys):
    import rimu.cli.design as design

    def bug(args):
        return 1 / 0

    monkeypatch.setattr(design, "run", bug)
    code, _, err = run(["design"], capsys)
    line = assert_one_error(err, "design")
    assert code == 3 and "ZeroDivisionError" in line and "--debug" in line


# ------------------------------------------------------------------ a few real processes
def _proc(*args: str, cwd: str | None = None) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env, cwd=cwd, timeout=120)


def test_python_m_rimu_works_like_rimu(f):
    r = _proc("-m", "rimu", "--version")
    assert r.returncode == 0 and r.stdout.startswith("rimu ")
    r = _proc("-m", "rimu", "calibrate", f["trunc"])
    assert r.returncode == 2 and "Traceback" not in r.stderr and r.stderr.count("\n") == 1 and "truncated" in r.stderr
    r = _proc("-m", "rimu.cli", "simulate", "--duration", "0")
    assert r.returncode == 2 and "Traceback" not in r.stderr and "--duration" in r.stderr


def test_a_long_replay_in_chunks_gives_the_same_events(f, tmp_path, capsys, monkeypatch):
    """Long replays run in chunks (for the progress bar); the manager keeps its state, so events and states are
    those of one run over the whole block."""
    import rimu.cli.replay as replay

    argv = ["replay", f["s"], "--calibration", f["cal"], "--inject", "bias:gyro:y2:30:10sigma",
            "--inject", "bias:accel:x1:50:8sigma"]
    assert run(argv + ["--json", str(tmp_path / "one.json")], capsys)[0] == 0
    monkeypatch.setattr(replay, "_CHUNK", 997)
    assert run(argv + ["--json", str(tmp_path / "chunks.json")], capsys)[0] == 0
    one, chunks = (json.loads((tmp_path / n).read_text()) for n in ("one.json", "chunks.json"))
    assert one == chunks and any(e["kind"] == "isolated" for e in one["accel"]["events"])


def test_a_scheduler_without_the_extra_is_refused_before_any_work(capsys):
    try:
        import distributed  # noqa: F401
        pytest.skip("dask.distributed is installed here")
    except ImportError:
        pass
    code, out, err = run(["campaign", "--scheduler", "tcp://127.0.0.1:1", "--workers", "0"], capsys)
    assert code == 2 and out == "" and "pip install 'rimu[distributed]'" in assert_one_error(err, "campaign")


def test_verbose_and_quiet(f, tmp_path, capsys):
    code, _, err = run(["-v", "calibrate", f["s"], "-o", str(tmp_path / "c.json")], capsys)
    assert code == 0 and "rimu calibrate: info: read " in err and "24 segments, 7200 samples" in err
    code, _, err = run(["calibrate", f["s"], "-o", str(tmp_path / "c.json"), "-vv"], capsys)
    assert code == 0 and "rimu calibrate: debug: arguments" in err
    code, _, err = run(["calibrate", f["s"], "-o", str(tmp_path / "c.json")], capsys)
    assert code == 0 and err == ""
