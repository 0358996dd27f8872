"""Every module that needs numba to import is left out of the doctest collection when numba is missing (the root
conftest.py), so that a numpy-only install runs the suite: the list there must name each of them."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _needs_numba(path: Path) -> bool:
    """A module whose top level imports numba inside ``try`` and raises ImportError without it."""
    tree = ast.parse(path.read_text())
    for node in tree.body:
        if isinstance(node, ast.Try) and any(isinstance(n, ast.Import) and any(a.name == "numba" for a in n.names)
                                             for n in node.body):
            return any(isinstance(n, ast.Raise) for h in node.handlers for n in ast.walk(h))
    return False


def test_the_conftest_ignores_every_numba_only_module():
    text = (ROOT / "conftest.py").read_text()
    found = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "rimu").rglob("*.py") if _needs_numba(p))
    assert found, "no numba-only module found: the scan is wrong"
    missing = [f for f in found if f'"{f}"' not in text]
    assert not missing, f"add {missing} to collect_ignore in conftest.py"
