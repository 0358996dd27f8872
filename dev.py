#!/usr/bin/env python3
"""Set up and run rimu on a fresh machine that has only Python (>= 3.10) and pip.

    python3 dev.py demo     # create .venv, install rimu, run the end-to-end demo
    python3 dev.py test     # create .venv, install rimu with test extras, run the test suite
    python3 dev.py bench [NAME ...]  # run the benchmarks, record them, regenerate benchmarks/RESULTS.md

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


def bench(names: list[str]) -> int:
    """Run the benchmarks (all, or those named), record each one's output in benchmarks/results/NAME.json with
    the machine, date and command, and render benchmarks/RESULTS.md from every record."""
    import datetime
    import json
    import platform
    import time

    bdir = ROOT / "benchmarks"
    skip = {"render_results", "imucal_reference"}  # the renderer; a reference script run by hand (see its doc)
    # (modules starting with "_" are shared helpers, not benchmarks)
    scripts = [b for b in sorted(bdir.glob("*.py"))
               if b.stem not in skip and not b.stem.startswith("_") and (not names or b.stem in names)]
    unknown = set(names) - {b.stem for b in scripts}
    if unknown:
        print(f"[dev] no benchmark called {sorted(unknown)}; known: {sorted(b.stem for b in bdir.glob('*.py'))}")
        return 2
    (bdir / "results").mkdir(exist_ok=True)
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    machine = f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}"
    code = 0
    for b in scripts:
        print(f"[dev] benchmark {b.name}", flush=True)
        t0 = time.perf_counter()
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
        proc = subprocess.Popen([str(PY), str(b)], cwd=ROOT, env=env, stdout=subprocess.PIPE, text=True)
        lines = []
        for line in proc.stdout:  # echo as it runs, keep for the record
            print(line, end="", flush=True)
            lines.append(line.rstrip("\n"))
        status = proc.wait()
        code |= status
        data, table = None, lines
        for k in range(len(lines) - 1, -1, -1):
            try:
                data = json.loads(lines[k])
            except ValueError:
                continue
            if isinstance(data, dict):
                table = lines[:k] + lines[k + 1:]
                break
            data = None
        doc = ""
        import ast
        try:
            doc = (ast.get_docstring(ast.parse(b.read_text())) or "").strip().split("\n\n")[0]
        except SyntaxError:
            pass
        rec = {"name": b.stem, "summary": " ".join(doc.split()), "command": f"python3 dev.py bench {b.stem}",
               "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
               "machine": machine, "seconds": time.perf_counter() - t0, "exit_status": status,
               "output": "\n".join(table), "json": data}
        tmp = bdir / "results" / f".{b.stem}.json.tmp"
        tmp.write_text(json.dumps(rec, indent=1) + "\n")
        os.replace(tmp, bdir / "results" / f"{b.stem}.json")
    code |= run([str(bdir / "render_results.py")])
    return code


def main(argv: list[str]) -> int:
    cmd = argv[0] if argv else "help"
    rest = argv[1:]
    if cmd == "demo":
        ensure_env("plots")
        return run(["-m", "rimu.cli", "demo", *rest])
    if cmd == "test":
        ensure_env("test")
        # one worker per core (pytest-xdist): the suite is ~7 min of CPU and CI has 2 cores; `-n 0` runs it serially
        workers = [] if any(a == "-n" or a.startswith(("-n", "--numprocesses")) for a in rest) else ["-n", "auto"]
        return run(["-m", "pytest", *workers, *rest], single_thread_blas=True)
    if cmd == "bench":
        ensure_env("test,bench")
        return bench(rest)
    print(__doc__)
    return 0 if cmd in ("help", "-h", "--help") else 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
