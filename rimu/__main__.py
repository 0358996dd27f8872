"""``python -m rimu`` works like the ``rimu`` command."""

from .cli import main

raise SystemExit(main())
