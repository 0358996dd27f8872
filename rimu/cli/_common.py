"""What every ``rimu`` subcommand shares: the option convention, option validators, deprecated spellings, the check
that output paths can be written before any work starts, and logging.

The convention (docs/cli.md):

``-o/--output FILE``
    the main artifact of the command (a session, a calibration, a recording);
``--report DIR``
    human reports: markdown/HTML, PNG plots;
``--json FILE``
    a machine-readable summary (``-`` prints it on stdout).

Options validated here fail with one line naming the option and the accepted range, exit status 2.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

from ..errors import OutputPathError

__all__ = [
    "Parser",
    "positive_float",
    "finite_float",
    "nonnegative_float",
    "probability",
    "positive_int",
    "nonnegative_int",
    "bounded_float",
    "check_samples",
    "Deprecated",
    "add_old_out",
    "add_procedure_options",
    "PROCEDURES",
    "add_json_option",
    "add_report_option",
    "add_accept_implausible",
    "check_outputs",
    "output_options",
    "configure_logging",
    "OUTPUT_FILE_OPTIONS",
    "OUTPUT_DIR_OPTIONS",
    "INPUT_OPTIONS",
    "json_dump",
    "plain_text",
    "noise_at_rate",
]

log = logging.getLogger("rimu.cli")

#: attributes of a parsed namespace that name output files / output folders / input files (checked by
#: :func:`check_outputs` for every subcommand, including ones added later that follow the convention)
OUTPUT_FILE_OPTIONS = ("output", "json", "truth", "record", "side_log", "plot", "estimates", "kalibr")
OUTPUT_DIR_OPTIONS = ("report",)
INPUT_OPTIONS = ("session", "data", "calibration", "layout", "csv", "npz", "replay", "ulog")


class Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose usage errors are one line on stderr (exit status 2), naming the command."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


# ---------------------------------------------------------------- value validators (argparse ``type=``)
def _number(kind: Callable[[str], Any], text: str) -> Any:
    try:
        v = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
    if kind is float and not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return v


_N = TypeVar("_N", int, float)


def _validator(kind: Callable[[str], _N], ok: Callable[[_N], bool], rule: str, name: str, doc: str
               ) -> Callable[[str], _N]:
    """An argparse ``type=``: ``text`` read as ``kind`` (finite), then ``ok(value)`` or "must be ``rule``"."""
    def check(text: str) -> _N:
        v = _number(kind, text)
        if not ok(v):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text}")
        return v  # type: ignore[no-any-return]

    check.__name__ = check.__qualname__ = name
    check.__doc__ = doc
    return check


#: the extremes every numeric option takes: magnitudes beyond 1e12 are typing mistakes for every quantity rimu takes
#: (s, Hz, SI noise, factors), counts beyond a C int do not fit the exported code, and probabilities below 1e-15 are
#: lost in the double precision of 1 - p (above 0.5 a test decides nothing). A positive number may be as small as
#: any normal double (FLOAT_TINY, about 2.2e-308): a tactical-grade drift rate (``--selfcal-bias-rw 1e-28`` (rad/s)^2/s)
#: is a real value, not a mistake; below that its reciprocal would overflow.
FLOAT_MAX = 1e12
FLOAT_TINY = sys.float_info.min
INT_MAX = 2**31 - 1
P_MIN = 1e-15

positive_float = _validator(float, lambda v: FLOAT_TINY <= v <= FLOAT_MAX, f"> 0, between {FLOAT_TINY:.3g} and {FLOAT_MAX:g}",
                            "positive_float", "A finite number > 0 (at most 1e12).")
finite_float = _validator(float, lambda v: abs(v) <= FLOAT_MAX, f"finite, at most {FLOAT_MAX:g} in magnitude",
                          "finite_float", "A finite number (at most 1e12 in magnitude).")
nonnegative_float = _validator(float, lambda v: v == 0 or FLOAT_TINY <= v <= FLOAT_MAX,
                               f">= 0, 0 or between {FLOAT_TINY:.3g} and {FLOAT_MAX:g}", "nonnegative_float",
                               "A finite number >= 0 (at most 1e12).")
probability = _validator(float, lambda v: P_MIN <= v <= 0.5, f"a probability strictly between 0 and 1 "
                         f"(between {P_MIN:g} and 0.5: a false-alarm probability or significance level above one "
                         "half decides nothing)", "probability",
                         "A false-alarm probability or significance level, between 1e-15 and 0.5.")
positive_int = _validator(int, lambda v: 1 <= v <= INT_MAX, f"an integer >= 1 (at most {INT_MAX})", "positive_int",
                          "An integer >= 1 (at most 2**31 - 1).")
nonnegative_int = _validator(int, lambda v: 0 <= v <= INT_MAX, f"an integer >= 0 (at most {INT_MAX})",
                             "nonnegative_int", "An integer >= 0 (at most 2**31 - 1).")


def bounded_float(lo: float, hi: float, unit: str = "", why: str = "") -> Callable[[str], float]:
    """An argparse ``type=``: a finite number in ``[lo, hi]`` (``why`` says where the range comes from).

    >>> bounded_float(9.7, 9.9, "m/s^2")("9.81")
    9.81
    """
    rule = f"between {lo:g} and {hi:g}{' ' + unit if unit else ''}" + (f" ({why})" if why else "")
    return _validator(float, lambda v: lo <= v <= hi, rule, "bounded_float", f"A finite number {rule}.")


def check_samples(n: float, options: str, limit: float = 5e7, least: float = 2) -> None:
    """Refuse options whose product asks for more than ``limit`` samples (the memory of the machine) or fewer
    than ``least`` (nothing to compute).

    >>> check_samples(1e12, "--duration 1e10 at --sample-rate 100")
    Traceback (most recent call last):
    ...
    rimu.errors.OptionError: --duration 1e10 at --sample-rate 100: 1e+12 samples, more than the 5e+07 rimu holds in memory; shorten it
    """
    from ..errors import OptionError

    if not n <= limit:
        raise OptionError(f"{options}: {n:.3g} samples, more than the {limit:.3g} rimu holds in memory; shorten it")
    if n < least:
        raise OptionError(f"{options}: {n:.3g} samples, fewer than {least:g}; lengthen it")


# ---------------------------------------------------------------- deprecated spellings
class Deprecated(argparse.Action):
    """An old option spelling kept for one release: stores into ``dest`` (through ``convert``) and prints one
    deprecation line on stderr naming the new spelling."""

    def __init__(self, option_strings: list[str], dest: str, new: str = "", convert: Callable[[Any], Any] | None = None,
                 **kw: Any) -> None:
        self.new, self.convert = new, convert
        kw.setdefault("help", argparse.SUPPRESS)
        super().__init__(option_strings, dest, **kw)

    def __call__(self, parser: argparse.ArgumentParser, ns: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(f"{parser.prog}: warning: {option_string} is deprecated and will be removed in the next release; "
              f"use {self.new}", file=sys.stderr)
        if self.convert is not None:
            self.convert(ns, values)
        else:
            setattr(ns, self.dest, values)


class _JsonAction(argparse.Action):
    """``--json FILE`` (``-`` for stdout); a bare ``--json`` (the old flag) means stdout, with a deprecation line."""

    def __call__(self, parser: argparse.ArgumentParser, ns: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        if values is None:
            print(f"{parser.prog}: warning: --json without a FILE is deprecated and will be removed in the next "
                  "release; use '--json -' to print the JSON summary on stdout", file=sys.stderr)
            values = "-"
        setattr(ns, self.dest, values)


def add_json_option(p: argparse.ArgumentParser, what: str = "a machine-readable summary",
                    allow_bare: bool = False) -> None:
    """``--json FILE``: write ``what`` as JSON (``-``: stdout). ``allow_bare`` keeps the old flag spelling."""
    if allow_bare:
        p.add_argument("--json", nargs="?", const=None, default=None, action=_JsonAction, metavar="FILE",
                       help=f"write {what} as JSON to FILE ('-': stdout)")
    else:
        p.add_argument("--json", default=None, metavar="FILE", help=f"write {what} as JSON to FILE ('-': stdout)")


def add_report_option(p: argparse.ArgumentParser, what: str = "plots and reports", default: str | None = None) -> None:
    """``--report DIR``: the folder for human reports (created if needed)."""
    p.add_argument("--report", default=default, metavar="DIR", help=f"folder for {what} (created if needed)")


def add_old_out(p: argparse.ArgumentParser, name: str, also: Callable[[argparse.Namespace, str], None] | None = None
                ) -> None:
    """``--out DIR`` (old spelling of ``--report DIR --json DIR/<name>.json``), hidden; ``also(ns, DIR)`` sets
    whatever else the old option meant."""
    def convert(ns: argparse.Namespace, value: str) -> None:
        ns.report = value
        ns.json = str(Path(value) / f"{name}.json")
        if also is not None:
            also(ns, value)

    p.add_argument("--out", action=Deprecated, new="--report DIR and --json FILE", convert=convert, metavar="DIR")


#: the simulated turntable procedures ``rimu simulate`` and ``rimu design`` know: the names of
#: :data:`rimu.sim.PROCEDURES`, spelled out so that the command line starts without importing the simulator
PROCEDURES = ["cho_park", "cho_park_table1", "cho_park_table2", "oliveira_table1", "zhang"]


def add_procedure_options(p: argparse.ArgumentParser, noise: Callable[[str], float] = positive_float) -> None:
    """``--duration``, ``--sample-rate``, ``--arw``, ``--vrw``: timing and noise of a simulated procedure (the
    noise densities read by ``noise``).

    >>> from rimu.sim import PROCEDURES as simulated
    >>> PROCEDURES == list(simulated)
    True
    """
    p.add_argument("--duration", type=positive_float, default=None,
                   help="s per static position and rate step (cho_park procedures only; default 60)")
    p.add_argument("--sample-rate", type=positive_float, default=100.0, help="Hz")
    p.add_argument("--arw", type=noise, default=3.0, help="gyro angle random walk, deg/sqrt(h)")
    p.add_argument("--vrw", type=noise, default=200.0, help="accelerometer noise density, micro-g/sqrt(Hz)")


def add_readmit_options(p: Any, other: str) -> None:
    """``--readmit-after N`` and ``--no-readmit`` (of a parser or argument group); read them with
    :func:`readmit_after`. ``other`` names the command that shares the default."""
    p.add_argument("--readmit-after", type=positive_int, default=None,
                   help="clean samples before an isolated sensor is re-admitted (doubled at each further isolation; "
                        f"default rimu.fdi.health.READMIT_AFTER, as the manager and {other})")
    p.add_argument("--no-readmit", action="store_true", help="never re-admit an isolated sensor automatically")


#: the fault management's defaults as the help texts state them (tests/fdi/test_settings_defaults.py checks them
#: against rimu.fdi.settings.DEFAULTS, which the options resolve to: the parsers stay free of heavy imports)
FDI_HELP_DEFAULTS = {"p_fa": "0.001", "confirm": "3"}


def add_fdi_options(p: Any) -> None:
    """``--p-fa`` and ``--confirm`` of every command that runs the fault management; an option not given takes
    the one default of :class:`rimu.fdi.FdiSettings` (read them with :func:`fdi_settings`)."""
    p.add_argument("--p-fa", type=probability, default=None,
                   help=f"per-sample false-alarm probability of the detector (default {FDI_HELP_DEFAULTS['p_fa']}, "
                        "rimu.fdi.FdiSettings)")
    p.add_argument("--confirm", type=positive_int, default=None,
                   help="consecutive alarms naming the same sensor set before it is isolated (default "
                        f"{FDI_HELP_DEFAULTS['confirm']}, rimu.fdi.FdiSettings)")


def fdi_settings(args: argparse.Namespace, **more: Any) -> Any:
    """The :class:`rimu.fdi.FdiSettings` of the options (an option not given keeps the one default); the
    namespace's ``p_fa`` and ``confirm`` are set to the values in use."""
    from ..errors import ExportError, OptionError
    from ..fdi.settings import DEFAULTS

    try:
        st = DEFAULTS.replace(p_fa=getattr(args, "p_fa", None), confirm=getattr(args, "confirm", None), **more)
    except ExportError as exc:  # a setting out of range: name the option
        msg = str(exc)
        for name in ("readmit_after", "p_fa", "confirm", "invalid_persist", "fail_after", "clear_after"):
            msg = msg.replace(name, "--" + name.replace("_", "-"))
        raise OptionError(msg) from None
    args.p_fa, args.confirm = st.p_fa, st.confirm
    return st


def readmit_after(args: argparse.Namespace) -> int | None:
    """Clean samples before re-admission: ``--readmit-after``, else the default of every entry point
    (:data:`rimu.fdi.health.READMIT_AFTER`); None with ``--no-readmit``."""
    from ..fdi.health import READMIT_AFTER

    if args.no_readmit:
        return None
    return READMIT_AFTER if args.readmit_after is None else int(args.readmit_after)


def noise_at_rate(cal: Any, fs: float, where: str, prefix: str = "  ") -> Any:
    """The calibration with its noise at the stream's rate ``fs`` (Hz; :func:`rimu.fdi.unit.noise_at_rate`), each
    conversion said on one line: what ``rimu replay`` (``where``: "the data's") and ``rimu monitor`` (the stream's
    declared or measured rate) both do with a unit set up on averages."""
    from ..fdi.unit import noise_at_rate as convert
    from ..units import fmt

    cal, was = convert(cal, fs)
    for k, per in was.items():
        print(f"{prefix}{k}: the calibration's noise is stated for epochs of {fmt(per, 'time', 's', digits=3)}; at "
              f"{where} {fmt(fs, 'frequency', 'Hz', digits=4)} it is x{math.sqrt(per * fs):.3g} per sample (white "
              "noise: sigma sqrt(T_noise / T))")
    return cal


def add_accept_implausible(p: argparse.ArgumentParser) -> None:
    """``--accept-implausible``: turn refusals of the plausibility checks (units against gravity and commanded
    rates, sample rate against timestamps; rimu.session.checks) into warnings."""
    p.add_argument("--accept-implausible", action="store_true",
                   help="read data that fail a plausibility check (units against gravity and table rates, sample "
                        "rate against timestamps) with a warning instead of refusing them")


def json_dump(doc: Any, target: str, **kw: Any) -> str:
    """Write ``doc`` as JSON to ``target`` atomically, or print it (``-``). Returns where it went."""
    import json

    from ..atomic import write_text

    text = json.dumps(doc, indent=1, default=_json_default, **kw)
    if target == "-":
        print(text)
        return "stdout"
    Path(target).parent.mkdir(parents=True, exist_ok=True)  # inside a --report folder (checked before the work)
    write_text(target, text + "\n")
    return str(target)


def _json_default(o: Any) -> Any:
    import numpy as np

    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return str(o)


def plain_text(text: str | None) -> str | None:
    """reST markup of a docstring as plain text for the terminal: ``x`` -> 'x', :func:`a.b` -> a.b, **x** -> x.

    >>> plain_text("reads ``t`` with :func:`rimu.array.lowpass` (**zero phase**)")
    "reads 't' with rimu.array.lowpass (zero phase)"
    """
    if not text:
        return text
    import re

    text = re.sub(r":[a-z]+:`~?([^`]+)`", r"\1", text)
    text = re.sub(r"``([^`]+)``", r"'\1'", text)
    return text.replace("**", "")


# ---------------------------------------------------------------- outputs checked before work
#: commands whose -o/--output CSV is a session with its .json sidecar (a monitor's CSV of epochs has none)
SESSION_OUTPUT_COMMANDS = ("simulate", "detect")


def _sidecar(p: Path, sidecar: bool = True) -> list[Path]:
    return [p, p.with_suffix(".json")] if p.suffix == ".csv" and sidecar else [p]


def _check_file(opt: str, p: Path) -> None:
    if p.is_dir():
        raise OutputPathError(f"--{opt} {p}: is a folder; give a file name")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        raise OutputPathError(f"--{opt} {p}: the folder {parent} does not exist; create it or write elsewhere")
    if not parent.is_dir():
        raise OutputPathError(f"--{opt} {p}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK) or (p.exists() and not os.access(p, os.W_OK)):
        raise OutputPathError(f"--{opt} {p}: not writable (permission denied); write elsewhere")


def _check_dir(opt: str, p: Path) -> None:
    if p.exists() and not p.is_dir():
        raise OutputPathError(f"--{opt} {p}: exists and is not a folder")
    q = p
    while not q.exists():
        q = q.parent
    if not q.is_dir():
        raise OutputPathError(f"--{opt} {p}: {q} is a file, cannot create a folder in it")
    if not os.access(q, os.W_OK | os.X_OK):
        raise OutputPathError(f"--{opt} {p}: {q} is not writable (permission denied); write elsewhere")


def output_options(args: argparse.Namespace, files: Iterable[str] = OUTPUT_FILE_OPTIONS,
                   dirs: Iterable[str] = OUTPUT_DIR_OPTIONS) -> tuple[list[str], list[str]]:
    """The attributes of ``args`` that name output files and output folders: the convention's names, every
    ``write_*`` option, the options a command names in ``set_defaults(extra_outputs=(...))`` (an output whose name
    says input elsewhere: ``rimu setup --session``), and ``-o`` as a folder where the command says so
    (``output_is_dir``)."""
    files = list(files) + sorted(k for k in vars(args) if k.startswith("write_") and k not in files)
    files += [k for k in getattr(args, "extra_outputs", ()) if k not in files]  # set_defaults(extra_outputs=...)
    dirs = list(dirs)
    if getattr(args, "output_is_dir", False):  # a command whose main artifact is a folder (export-c)
        files.remove("output")
        dirs.append("output")
    return files, dirs


def _inputs(args: argparse.Namespace, outputs: Iterable[str], inputs: Iterable[str] | None) -> list[tuple[str, Path]]:
    """(option, path) of every input of the run: the named ``inputs``, or (None) every other string option or
    argument that names an existing file, with the sidecar of a session (``.csv`` <-> ``.json``)."""
    names = list(inputs) if inputs is not None else [k for k in vars(args) if k not in set(outputs)]
    found = []
    for name in names:
        v = getattr(args, name, None)
        if not v or v == "-" or not isinstance(v, (str, os.PathLike)):
            continue
        p = Path(v)
        for q in _sidecar(p) + ([p.with_suffix(".csv")] if p.suffix == ".json" else []):
            if q.is_file():
                found.append((name.replace("_", "-"), q))
    return found


def _same(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def check_outputs(args: argparse.Namespace, files: Iterable[str] = OUTPUT_FILE_OPTIONS,
                  dirs: Iterable[str] = OUTPUT_DIR_OPTIONS, inputs: Iterable[str] | None = None
                  ) -> tuple[list[Path], list[Path]]:
    """Refuse, before any work, output paths that cannot be written, that name the same file twice (including the
    ``.json`` sidecar of a ``-o`` session ``.csv``), or that resolve to an input of the run (symlinks, hard links
    and relative paths included; by default every option and argument naming an existing file is an input).

    The one input-protection check of every command (:func:`rimu.cli.main` calls it for all of them).

    Returns
    -------
    files, dirs : list of Path
        The planned output files (with sidecars) and folders: the :class:`rimu.atomic.OutputGroup` of the run.

    Raises
    ------
    OutputPathError

    Examples
    --------
    >>> import tempfile, os
    >>> d = Path(tempfile.mkdtemp())
    >>> _ = (d / "raw.csv").write_text("t,a\\n")
    >>> os.symlink(d / "raw.csv", d / "link.csv")
    >>> check_outputs(argparse.Namespace(raw=str(d / "raw.csv"), output=str(d / "link.csv")))
    Traceback (most recent call last):
    ...
    rimu.errors.OutputPathError: --output ... would overwrite the input .../raw.csv (raw); write the output elsewhere
    """
    files, dirs = output_options(args, files, dirs)
    planned_dirs: list[Path] = []
    for name in dirs:
        v = getattr(args, name, None)
        if v and isinstance(v, (str, os.PathLike)):
            _check_dir(name.replace("_", "-"), Path(v))
            planned_dirs.append(Path(v))
    planned = [d.resolve() for d in planned_dirs]
    seen: dict[Path, tuple[str, str, Path]] = {}
    for name in files:
        v = getattr(args, name, None)
        if not v or v == "-" or not isinstance(v, (str, os.PathLike)):
            continue
        opt = name.replace("_", "-")
        p = Path(v)
        if not any(p.parent.resolve() == d or d in p.parent.resolve().parents for d in planned):
            _check_file(opt, p)  # (a file inside a --report folder about to be created is checked with it)
        elif p.is_dir():
            raise OutputPathError(f"--{opt} {p}: is a folder; give a file name")
        session_out = name == "output" and getattr(args, "command", None) in SESSION_OUTPUT_COMMANDS
        for q in _sidecar(p, session_out):
            r = q.resolve()
            what = f"{q} (the sidecar of --{opt} {p})" if q != p else f"--{opt} {q}"
            if r in seen:
                raise OutputPathError(f"{what} would overwrite {seen[r][1]}; give them different names")
            seen[r] = (opt, what, q)
    for name, q in _inputs(args, files + dirs, inputs):
        for _opt, what, out in seen.values():
            if _same(out, q):
                raise OutputPathError(f"{what} would overwrite the input {q} ({name}); write the output elsewhere")
    return [q for _, _, q in seen.values()], planned_dirs


# ---------------------------------------------------------------- logging
class _CliHandler(logging.StreamHandler):
    """The command line's handler (a class of its own, so that a second configuration replaces it)."""


def configure_logging(command: str, verbose: int = 0, quiet: bool = False) -> None:
    """Standard ``logging`` for the ``rimu`` logger tree: warnings by default, ``-v`` info, ``-vv`` debug, ``-q``
    errors only. One line per record on stderr, prefixed with the command."""
    from .. import progress

    level = logging.ERROR if quiet else (logging.WARNING, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    root = logging.getLogger("rimu")
    for h in list(root.handlers):
        if isinstance(h, _CliHandler):
            root.removeHandler(h)
    h = _CliHandler(sys.stderr)
    h.setFormatter(_Formatter(f"rimu {command}".strip()))
    root.addHandler(h)
    root.setLevel(level)
    progress.set_enabled(not quiet)


class _Formatter(logging.Formatter):
    def __init__(self, prefix: str) -> None:
        super().__init__()
        self.prefix = prefix

    def format(self, record: logging.LogRecord) -> str:
        return f"{self.prefix}: {record.levelname.lower()}: {record.getMessage()}"
