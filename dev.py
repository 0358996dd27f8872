#!/usr/bin/env python3
"""Set up and run rimu on a fresh machine that has only Python (>= 3.10) and pip.

    python3 dev.py demo     # create .venv, install rimu, run the end-to-end demo
    python3 dev.py test     # create .venv, install rimu with test extras, run the test suite
    python3 dev.py bench    # run the benchmarks (prints tables and JSON)

The virtual environment lives in .venv beside this file and is reused on later calls.
"""

from __future__ import annotations

import os
import subprocess
import sys
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent
VENV = ROOT / ".venv"
BIN = VENV / ("Scripts" if os.name == "nt" else "bin")
PY = BIN / ("python.exe" if os.name == "nt" else "python")
STAMP = VENV / ".rimu-installed"


def ensure_env(extras: str) -> None:
    if not PY.exists():
        print(f"[dev] creating virtual environment in {VENV}", flush=True)
        # system site packages let an already-installed numpy/scipy be reused; pip installs what is missing
        venv.EnvBuilder(with_pip=True, system_site_packages=True).create(VENV)
    want = f"{extras}:{(ROOT / 'pyproject.toml').stat().st_mtime}"
    if STAMP.exists() and STAMP.read_text() == want:
        return
    print(f"[dev] installing rimu[{extras}] (editable)", flush=True)
    subprocess.check_call([str(PY), "-m", "pip", "install", "-q", "--disable-pip-version-check", "-e", f".[{extras}]"],
                          cwd=ROOT)
    STAMP.write_text(want)


def run(args: list[str], single_thread_blas: bool = False) -> int:
    env = dict(os.environ)
    if single_thread_blas:
        # the suite runs many small matrix products; a threaded BLAS on 2 cores only oversubscribes them
        for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            env.setdefault(k, "1")
    return subprocess.call([str(PY), *args], cwd=ROOT, env=env)


def main(argv: list[str]) -> int:
    cmd = argv[0] if argv else "help"
    rest = argv[1:]
    if cmd == "demo":
        ensure_env("plots")
        return run(["-m", "rimu.cli", "demo", *rest])
    if cmd == "test":
        ensure_env("test")
        return run(["-m", "pytest", *rest], single_thread_blas=True)
    if cmd == "bench":
        ensure_env("test,bench")
        code = 0
        for b in sorted((ROOT / "benchmarks").glob("*.py")):
            print(f"[dev] benchmark {b.name}", flush=True)
            code |= run([str(b), *rest])
        return code
    print(__doc__)
    return 0 if cmd in ("help", "-h", "--help") else 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
