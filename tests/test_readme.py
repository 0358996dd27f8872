"""The README's first look runs as written."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_first_look_snippet_runs(tmp_path, monkeypatch):
    code = re.search(r"## A first look\n\n```python\n(.*?)```", (ROOT / "README.md").read_text(), re.S).group(1)
    code = code.replace("duration=20.0", "duration=5.0")  # the same steps on a shorter simulation
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(code, "README.md", "exec"), ns)
    assert (tmp_path / "cal.json").exists()
    assert ns["out"]["gyro"].x.shape[1] == 3 and ns["out"]["gyro"].parity.shape[1] == 3
