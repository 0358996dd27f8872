"""``rimu noise RECORDING -o NOISE.json``: Allan deviation and IEEE Std 952 noise terms of every sensor.

RECORDING is a static recording: a session file in rimu's format (``.npz``, or ``.csv`` with its ``.json``
sidecar; the longest static segment, or ``--segment``); a raw log of counts with a header row naming its
columns (``ax,ay,az,gx,gy,gz``, as rimu detect reads; ``--calibration`` required: its scale factors give the
SI, applied once to the counts, also to a log whose reader knows the chip's nominal scales); or a plain array of compensated outputs in SI of one instrument (``.npy``, or a ``.csv`` without header
or sidecar: N rows, one column per sensor) with ``--sample-rate``. Counts are never taken as SI: whole numbers
in the hundreds, or an accelerometer at rest given as gyros, are refused. Writes the noise model (JSON, ``format: rimu.noise``); ``--report DIR``
adds one log-log plot per instrument with the fitted slopes, the parity plot and a markdown summary;
``--json FILE`` a short machine-readable summary; ``--write-calibration OUT`` the calibration with the noise
terms in its optional ``noise`` section (what the detectors of rimu.fdi read). See docs/noise.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

from ._common import positive_float, probability
from ._inputs import add_log_options


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("noise", help="Allan deviation and noise terms (ARW/VRW, bias instability, RRW) of a static "
                       "recording", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("recording", help="session file (.npz, .csv + .json sidecar), a static log (rimu import --help), "
                   "or plain .npy/.csv in SI")
    p.add_argument("-o", "--output", default="noise.json", help="noise model file (default noise.json)")
    p.add_argument("--report", default=None, metavar="DIR", help="folder for the plots and noise.md")
    p.add_argument("--json", default=None, metavar="FILE", help="machine-readable summary")
    p.add_argument("--calibration", default=None, help="calibration file: scale factors, biases and axes")
    p.add_argument("--write-calibration", default=None, metavar="OUT",
                   help="write the calibration with the identified noise in its 'noise' section")
    p.add_argument("--segment", default=None, help="segment label (default: the longest static one)")
    p.add_argument("--instrument", action="append", default=None, help="gyro or accel (repeatable; default all)")
    p.add_argument("--terms", default="quantization,white,bias_instability,rate_random_walk",
                   help="terms to fit, comma-separated")
    p.add_argument("--sample-rate", type=positive_float, default=None, help="Hz (plain recordings)")
    p.add_argument("--geometry", default=None, help="geometry preset of a plain recording (for the parity check)")
    p.add_argument("--p-fa", type=probability, default=1e-3, help="false-verdict probability of each parity check")
    p.add_argument("--from-kalibr", default=None, metavar="YAML",
                   help="no recording: seed the noise model of --calibration's sensors from kalibr's imu.yaml "
                        "(white noise and random walk per triad; RECORDING is then '-')")
    p.add_argument("--kalibr", default=None, metavar="YAML",
                   help="also write kalibr's imu.yaml (noise densities and random walks per triad, SI)")
    add_log_options(p)
    p.set_defaults(func=run)


def _header_line(path: Path) -> bool:
    """Whether a text file starts with a non-numeric line (a header or a metadata block: a raw log)."""
    from ..io.rawtext import is_number

    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if line.strip() and not line.lstrip().startswith("#"):
                return not all(is_number(p.strip()) for p in line.replace(";", ",").split(",") if p.strip())
    return False


def _raw_log(args: argparse.Namespace, path: Path) -> Any:
    """A raw log of counts (a metadata block and a header naming the columns, as rimu detect reads): compensated
    with the calibration, whose scale factors give the SI; refused without one."""
    from ..calibration import Calibration
    from ..errors import CalibrationFileError
    from ..io.rawtext import read_raw_text
    from ..noise.api import identify

    log = read_raw_text(path, args.sample_rate)
    cols = "; ".join(f"{k} {','.join(v)}" for k, v in log.columns.items())
    if not args.calibration:
        raise CalibrationFileError(
            f"{path} is a raw log ({cols}) of counts: the noise terms in SI need its scale factors; give the "
            "unit's calibration: rimu noise FILE --calibration cal.json")
    cal = Calibration.load(args.calibration)
    insts = args.instrument or [k for k in log.raw if k in cal.instruments]
    outputs, axes, names = {}, {}, {}
    for k in insts:
        if k not in log.raw:
            raise CalibrationFileError(f"--instrument {k}: {path} has no {k} columns ({cols})")
        if k not in cal.instruments:
            raise CalibrationFileError(f"{args.calibration} has no {k} calibration (it has "
                                       f"{', '.join(cal.instruments)}): calibrate the {k} too, or give --instrument "
                                       f"{' --instrument '.join(i for i in log.raw if i in cal.instruments) or k}")
        c = cal[k]
        if c.geometry.n != log.raw[k].shape[1]:
            raise CalibrationFileError(f"{path} has {log.raw[k].shape[1]} {k} columns, {args.calibration} "
                                       f"calibrates {c.geometry.n} {k} sensors: calibrate this unit, or give the "
                                       "calibration made for it")
        outputs[k], axes[k], names[k] = c.compensate(log.raw[k]), c.axes_mb(), list(log.columns[k])
    if not outputs:
        raise CalibrationFileError(f"{args.calibration} calibrates none of the instruments of {path} ({cols})")
    return identify(outputs, log.sample_rate, axes, names, _terms(args), args.p_fa,
                    meta={"recording": str(path), "plain": False, "calibrated": True, "raw_columns": log.columns})


def _counts_log(path: Path, calibration: str) -> bool:
    """Whether ``path`` is a text log with a header row (its cells counts) and ``calibration`` one of counts: then
    the calibration's scale factors give the SI, once (its reader's nominal scales are not applied as well)."""
    from ..calibration import Calibration

    if path.suffix.lower() not in (".csv", ".txt") or path.with_suffix(".json").exists() or not path.is_file():
        return False
    try:
        if not _header_line(path):
            return False
    except OSError:
        return False
    return str(Calibration.load(calibration).raw_unit).lower() in ("count", "counts")


def _check_si(z: np.ndarray, inst: str, path: Path) -> None:
    """Refuse a plain array that cannot be compensated outputs of ``inst`` in SI: raw counts (integers in the
    hundreds), an accelerometer at rest read as gyros, accelerations in g or rates in deg/s."""
    from ..errors import PlausibilityError
    from ..units import G0

    big = float(np.max(np.abs(z))) if z.size else 0.0
    if big >= 100 and np.all(z == np.round(z)):
        raise PlausibilityError(
            f"{path}: whole numbers up to {big:.0f}: these look like raw counts, not {inst} outputs in SI; give the "
            "file with its header (ax,ay,az,gx,gy,gz) and --calibration cal.json, or convert it to SI first")
    m = np.abs(z.mean(axis=0))
    triads = [np.linalg.norm(z[:, i:i + 3].mean(axis=0)) for i in range(0, z.shape[1] - 2, 3)]
    if inst == "gyro" and (any(0.8 * G0 < x < 1.25 * G0 for x in triads) or np.any(m > 2.0)):
        raise PlausibilityError(
            f"{path}: column means up to {m.max():.3g} ({'a triad of norm ' + format(max(triads), '.3g') if triads else ''}"
            "): not gyro outputs at rest in rad/s (an accelerometer at rest in m/s^2, or deg/s?); give "
            "--instrument accel for accelerometers, or convert deg/s to rad/s")
    if inst == "accel" and triads and 0.8 < max(triads) < 1.25:
        raise PlausibilityError(f"{path}: accelerometer triad at rest of norm {max(triads):.3g}: these are in g, "
                                "not m/s^2; multiply by 9.80665 first")


def _plain(args: argparse.Namespace, path: Path) -> Any:
    from ..errors import OptionError, SessionFormatError
    from ..noise.api import identify

    if path.suffix != ".npy" and _header_line(path):
        return _raw_log(args, path)
    if args.sample_rate is None:
        raise SessionFormatError(f"{path} is a plain array: give its --sample-rate (Hz)")
    if args.calibration:
        raise OptionError(f"--calibration: {path} is a plain array without a header, read as compensated outputs in "
                          "SI; a calibration would not apply. Give raw counts with their header row (ax,ay,az,gx,"
                          "gy,gz) to apply it, or drop --calibration")
    if args.instrument and len(args.instrument) > 1:
        raise OptionError(f"{path} is a plain array of one instrument; give one --instrument, not "
                          f"{', '.join(args.instrument)}")
    from ..io.guard import load_array, reading

    if path.suffix == ".npy":
        z = load_array(path, "NPY array")
    else:
        with reading(path, "CSV text"):
            try:
                z = np.loadtxt(path, delimiter=",", ndmin=2)
            except ValueError as exc:
                raise SessionFormatError(f"{path}: not a table of numbers ({exc}); a plain recording is N rows "
                                         "of comma-separated numbers, one column per sensor") from None
    if not isinstance(z, np.ndarray) or z.ndim != 2 or z.shape[0] < 2 or not np.issubdtype(z.dtype, np.number):
        shape = getattr(z, "shape", None)
        raise SessionFormatError(f"{path}: a plain recording is a numeric array of N rows and one column per sensor "
                                 f"(N, n), got shape {shape}; reshape it (a single sensor: (N, 1))")
    z = np.asarray(z, dtype=float)
    if not np.all(np.isfinite(z)):
        r, c = np.argwhere(~np.isfinite(z))[0]
        raise SessionFormatError(f"{path}: {int((~np.isfinite(z)).sum())} values are not finite (first: row {r + 1}, "
                                 f"column {c + 1}); noise identification needs an unbroken static recording")
    flat = np.flatnonzero(np.ptp(z, axis=0) == 0)
    if flat.size:
        raise SessionFormatError(f"{path}: column {int(flat[0]) + 1} is constant: not the output of a sensor (a "
                                 "disconnected channel?); remove it")
    inst = (args.instrument or ["gyro"])[0]
    _check_si(z, inst, path)
    axes = names = None
    if args.geometry:
        from ..geometry import preset

        g = preset(args.geometry)
        if g.n != z.shape[1]:
            raise SessionFormatError(f"{path} has {z.shape[1]} columns, geometry {g.name!r} {g.n} sensors")
        axes, names = {inst: g.H}, {inst: list(g.names)}
    return identify({inst: z}, args.sample_rate, axes, names, _terms(args), args.p_fa,
                    meta={"recording": str(path), "plain": True})


def _is_plain(path: Path) -> bool:
    """A plain array in SI: ``.npy``, or a numeric ``.csv`` without a sidecar that no log format claims."""
    if path.suffix == ".npy":
        return True
    if path.suffix != ".csv" or path.with_suffix(".json").exists():
        return False
    from ..io.formats import find_format

    return find_format(path) in (None, "text")


def _terms(args: argparse.Namespace) -> tuple[str, ...]:
    from ..errors import OptionError
    from ..noise.model import TERMS

    terms = tuple(t.strip() for t in args.terms.split(",") if t.strip())
    unknown = [t for t in terms if t not in TERMS]
    if not terms or unknown:
        raise OptionError(f"--terms {args.terms!r}: give one or more of {', '.join(TERMS)}, comma-separated"
                          + (f" (unknown: {', '.join(unknown)})" if unknown else ""))
    return terms


def run(args: argparse.Namespace) -> int:
    from ..errors import RimuError

    try:
        return _run(args)
    except RimuError as exc:
        print(f"rimu noise: error: {exc}", file=sys.stderr)
        return 2


def _run(args: argparse.Namespace) -> int:
    from ..noise.api import identify_session
    from ._common import json_dump

    if args.from_kalibr:
        return _seed(args)
    path = Path(args.recording)
    if not path.exists():
        raise FileNotFoundError(f"no such recording: {path}")
    _terms(args)  # the options first: a refusal before any work
    if args.write_calibration and not args.calibration:
        from ..errors import OptionError

        raise OptionError("--write-calibration needs --calibration (the file to add the noise to)")
    cal = None
    if _is_plain(path):
        model = _plain(args, path)
    elif args.calibration and _counts_log(path, args.calibration):
        # a log of counts whose reader would convert them with the chip's nominal scales, and a calibration of
        # counts: the counts are read as they are and the calibration applied once (not on top of the nominal ones)
        model = _raw_log(args, path)
    else:
        from ..calibration import Calibration
        from ._inputs import open_session

        session = open_session(path, kind="static_unknown", args=args)
        if args.calibration:
            cal = Calibration.load(args.calibration, geometries=session.geometries)
        model = identify_session(session, cal, args.segment, args.instrument, _terms(args), args.p_fa)
        model.meta["recording"] = str(path)
    for k, m in model.instruments.items():
        print(m.table())
        if k in model.parity:
            print("  " + model.parity[k]["verdict"])
    out = model.save(args.output)
    extra = []
    if args.report:
        extra.append(f"report {_report(model, Path(args.report))}")
    if args.json:
        summary = {"output": str(out), "instruments": {k: m.table_rows() for k, m in model.instruments.items()},
                   "parity": {k: {"white": v["white"], "independent": v["independent"], "verdict": v["verdict"]}
                              for k, v in model.parity.items()}}
        json_dump(summary, args.json)
        extra.append(f"summary {args.json}")
    if args.kalibr:
        extra.append(f"kalibr {_write_kalibr(model, args.kalibr)}")
    if args.write_calibration:
        if cal is None:
            from ..errors import CalibrationFileError

            raise CalibrationFileError("--write-calibration needs --calibration (the file to add the noise to)")
        for k, m in model.instruments.items():
            if k in cal:
                cal[k].noise = m
        cal.save(args.write_calibration)
        extra.append(f"calibration with noise {args.write_calibration}")
    insts = ", ".join(f"{k} ({m.n} sensors)" for k, m in model.instruments.items())
    print(f"noise of {insts} -> {out}" + ("; " + "; ".join(extra) if extra else ""))
    return 0


def _seed(args: argparse.Namespace) -> int:
    """``--from-kalibr``: the noise of every sensor of the calibration from kalibr's imu.yaml (or IMU chain)."""
    from ..calibration import Calibration
    from ..errors import OptionError
    from ..noise.kalibr import noise_from_kalibr, read_kalibr
    from ..noise.model import NoiseModel

    if not args.calibration:
        raise OptionError("--from-kalibr needs --calibration (the unit whose sensors the noise is for)")
    cal = Calibration.load(args.calibration)
    doc = read_kalibr(args.from_kalibr)
    models = {}
    for k in cal.instruments:
        names = list(cal[k].geometry.names)
        blocks = [doc[f"imu{j}"] for j in range(len(names) // 3)] if "imu0" in doc else [doc]
        if len(blocks) * 3 != len(names) and len(blocks) != 1:
            raise OptionError(f"--from-kalibr: {len(blocks)} IMU blocks for {len(names)} {k} sensors")
        per = [noise_from_kalibr(blocks[min(i // 3, len(blocks) - 1)], k, [n]) for i, n in enumerate(names)]
        m = noise_from_kalibr(blocks[0], k, names)
        for t in m.terms:
            m.terms[t] = np.array([p.terms[t][0] for p in per])
        models[k] = m
        cal[k].noise = m
        u = ("rad/s/sqrt(Hz)", "rad/s^2/sqrt(Hz)") if k == "gyro" else ("m/s^2/sqrt(Hz)", "m/s^3/sqrt(Hz)")
        print(f"{k}: noise density " + ", ".join(f"{v:.4g}" for v in m.terms["white"]) + f" {u[0]}, random walk "
              + ", ".join(f"{v:.4g}" for v in m.terms["rate_random_walk"]) + f" {u[1]}, at {m.sample_rate:g} Hz")
    out = NoiseModel(models, meta={"source": str(args.from_kalibr)}).save(args.output)
    msg = f"noise model seeded from {args.from_kalibr} -> {out}"
    if args.write_calibration:
        msg += f"; calibration with noise {cal.save(args.write_calibration)}"
    print(msg)
    return 0


def _write_kalibr(model: Any, path: str) -> str:
    """kalibr's imu.yaml of the model: one block per triad of the geometry (rimu.noise.kalibr)."""
    from ..atomic import write_text
    from ..noise.kalibr import kalibr_yaml, to_kalibr, to_kalibr_chain

    n = max(m.n for m in model.instruments.values())
    if n == 3:
        doc = to_kalibr(model.instruments)
    elif n % 3 == 0:
        doc = to_kalibr_chain(model.instruments, [[3 * j, 3 * j + 1, 3 * j + 2] for j in range(n // 3)])
    else:
        from ..errors import NotApplicableError

        raise NotApplicableError(f"--kalibr: kalibr describes triads; this unit has {n} sensors, not 3 per IMU")
    write_text(path, kalibr_yaml(doc))
    from ..noise.kalibr import UNITS

    for name, d in ([("", doc)] if any(isinstance(v, float) for v in doc.values())
                    else [(f"{k} ", v) for k, v in doc.items() if isinstance(v, dict)]):
        print(f"kalibr noise {name}".rstrip() + ": " + ", ".join(
            f"{k} {v:.4g} {UNITS.get(k, '')}".rstrip() for k, v in d.items() if isinstance(v, float)))
    return path


def _report(model: Any, folder: Path) -> Path:
    from ..atomic import write_text
    from ..noise.model import FIELD_UNITS, TERMS
    from ..noise.plots import plot_instrument, plot_parity

    folder.mkdir(parents=True, exist_ok=True)
    lines = ["# Noise identification (IEEE Std 952 / 1554)", ""]
    for k, m in model.instruments.items():
        png = plot_instrument(m, folder / f"allan-{k}.png")
        units = FIELD_UNITS[k]
        lines += [f"## {k}", "", f"![Allan deviation]({png.name})", "",
                  "| sensor | " + " | ".join(f"{t.replace('_', ' ')} [{units[t][0]}]" for t in TERMS) + " |",
                  "|---|" + "---|" * len(TERMS)]
        for r in m.table_rows():
            lines.append(f"| {r['sensor']} | " + " | ".join(f"{r[t]:.4g} +/- {r[t + '_sigma']:.2g}" for t in TERMS)
                         + " |")
        lines.append("")
        if k in model.parity:
            pp = plot_parity(model.parity[k], folder / f"parity-{k}.png")
            lines += [model.parity[k]["verdict"], "", f"![parity]({pp.name})", ""]
    md = folder / "noise.md"
    write_text(md, "\n".join(lines))
    return md
