"""Temporal averaging of held-out saliency along the flow before the ``epo`` preset's CRF: which variant, held out.

Reads the held-out saliency maps of a k-fold run (``benchmarks/kfold.py --what epo --save masks,saliency``: 8-bit
maps at 480p, each of the 30 DAVIS-2016 train sequences scored by networks trained without it; with ``--what epo+``
the fused maps, refined with ``--preset epo+``'s CRF). For every
``--every``-th scored frame t, each variant averages t's map with its neighbours' warped into t along DIS
``medium`` flow of the 240p frames (upsampled), then refines with the preset's CRF and scores J against the 480p
ground truth. Variants: the radius (1: t - 1 and t + 1; 2: also t +- 2 at half weight), the mean or the median,
and the forward-backward test (``fb``: where the flow does not come back, Sundaram et al. 2010, t's own value
stands in; :mod:`eponet.core.temporal`, which the run loop's ``refiner: {temporal: 1}`` uses, is ``r1 fb``);
``plain``: the neighbours unwarped. The variant chosen per fold on the other four folds gives the nested J.

    python benchmarks/temporal_sweep.py --dump runs/kfold-v5-spread [--every 4] [--jobs 2] [--preset epo+]
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from crf_speed_sweep import nested, preset_crf, saved_map, scored_frames  # noqa: E402

#: (label, {offset: weight of each neighbour at that offset}, combine, forward-backward test, warp)
VARIANTS = [("none", {}, "mean", False, True),
            ("plain r1", {1: 1.0}, "mean", False, False),
            ("r1", {1: 1.0}, "mean", False, True),
            ("r1 fb", {1: 1.0}, "mean", True, True),
            ("r1 .75", {1: 0.75}, "mean", False, True),
            ("r1 median", {1: 1.0}, "median", False, True),
            ("r2", {1: 1.0, 2: 0.5}, "mean", False, True),
            ("r2 fb", {1: 1.0, 2: 0.5}, "mean", True, True)]


def _score_sequence(job: tuple) -> dict:
    """J mean of one sequence for each variant."""
    cv2.setNumThreads(1)
    from eponet.core.temporal import warp_into
    from eponet.evaluation.metrics import db_eval_iou
    from eponet.plugins.refiner.densecrf import densecrf_mask

    root, heldout, name, every, preset_name = job
    preset = preset_crf(preset_name)
    files = sorted((root / "JPEGImages" / "480p" / name).glob("*.png"))
    stems = [f.stem for f in files]
    maps = np.stack([saved_map(heldout, name, s) for s in stems]).astype(np.float32)
    grey = [cv2.resize(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
            for f in files]
    size = maps.shape[2], maps.shape[1]
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    flows: dict = {}

    def flow(a: int, b: int) -> np.ndarray:  # a -> b at 480p, in 480p pixels
        if (a, b) not in flows:
            flows[(a, b)] = cv2.resize(dis.calc(grey[a], grey[b], None), size) * 2.0
        return flows[(a, b)]

    def neighbour(t: int, s: int, fb: bool, warp: bool) -> np.ndarray:
        if not warp:
            return maps[s]
        warped, consistent = warp_into(maps[s], flow(t, s), flow(s, t))
        return np.where(consistent, warped, maps[t]) if fb else warped

    frames = scored_frames(root, name, every)
    count = next(frames)
    scores = [[] for _ in VARIANTS]
    for frame, image, gt, void in frames:
        t = stems.index(frame)
        for k, (_, weights, combine, fb, warp) in enumerate(VARIANTS):
            stack, w = [maps[t]], [1.0]
            for offset, weight in weights.items():
                for s in (t - offset, t + offset):
                    if 0 <= s < len(maps):
                        stack.append(neighbour(t, s, fb, warp))
                        w.append(weight)
            p = np.median(stack, 0) if combine == "median" else np.average(stack, axis=0, weights=w)
            scores[k].append(db_eval_iou(densecrf_mask(image, p, **preset).astype(bool), gt, void))
    return {"name": name, "frames": count, "J": [float(np.mean(s)) for s in scores]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dump", type=Path, required=True, help="output folder of kfold.py --save ...,saliency")
    parser.add_argument("--every", type=int, default=4)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--preset", default="epo", help="whose CRF refines the maps (epo+ for epo+'s fused maps)")
    args = parser.parse_args()
    record = json.loads((args.dump / "kfold.json").read_text())
    root, folds = args.dump / "davis-480p-from-240p", record["folds"]
    jobs = [(root, args.dump / f"fold{i}" / "heldout", name, args.every, args.preset) for i, names in enumerate(folds)
            for name in names]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = {r["name"]: r for r in pool.map(_score_sequence, jobs)}
    labels = [v[0] for v in VARIANTS]
    mean_j = lambda names, k: float(np.mean([rows[n]["J"][k] for n in names]))  # noqa: E731
    print(f"J on every {args.every}th scored frame, {sum(r['frames'] for r in rows.values())} frames of "
          f"{len(rows)} sequences")
    print(f"{'sequence':<18}" + "".join(f"{label:>11}" for label in labels))
    for name, r in rows.items():
        print(f"{name:<18}" + "".join(f"{j:>11.3f}" for j in r["J"]))
    print(f"{'mean':<18}" + "".join(f"{mean_j(rows, k):>11.3f}" for k in range(len(labels))))
    chosen, heldout_j = nested(rows, folds, lambda others: max(range(len(labels)), key=lambda k: mean_j(others, k)))
    chosen = {i: labels[k] for i, k in chosen.items()}
    nested_j = float(np.mean(list(heldout_j.values())))
    print("chosen per fold (on the other folds): " + ", ".join(f"{i}: {c}" for i, c in chosen.items()))
    print(f"nested: J {nested_j:.3f} against {mean_j(rows, 0):.3f} without averaging on the same frames")
    (args.dump / "temporal-sweep.json").write_text(json.dumps(
        {"every": args.every, "variants": labels, "sequences": rows, "chosen": chosen, "nested_J": nested_j}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
