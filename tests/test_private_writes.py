"""Each piece of state has one owner: no module writes another object's private fields (``obj._x = ...``,
``obj._x[i] = ...``, ``obj._x += ...``, for ``obj`` other than ``self``/``cls``). The isolation set of a unit, for
one, belongs to its runtime (rimu.fdi.Runtime): the pipeline gets it as an argument, nobody writes the
pipeline's fields (the former ``sync_pipeline``)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "rimu"

#: writes inside one room (a part's own helper objects, of classes of the same part), with the reason. Any other
#: write to another object's private field fails the test.
WITHIN_ROOM = {
    ("rimu/io/can.py", "a"): "io: the frame processor's vectorised path advances its own EpochAssembler",
    ("rimu/diagnose/candidates.py", "ct"): "diagnose: the ranking fills the CandidateTest it has just built",
}


def _private_writes(path: Path) -> list[tuple[int, str, str]]:
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        targets = node.targets if isinstance(node, ast.Assign) else \
            [node.target] if isinstance(node, (ast.AugAssign, ast.AnnAssign)) else []
        stack = list(targets)
        while stack:
            t = stack.pop()
            if isinstance(t, (ast.Tuple, ast.List)):
                stack.extend(t.elts)
                continue
            if isinstance(t, ast.Subscript):  # obj._x[i] = ...
                t = t.value
            if isinstance(t, ast.Attribute) and t.attr.startswith("_") and not t.attr.startswith("__"):
                owner = ast.unparse(t.value)
                if owner not in ("self", "cls"):
                    out.append((node.lineno, owner, t.attr))
    return out


def test_nobody_writes_another_objects_private_fields():
    found = []
    for p in sorted(PKG.rglob("*.py")):
        rel = p.relative_to(ROOT).as_posix()
        for line, owner, attr in _private_writes(p):
            if (rel, owner) not in WITHIN_ROOM:
                found.append(f"{rel}:{line}: {owner}.{attr}")
    assert not found, "writes to another object's private fields:\n" + "\n".join(found)


def test_the_check_catches_a_planted_write(tmp_path):
    planted = tmp_path / "planted.py"
    planted.write_text("def sync(mgr, pipe):\n    pipe._isolated[:] = mgr.iso\n    pipe._n, x = 1, 2\n"
                       "    self._ok = 1\n")
    assert sorted((o, a) for _, o, a in _private_writes(planted)) == [("pipe", "_isolated"), ("pipe", "_n")]


def _room(p: Path) -> str:
    return p.relative_to(PKG).parts[0].removesuffix(".py")


#: private names read across rooms, with the reason (each one is a port that should read a public form instead)
CROSS_ROOM_READS = {
    ("export", "c"): ("the C port of the effects' compensation (rimu.export.c_effects) reads the coefficient arrays "
                      "of rimu.fusion.EffectCompensation; guarded decision for decision by tests/export/"
                      "test_c_effects.py"),
    # not rimu rooms: the private fields of third-party objects (fragile across their releases, but no rimu state)
    ("cli", "sub"): "argparse's subparsers action (_choices_actions), for the grouped --help",
    ("cli", "p"): "argparse's parser (_actions), for the grouped --help",
    ("report", "fig"): "matplotlib's figure title (_suptitle)",
}


def test_no_room_reaches_into_another_rooms_private_fields():
    """A private name (``obj._x``, ``obj`` other than self/cls) used in a room (a part of rimu) must be one that
    room defines itself: the runtime (fdi) no longer reaches into the pipeline's ``_order``,
    ``_compensate_block``, ``_isolated`` or its counters, nor the CLI into the managers."""
    trees = {p: ast.parse(p.read_text(), filename=str(p)) for p in sorted(PKG.rglob("*.py"))}
    defined: dict[str, set[str]] = {}
    for p, tree in trees.items():
        d = defined.setdefault(_room(p), set())
        for n in ast.walk(tree):
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and n.name.startswith("_"):
                d.add(n.name)
            elif isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Store) \
                    and ast.unparse(n.value) in ("self", "cls"):
                d.add(n.attr)
            elif isinstance(n, ast.Name) and isinstance(n.ctx, ast.Store) and n.id.startswith("_"):
                d.add(n.id)
    found = []
    for p, tree in trees.items():
        r = _room(p)
        for n in ast.walk(tree):
            if isinstance(n, ast.Attribute) and n.attr.startswith("_") and not n.attr.startswith("__"):
                owner = ast.unparse(n.value)
                if owner in ("self", "cls", "argparse") or n.attr in defined[r] or (r, owner) in CROSS_ROOM_READS:
                    continue
                found.append(f"{p.relative_to(ROOT)}:{n.lineno}: {owner}.{n.attr}")
    assert not found, "private fields of another room:\n" + "\n".join(found)
