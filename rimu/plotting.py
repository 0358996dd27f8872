"""matplotlib for rimu's figures: the headless Agg backend, and one clear message when the extra is missing."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

__all__ = ["pyplot", "save_figure"]


def pyplot(optional: bool = False) -> Any:
    """``matplotlib.pyplot`` on the Agg backend (no screen needed).

    Without matplotlib: None when ``optional`` (the caller skips its figure), else ImportError naming the
    extra to install.
    """
    try:
        import matplotlib
    except ImportError as exc:  # pragma: no cover - depends on the environment
        if optional:
            return None
        raise ImportError("plots need matplotlib: pip install 'rimu[plots]'") from exc
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 110) -> Path:
    """Write ``fig`` to ``path`` whole or not at all (:func:`rimu.atomic.atomic_path`), close it, return the path."""
    import matplotlib.pyplot as plt

    from .atomic import atomic_path

    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi)
    plt.close(fig)
    return path
