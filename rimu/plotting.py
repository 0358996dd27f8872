"""matplotlib for rimu's figures: the headless Agg backend, and one clear message when the extra is missing."""

from __future__ import annotations

from typing import Any

__all__ = ["pyplot"]


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
