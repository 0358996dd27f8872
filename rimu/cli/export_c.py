"""``rimu export-c``: write a calibration's runtime (compensation, projection, covariance, parity) as C99."""

from __future__ import annotations

import argparse
import shutil
import subprocess
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export-c", help="write the runtime of a calibration as dependency-free C99",
                       description="Write rimu_unit.h/.c (the runtime: no dynamic memory, only <math.h>), a CSV "
                                   "filter program rimu_filter.c and a Makefile for one calibrated unit. See "
                                   "docs/flying.md.")
    p.add_argument("calibration", help="calibration file (rimu calibrate -o ...)")
    p.add_argument("-o", "--output", required=True, help="directory to write the C sources into")
    p.add_argument("--real", choices=("double", "float"), default="double",
                   help="floating-point type of the generated code (float for FPUs without double)")
    p.add_argument("--build", action="store_true", help="also build rimu_filter with the system C compiler")
    p.set_defaults(func=run, output_is_dir=True)  # -o names a folder (rimu.cli._common.check_outputs)


def run(args: argparse.Namespace) -> int:
    from ..calibration.result import Calibration
    from ..export import export_c

    cal = Calibration.load(args.calibration)
    files = export_c(cal, args.output, real=args.real)
    msg = f"wrote {', '.join(f.name for f in files)} to {Path(args.output)} ({args.real})"
    if args.build:
        cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
        if cc is None:
            print(f"{msg}; not built: no C compiler found (install gcc or clang, then run make in {args.output})")
            return 1
        res = subprocess.run(["make", "-s", f"CC={cc}"], cwd=args.output, capture_output=True, text=True)
        if res.returncode != 0:
            print(res.stderr.strip())
            print(f"{msg}; the build failed (above)")
            return 1
        msg += f"; built {Path(args.output) / 'rimu_filter'}"
    print(msg)
    return 0
