"""Fixtures of the hostile-input battery (tests/cli/battery.py): the valid inputs, made once, and an empty output
folder per test."""

from __future__ import annotations

from pathlib import Path

import pytest

from . import battery


@pytest.fixture(scope="session")
def inp(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("battery-in")
    battery.make_inputs(d)
    return d


@pytest.fixture
def out(tmp_path) -> Path:
    d = tmp_path / "out"
    d.mkdir()
    return d
