"""``python -m eponet.run spec.yaml [--set KEY=VALUE ...] [--no-cache] [-q] [-v]``: run a pipeline spec."""

from eponet.cli import run_main

if __name__ == "__main__":
    raise SystemExit(run_main())
