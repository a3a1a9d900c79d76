"""A setting chosen without looking at the sequences it is reported on: several k-fold reports of the same folds
(``benchmarks/kfold.py``'s ``kfold.json``, one per setting), and for each fold the setting whose mean J over the
other folds' sequences is best; that fold's sequences are reported with it (nested J, and the F and T of the same
runs). Usage::

    python benchmarks/kfold_nested.py runs/kfold-a/kfold.json runs/kfold-b/kfold.json ... [--labels a,b,...]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from crf_speed_sweep import nested  # noqa: E402
from kfold import attributes, report  # noqa: E402


def nested_report(reports: list[dict], labels: list[str]) -> str:
    """The per-setting means, the setting chosen per fold on the other folds, and the nested table."""
    names = sorted(set.intersection(*(set(r["sequences"]) for r in reports)))
    folds = [[n for n in names if reports[0]["sequences"][n]["fold"] == i]
             for i in range(max(reports[0]["sequences"][n]["fold"] for n in names) + 1)]
    rows = {n: {"J": [r["sequences"][n]["J"] for r in reports]} for n in names}
    chosen, _ = nested(rows, folds, lambda others: int(np.argmax([np.mean([rows[n]["J"][k] for n in others])
                                                                   for k in range(len(reports))])))
    lines = [f"{label:<24} J {np.mean([rows[n]['J'][k] for n in names]):.3f}" for k, label in enumerate(labels)]
    lines.append("chosen per fold (on the other folds): "
                 + ", ".join(f"fold {i} {labels[k]}" for i, k in sorted(chosen.items())))
    per_sequence = {n: reports[chosen[reports[0]["sequences"][n]["fold"]]]["sequences"][n] for n in names}
    return "\n".join(lines) + "\n" + report(per_sequence, ("J", "F", "T"), attributes())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reports", type=Path, nargs="+", help="kfold.json of each setting (the same folds)")
    parser.add_argument("--labels", default=None, help="comma-separated names of the settings (default: folders)")
    args = parser.parse_args(argv)
    if len(args.reports) < 2:
        parser.error("give at least two reports to choose between")
    labels = args.labels.split(",") if args.labels else [p.parent.name for p in args.reports]
    if len(labels) != len(args.reports):
        parser.error(f"--labels: {len(labels)} labels for {len(args.reports)} reports")
    reports = []
    for path in args.reports:
        try:
            reports.append(json.loads(path.read_text()))
        except (OSError, ValueError) as exc:
            parser.error(f"{path}: not a readable kfold.json ({exc.__class__.__name__})")
    if [r["folds"] for r in reports].count(reports[0]["folds"]) != len(reports):
        parser.error("the reports were made on different folds")
    print(nested_report(reports, labels))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
