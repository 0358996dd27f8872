"""The ``rimu`` command line. Each subcommand is a module of this package with ``register(subparsers)``;
adding one is a new file plus one line in ``COMMANDS``.

Every subcommand follows one option convention (``-o/--output`` main artifact, ``--report DIR`` human reports,
``--json FILE`` machine-readable summary; docs/cli.md) and one error path: rimu's exceptions, OS errors and
missing extras end in one line on stderr saying what was wrong and what to do. Exit status: 0 success, 1 a check
that ran and failed, 2 bad input or options, 3 an internal error (a bug: rerun with ``--debug`` and report it),
130 interrupted (Ctrl-C). ``--debug`` shows the traceback instead of the one line.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import logging
import os
import sys
import warnings

from ..errors import RimuError
from ._common import Parser, check_outputs, configure_logging, plain_text

__all__ = ["main", "COMMANDS", "build_parser", "EXIT_OK", "EXIT_CHECK_FAILED", "EXIT_BAD_INPUT", "EXIT_INTERNAL",
           "EXIT_INTERRUPTED"]

#: subcommand modules, in the order ``rimu --help`` lists them
COMMANDS = [
    "demo",
    "simulate",
    "calibrate",
    "design",
    "diagnose",
    "monitor",
    "replay", "campaign", "check",
    "detect",
    "noise",
    "export_c",
    "array",
    "import_",
    "setup",
    "apply",
    "selfcal",
]

EXIT_OK = 0
EXIT_CHECK_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERNAL = 3
EXIT_INTERRUPTED = 130

log = logging.getLogger("rimu.cli")

#: optional modules and the extra that installs them (pyproject.toml)
_EXTRAS = {"matplotlib": "plots", "pywt": "wavelets", "cantools": "dbc", "pyulog": "ulog", "distributed": "distributed",
           "dask": "distributed", "tqdm": "progress", "pymavlink": "logs",
           "rosbags": "logs", "zstandard": "logs", "imucal": "bench"}


def _common_options(p: argparse.ArgumentParser, top: bool) -> None:
    # on the subcommands the defaults are SUPPRESS so that `rimu -v calibrate` and `rimu calibrate -v` both work
    kw = {} if top else {"default": argparse.SUPPRESS}
    p.add_argument("-v", "--verbose", action="count", help="more log output (-vv: debug)", **({"default": 0} if top else kw))
    p.add_argument("-q", "--quiet", action="store_true", help="errors only, no progress bars",
                   **({"default": False} if top else kw))
    p.add_argument("--debug", action="store_true", help="show the Python traceback of an error",
                   **({"default": False} if top else kw))


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = Parser(prog="rimu", description="Redundant IMU calibration, fusion and FDI.",
                    epilog="Options: -o/--output FILE main artifact, --report DIR reports and plots, --json FILE "
                           "summary ('-': stdout). Exit status: 0 ok, 1 check failed, 2 bad input, 3 internal error, "
                           "130 interrupted. See docs/cli.md.")
    parser.add_argument("--version", action="version", version=f"rimu {__version__}")
    _common_options(parser, top=True)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    for p in sub.choices.values():
        _common_options(p, top=False)
        _plain_help(p)
    for a in sub._choices_actions:
        a.help = plain_text(a.help)
    return parser


def _plain_help(p: argparse.ArgumentParser) -> None:
    """Help texts as a terminal shows them: the module docstrings' reST markup (``code``, :func:`x`) removed."""
    p.description = plain_text(p.description)
    p.epilog = plain_text(p.epilog)
    for a in p._actions:
        a.help = plain_text(a.help)


def _describe(exc: BaseException) -> tuple[str, int]:
    """The one line and exit status of an exception that ends a command."""
    if isinstance(exc, RimuError):
        return str(exc), EXIT_BAD_INPUT
    if isinstance(exc, ImportError):
        mod = (getattr(exc, "name", None) or "").split(".")[0]
        extra = _EXTRAS.get(mod)
        if "pip install" in str(exc):
            return str(exc), EXIT_BAD_INPUT
        how = f"pip install 'rimu[{extra}]'" if extra else "install the extra the message names"
        return f"{exc} (an optional dependency is missing: {how})", EXIT_BAD_INPUT
    if type(exc).__module__.split(".")[0] in ("can", "serial", "distributed"):  # device/cluster libraries
        return (f"{exc} ({type(exc).__name__}); check the interface or address and that the device is there",
                EXIT_BAD_INPUT)
    if isinstance(exc, OSError):
        name = getattr(exc, "filename", None)
        why = exc.strerror or str(exc)
        return (f"{name}: {why}" if name else why) + "; check the path and permissions", EXIT_BAD_INPUT
    if isinstance(exc, (ValueError, KeyError)):
        # the library validates its arguments with ValueError; the CLI checks its options first, so this is a
        # value rimu could not use
        msg = exc.args[0] if isinstance(exc, KeyError) and exc.args else exc
        return f"{msg}", EXIT_BAD_INPUT
    return (f"internal error {type(exc).__name__}: {exc}; this is a bug in rimu: rerun with --debug and report the "
            "traceback", EXIT_INTERNAL)


@contextlib.contextmanager
def _promises(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    """What ``-q`` promises (errors only: the results a command prints go nowhere, except a ``--json -`` asked
    for on stdout), and Python warnings (matplotlib's, numpy's) as one log line each, none under ``-q``."""
    wlog = logging.getLogger("rimu.warnings")

    def show(message, category, filename, lineno, file=None, line=None):  # type: ignore[no-untyped-def]
        wlog.warning("%s", str(message).splitlines()[0] if str(message) else category.__name__)

    with warnings.catch_warnings():
        warnings.showwarning = show
        if getattr(args, "quiet", False) and getattr(args, "json", None) != "-":
            with open(os.devnull, "w") as null, contextlib.redirect_stdout(null):
                yield
        else:
            yield


def main(argv: list[str] | None = None) -> int:
    """Run ``rimu`` with ``argv`` (default ``sys.argv[1:]``) and return the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a usage error (already printed as one line)
        return exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_BAD_INPUT
    configure_logging(args.command, args.verbose, args.quiet)
    log.debug("arguments: %s", {k: v for k, v in vars(args).items() if k != "func"})
    from ..atomic import OutputGroup

    group: OutputGroup | None = None
    try:
        files, dirs = check_outputs(args)
        # every output of the run appears together at the end, or none (rimu.atomic): a refusal (exit 2), an
        # error or Ctrl-C removes the temporaries and whatever the run created
        group = OutputGroup(files, dirs).activate()
        with _promises(args):
            code = int(args.func(args) or 0)
        if code >= EXIT_BAD_INPUT:
            group.abort()
        else:
            group.commit()
        return code
    except BrokenPipeError:  # `rimu ... | head`: the reader left; nothing to say
        _finish(group, ok=True)
        try:
            sys.stdout = open(os.devnull, "w")
        except OSError:
            pass
        return EXIT_OK
    except KeyboardInterrupt:
        left = _finish(group, ok=False)
        if args.debug:
            raise
        if left:
            print(f"rimu {args.command}: interrupted; could not undo {', '.join(map(str, left))} (an existing file "
                  "the run had already replaced, or one that could not be removed)", file=sys.stderr)
        else:
            print(f"rimu {args.command}: interrupted; no partial output file was left behind", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Exception as exc:  # one line, the traceback only with --debug
        left = _finish(group, ok=False)
        if args.debug:
            raise
        msg, code = _describe(exc)
        if (isinstance(exc, OSError) and exc.errno in _FULL and not getattr(exc, "filename", None)
                and group is not None and group.folders()):
            # a write failed (a full disk): the file object does not know its name, the run knows its folders
            where = ", ".join(map(str, group.folders()))
            msg = f"{exc.strerror or exc} while writing the outputs in {where}; free some space or write elsewhere"
        if left:
            msg += f" (could not undo {', '.join(map(str, left))})"
        print(f"rimu {args.command}: error: {msg}", file=sys.stderr)
        return code
    finally:  # SystemExit and the like: the run's outputs are undone too
        if group is not None and not group.done:
            group.abort()


#: errno of a write that found no room (a full disk, a quota, a file too large)
_FULL = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG}


def _finish(group: object, ok: bool) -> list:
    """Commit (``ok``) or abort the run's outputs; what could not be undone."""
    if group is None:
        return []
    if ok:
        group.commit()  # type: ignore[attr-defined]
        return []
    return list(group.abort())  # type: ignore[attr-defined]
