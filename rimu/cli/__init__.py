"""The ``rimu`` command line. Each subcommand is a module of this package with ``register(subparsers)``;
adding one is a new file plus one line in ``COMMANDS``."""

from __future__ import annotations

import argparse
import importlib
import sys

from ..errors import RimuError

__all__ = ["main", "COMMANDS"]

#: subcommand modules, in the order ``rimu --help`` lists them
COMMANDS = [
    "demo",
    "simulate",
    "calibrate",
    "design",
    "diagnose",
    "monitor",
    "replay", "campaign", "check",
    "export_c",
]


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = argparse.ArgumentParser(prog="rimu", description="Redundant IMU calibration, fusion and FDI.")
    parser.add_argument("--version", action="version", version=f"rimu {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except RimuError as exc:
        print(f"rimu {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"rimu {args.command}: interrupted", file=sys.stderr)
        return 130
