"""``python -m eponet.run spec.yaml [--set KEY=VALUE ...] [--no-cache] [-q] [-v]``: run a pipeline spec."""

import sys

from eponet.cli import run_main

if __name__ == "__main__":
    raise SystemExit(run_main())
if __name__ == "eponet.run":
    # imported rather than run: ``eponet.run`` stays the API function (the import system binds the package's
    # attribute to what sys.modules holds), not this module
    from eponet.api import run

    sys.modules[__name__] = run
