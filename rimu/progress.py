"""Progress bars for long runs (calibration Monte Carlo, diagnosis of many candidates, long replays, campaigns).

tqdm draws them when it is installed (extra ``progress``: ``pip install rimu[progress]``); without it, and when
stderr is not a terminal, they degrade silently to nothing. The command line switches them off with ``-q``
(:func:`set_enabled`).

>>> list(bar(range(3), desc="demo", enabled=False))
[0, 1, 2]
"""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import Any

__all__ = ["bar", "set_enabled", "enabled"]

_ENABLED = True


def set_enabled(on: bool) -> None:
    """Switch every progress bar of this process on (the default: shown on a terminal) or off."""
    global _ENABLED
    _ENABLED = bool(on)


def enabled() -> bool:
    """Whether progress bars may be shown."""
    return _ENABLED


def bar(it: Iterable[Any], total: int | None = None, desc: str = "", unit: str = "it",
        enabled: bool | None = None) -> Iterator[Any]:
    """Iterate ``it`` with a progress bar on stderr (tqdm, only on a terminal); the items unchanged.

    Parameters
    ----------
    enabled : bool, optional
        False: no bar. None (default): a bar if bars are switched on and stderr is a terminal.
    """
    on = _ENABLED if enabled is None else bool(enabled)
    if on:
        try:
            from tqdm import tqdm
        except ImportError:
            on = False
    if not on:
        yield from it
        return
    yield from tqdm(it, total=total, desc=desc, unit=unit, file=sys.stderr, disable=None if enabled is None else False,
                    leave=False)
