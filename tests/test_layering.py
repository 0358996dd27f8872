"""The house keeps its layering: imports point one way along the data's path, and no module import circles.

The order is documented in docs/architecture.md. Every import statement of rimu/ (at module level and inside
functions alike) is parsed; relative imports are resolved to absolute module names.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "rimu"

#: stage of each top-level part of rimu on the data's path; a module may import its own stage or earlier ones
STAGE = {
    "errors": 0, "plotting": 0, "report": 0, "units": 0, "epoch": 0, "geometry": 0, "py.typed": 0,   # foundations
    "atomic": 0, "progress": 0,                                           # atomic writes, progress bars
    "_backend": 0,       # numpy or numba: the generic backend choice (runtime and calibration kernels)
    "io": 1,             # raw data in
    "session": 2, "session_io": 2,
    "calibration": 3,
    "diagnose": 4,
    "noise": 0,          # IEEE 952 noise model + Allan analysis: imports only foundations; calibration files hold it
    "array": 5,
    "fusion": 5,
    "fdi": 6,
    "export": 7,
    "sim": 8,            # the simulator: imports the models it simulates; imported only by the leaves below
    "experiments": 9,    # the harness above the runtime: faults, campaigns, scenarios, validation, quality reports
    "cli": 10, "__main__": 10, "__init__": 10,
}
#: parts that nobody may import, whatever their stage (beyond the leaves listed)
NO_IMPORT_FROM = {
    "sim": {"cli", "__main__", "sim"},
    "io": {"io", "session", "cli", "__main__", "__init__"},  # fusion and fdi never import io
    "experiments": {"experiments", "cli", "__main__", "__init__"},  # the runtime never imports the harness
}
#: leaves allowed to import sim besides the CLI: fault campaigns and the demo-like report builders
SIM_USERS = {"rimu.experiments.campaign"}
#: deprecated aliases kept for one release; each is the only module of its part allowed to break the order
DEPRECATED_ALIASES = {"rimu.calibration.diagnostics": "rimu.diagnose"}


def _modules() -> dict[str, Path]:
    out = {}
    for p in PKG.rglob("*.py"):
        rel = p.relative_to(ROOT).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    is_pkg = path.name == "__init__.py"
    base = name.split(".") if is_pkg else name.split(".")[:-1]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names if a.name.split(".")[0] == "rimu")
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                mod = ".".join(base[: len(base) - node.level + 1] + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod.split(".")[0] != "rimu":
                continue
            for a in node.names:  # "from pkg import submodule" targets the submodule
                sub = f"{mod}.{a.name}"
                out.add(sub if sub in MODULES else mod)
    return {m for m in out if m != name}


def _part(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


GRAPH = {m: _imports(m, p) for m, p in MODULES.items()}


def test_every_part_has_a_stage():
    unknown = sorted({_part(m) for m in MODULES} - set(STAGE))
    assert not unknown, f"place these parts of rimu on the data's path in STAGE and docs/architecture.md: {unknown}"


def _violations() -> list[str]:
    bad = []
    for m, targets in GRAPH.items():
        pm = _part(m)
        for t in targets:
            pt = _part(t)
            if pm == pt:
                continue
            if DEPRECATED_ALIASES.get(m) and t.startswith(DEPRECATED_ALIASES[m]):
                continue
            if pt in NO_IMPORT_FROM and pm not in NO_IMPORT_FROM[pt] and m not in SIM_USERS | {"rimu"}:
                bad.append(f"{m} imports {t}: nothing in {pm} may import {pt}")
            elif STAGE[pt] > STAGE[pm] and not (pt == "sim" and m in SIM_USERS):
                bad.append(f"{m} (stage {STAGE[pm]}, {pm}) imports {t} (stage {STAGE[pt]}, {pt}): a later stage")
    return sorted(bad)


def test_imports_point_one_way_along_the_data_path():
    bad = _violations()
    assert not bad, "layering broken:\n" + "\n".join(bad)


def test_calibration_does_not_import_diagnose_fusion_or_fdi():
    bad = [f"{m} -> {t}" for m, ts in GRAPH.items() if _part(m) == "calibration" and m not in DEPRECATED_ALIASES
           for t in ts if _part(t) in ("diagnose", "fusion", "fdi", "sim", "cli")]
    assert not bad


def _cycles() -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in GRAPH.get(v, ()):
            if w not in GRAPH:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(GRAPH):
        if v not in index:
            visit(v)
    return out


def test_no_import_circles():
    cycles = _cycles()
    assert not cycles, "import circles (break them with a small shared module):\n" + "\n".join(
        " <-> ".join(c) for c in cycles)


@pytest.mark.parametrize("bad", [("rimu.fusion.x", "rimu.io.base"), ("rimu.calibration.x", "rimu.fdi.manager"),
                                 ("rimu.io.x", "rimu.calibration.result"), ("rimu.calibration.x", "rimu.sim"),
                                 ("rimu.fdi.manager", "rimu.experiments.campaign"), ("rimu.fusion.x", "rimu.sim"),
                                 ("rimu.fdi.x", "rimu.sim")])
def test_the_rule_catches_a_violation(bad, monkeypatch):
    """The checker itself can fail: a planted bad import is reported."""
    m, t = bad
    monkeypatch.setitem(GRAPH, m, {t})
    assert any(v.startswith(m) for v in _violations())


def test_the_circle_finder_finds_a_planted_circle(monkeypatch):
    monkeypatch.setitem(GRAPH, "rimu.diagnose.residuals", GRAPH["rimu.diagnose.residuals"] | {"rimu.diagnose.api"})
    assert any("rimu.diagnose.residuals" in c for c in _cycles())
