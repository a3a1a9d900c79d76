"""An offline study on a k-fold run's held-out masks: drop the small connected components of each mask.

DAVIS-2016 annotates one salient object per sequence, and masks that follow distracting background motion
(spray, foliage, a screen) often add blobs apart from the object. This keeps, in each frame, the connected
components (8-connected) whose area is at least ``fraction`` of the largest one's, for each ``fraction`` of a
grid (0: the masks unchanged; 1: the largest component only), and scores every variant with the DAVIS-2016
protocol (J and F at 480p). The setting is chosen without looking at the sequences it is reported on: for each
fold, the fraction with the best mean J over the other folds' sequences (nested) is applied to that fold's.

    python benchmarks/kfold_components.py runs/kfold-epo [--fractions 0 0.1 0.25 0.5 1]

``runs/kfold-epo`` is a ``benchmarks/kfold.py`` output folder (``fold<i>/heldout/<sequence>/masks/*.png`` and
``kfold.json``); the variants' masks and the report go to ``<folder>/components/``.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from geometry_davis_auc import DAVIS  # noqa: E402


def keep_components(mask: np.ndarray, fraction: float) -> np.ndarray:
    """Binary uint8 ``mask`` (H, W) without the 8-connected components smaller than ``fraction`` of its largest.

    >>> m = np.zeros((6, 12), np.uint8); m[1:5, 1:5] = 1; m[2:4, 8:10] = 1
    >>> int(keep_components(m, 0.5).sum()), int(keep_components(m, 0.25).sum()), int(keep_components(m, 0).sum())
    (16, 20, 20)
    """
    if fraction <= 0:
        return mask
    count, labels, stats, _ = cv2.connectedComponentsWithStats((mask > 0).astype(np.uint8), connectivity=8)
    if count <= 2:  # background and at most one component
        return mask
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.r_[False, areas >= fraction * areas.max()]
    return keep[labels].astype(mask.dtype) * mask.max()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--fractions", type=float, nargs="+", default=[0.0, 0.1, 0.25, 0.5, 1.0])
    args = parser.parse_args(argv)
    from eponet.evaluation.evaluator import evaluate

    report = json.loads((args.folder / "kfold.json").read_text())
    fold_of = {name: row["fold"] for name, row in report["sequences"].items()}
    names = sorted(fold_of)
    out = args.folder / "components"
    scores: dict[float, dict[str, dict]] = {}
    for fraction in args.fractions:
        variant = out / f"fraction-{fraction:g}"
        for name in names:
            target = variant / name
            if target.is_dir():
                continue
            tmp = target.with_name(name + ".tmp")
            tmp.mkdir(parents=True, exist_ok=True)
            for file in sorted((args.folder / f"fold{fold_of[name]}" / "heldout" / name / "masks").glob("*.png")):
                mask = cv2.imread(str(file), cv2.IMREAD_GRAYSCALE)
                cv2.imwrite(str(tmp / file.name), keep_components(mask, fraction))
            tmp.rename(target)
        result = evaluate("davis2016", DAVIS, variant, names, "480p", compute_t=False)
        scores[fraction] = {n: {"J": v["J"]["mean"], "F": v["F"]["mean"]} for n, v in result["sequences"].items()}
        print(f"fraction {fraction:g}: J {np.mean([s['J'] for s in scores[fraction].values()]):.4f}, "
              f"F {np.mean([s['F'] for s in scores[fraction].values()]):.4f} (every sequence; for reference only)",
              flush=True)
    chosen, nested = {}, {}
    for fold in sorted(set(fold_of.values())):
        others = [n for n in names if fold_of[n] != fold]
        chosen[fold] = max(args.fractions, key=lambda f: np.mean([scores[f][n]["J"] for n in others]))
        for n in names:
            if fold_of[n] == fold:
                nested[n] = {"fold": fold, "fraction": chosen[fold], **scores[chosen[fold]][n],
                             "J_unchanged": scores[0.0][n]["J"] if 0.0 in scores else None}
    print("nested choice per fold (best mean J on the other folds):", chosen)
    for n in names:
        row = nested[n]
        change = "" if row["J_unchanged"] is None else f" ({row['J'] - row['J_unchanged']:+.3f})"
        print(f"  {n:<18} fold {row['fold']} fraction {row['fraction']:g}: J {row['J']:.3f}{change} F {row['F']:.3f}")
    mean_j = np.mean([r["J"] for r in nested.values()])
    base = [r["J_unchanged"] for r in nested.values() if r["J_unchanged"] is not None]
    print(f"  nested mean ({len(nested)}): J {mean_j:.4f}, F {np.mean([r['F'] for r in nested.values()]):.4f}"
          + (f"; unchanged masks J {np.mean(base):.4f}" if base else ""))
    (out / "report.json").write_text(json.dumps({"fractions": args.fractions, "scores": {str(k): v for k, v in
                                                 scores.items()}, "chosen": chosen, "nested": nested}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
