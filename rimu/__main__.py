"""``python -m rimu`` works like the ``rimu`` command.

Run from a folder that holds a checkout named ``rimu`` (no ``__init__.py`` at its top), Python imports that folder
as a namespace package ``rimu`` and the installed package's modules are not found; this file is the installed
package's own, so it puts its package first and imports it again.
"""

import os
import sys

if getattr(sys.modules.get("rimu"), "__file__", None) is None:  # a namespace 'rimu' from the current folder
    _root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for _name in [m for m in sys.modules if m == "rimu" or m.startswith("rimu.")]:
        del sys.modules[_name]
    sys.path.insert(0, _root)
    from rimu.cli import main
else:
    from .cli import main

raise SystemExit(main())
