from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def shared_data(name: str, needs: str | None = None) -> Path:
    """A folder of ../shared/data (holding the file ``needs``, when given), or skip the test when it is absent."""
    for base in (ROOT / ".." / "shared" / "data", Path("/work/shared/data")):
        p = (base / name).resolve()
        if p.exists() and (needs is None or (p / needs).exists()):
            return p
    pytest.skip(f"shared data {name!r} is not available on this machine")
