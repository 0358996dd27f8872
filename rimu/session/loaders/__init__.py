"""Loaders of third-party recordings, one module per format; each returns a :class:`rimu.session.Session`.

Adding a format: one new module here plus one import line below.
"""

from .ferraris import FERRARIS_SECTIONS, load_ferraris

__all__ = ["FERRARIS_SECTIONS", "load_ferraris"]
