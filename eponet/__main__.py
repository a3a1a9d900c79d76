"""``python -m eponet``: the ``eponet`` command line."""

from eponet.cli import main

raise SystemExit(main())
