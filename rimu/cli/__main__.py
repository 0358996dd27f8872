"""``python -m rimu.cli`` works like the ``rimu`` command."""

from . import main

raise SystemExit(main())
