"""Two k-fold reports (``benchmarks/kfold.py``'s ``kfold.json``) side by side: per sequence, the mean, the
worst, and per DAVIS attribute, each measure of A and of B and their difference B - A, over the sequences both
scored. Usage::

    python benchmarks/kfold_compare.py runs/kfold-epo-before/kfold.json runs/kfold-epo-newed/kfold.json [--measure J]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from kfold import ATTRIBUTES, attributes  # noqa: E402

#: Measures where a lower value is better (DAVIS temporal stability).
LOWER_IS_BETTER = ("T",)


def compare(a: dict[str, dict], b: dict[str, dict], measure: str, attrs: dict[str, list[str]],
            wanted: tuple[str, ...] = ATTRIBUTES) -> str:
    """A plain-text table of ``measure`` in reports ``a`` and ``b`` (sequence -> row) and ``b - a``."""
    names = sorted(n for n in set(a) & set(b) if a[n].get(measure) is not None and b[n].get(measure) is not None)
    lines = [f"{'sequence':<18}{'fold':>5}{'A':>8}{'B':>8}{'B-A':>8}  attributes"]
    for n in names:
        lines.append(f"{n:<18}{a[n]['fold']:>5}{a[n][measure]:>8.3f}{b[n][measure]:>8.3f}"
                     f"{b[n][measure] - a[n][measure]:>+8.3f}  {' '.join(attrs.get(n, []))}")

    def row(label, members, reduce=np.mean):
        va = reduce([a[n][measure] for n in members])
        vb = reduce([b[n][measure] for n in members])
        return f"{label:<18}{len(members):>5}{va:>8.3f}{vb:>8.3f}{vb - va:>+8.3f}"

    if names:
        lines.append(row("mean", names))
        lines.append(row("worst", names, np.min))
        sign = -1 if measure in LOWER_IS_BETTER else 1
        better = sum(sign * (b[n][measure] - a[n][measure]) > 0.005 for n in names)
        worse = sum(sign * (b[n][measure] - a[n][measure]) < -0.005 for n in names)
        lines.append(f"{'B better / worse':<18}{'':>5}{better:>8}{worse:>8}   (by more than 0.005)")
        for attr in wanted:
            members = [n for n in names if attr in attrs.get(n, [])]
            if members:
                lines.append(row(f"attr {attr}", members))
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("a", type=Path)
    parser.add_argument("b", type=Path)
    parser.add_argument("--measure", default="J")
    parser.add_argument("--attributes", nargs="*", default=list(ATTRIBUTES))
    args = parser.parse_args(argv)
    a, b = (json.loads(p.read_text())["sequences"] for p in (args.a, args.b))
    print(compare(a, b, args.measure, attributes(), tuple(args.attributes)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
