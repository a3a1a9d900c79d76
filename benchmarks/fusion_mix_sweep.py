"""How much of the motion network's own map should EpO+ keep? Held-out J of the fused map mixed with the motion map.

Reads two k-fold runs over the same folds (``benchmarks/kfold.py ... --save masks,saliency``): ``--fused``, an
``--what epo+`` run (its saved saliency is the fusion's output, what the refiner reads) and ``--motion``, an
``--what epo`` run of the same fold networks (its saliency is the motion network's probability). For every
``--every``-th scored frame of every sequence, the map ``(1 - a) * fused + a * motion`` (``space: prob``) or
``sigmoid((1 - a) * logit(fused) + a * logit(motion))`` (``space: logit``) for each share ``a`` of ``--shares``
is refined with the ``--preset`` CRF and scored with DAVIS-2016 J against the 480p ground truth.

Selection without choosing on the reported sequences: for each fold, the setting with the best mean J over the
other 24 sequences; that fold's six sequences are reported with it (nested J).

    python benchmarks/fusion_mix_sweep.py --fused runs/kfold-v5-plus --motion runs/kfold-v5-epo [--every 4]
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from crf_speed_sweep import nested, preset_crf, saved_map, scored_frames  # noqa: E402

EPS = 1e-3


def mix(fused: np.ndarray, motion: np.ndarray, share: float, space: str) -> np.ndarray:
    """The fused and motion probabilities ``(H, W)`` mixed with ``share`` of the motion map, in ``space``."""
    if space == "prob":
        return (1 - share) * fused + share * motion
    fused, motion = np.clip(fused, EPS, 1 - EPS), np.clip(motion, EPS, 1 - EPS)
    logits = (1 - share) * np.log(fused / (1 - fused)) + share * np.log(motion / (1 - motion))
    return 1 / (1 + np.exp(-logits))


def _score_sequence(job: tuple) -> dict:
    import cv2

    cv2.setNumThreads(1)
    from eponet.evaluation.metrics import db_eval_iou
    from eponet.plugins.refiner.densecrf import densecrf_mask

    root, fused_dir, motion_dir, name, every, preset_name, grid = job
    preset = preset_crf(preset_name)
    frames = scored_frames(root, name, every)
    count = next(frames)
    scores = [[] for _ in grid]
    for frame, image, gt, void in frames:
        fused, motion = saved_map(fused_dir, name, frame), saved_map(motion_dir, name, frame)
        for i, (share, space) in enumerate(grid):
            mask = densecrf_mask(image, mix(fused, motion, share, space).astype(np.float32), **preset)
            scores[i].append(db_eval_iou(mask.astype(bool), gt, void))
    return {"name": name, "frames": count, "J": [float(np.mean(s)) for s in scores]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fused", type=Path, required=True, help="kfold.py --what epo+ output with saliency saved")
    parser.add_argument("--motion", type=Path, required=True, help="kfold.py --what epo output with saliency saved")
    parser.add_argument("--shares", default="0,0.2,0.35,0.5,0.65,0.8,1")
    parser.add_argument("--spaces", default="prob,logit")
    parser.add_argument("--every", type=int, default=4)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--preset", default="epo+", help="the preset whose CRF refines the mixed map")
    args = parser.parse_args()
    shares = [float(s) for s in args.shares.split(",")]
    grid = [(0.0, "prob")] + [(a, space) for space in args.spaces.split(",") for a in shares if 0 < a]
    record = json.loads((args.fused / "kfold.json").read_text())
    folds = record["folds"]
    if json.loads((args.motion / "kfold.json").read_text())["folds"] != folds:
        raise SystemExit(f"{args.motion}: its folds differ from {args.fused}'s")
    root = args.fused / "davis-480p-from-240p"
    jobs = [(root, args.fused / f"fold{i}" / "heldout", args.motion / f"fold{i}" / "heldout", name, args.every,
             args.preset, grid) for i, names in enumerate(folds) for name in names]
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = {r["name"]: r for r in pool.map(_score_sequence, jobs)}
    labels = [f"{space} {a:.2f}" for a, space in grid]
    mean_j = lambda names, k: float(np.mean([rows[n]["J"][k] for n in names]))  # noqa: E731
    frames = sum(r["frames"] for r in rows.values())
    print(f"every {args.every}th scored frame, {frames} frames of {len(rows)} sequences; {args.preset}'s CRF")
    print(f"{'motion share':<16}{'J':>7}")
    for k, label in enumerate(labels):
        print(f"{label:<16}{mean_j(list(rows), k):>7.3f}")
    chosen, heldout_j = nested(rows, folds, lambda others: max(range(len(grid)), key=lambda k: mean_j(others, k)))
    chosen = {i: labels[k] for i, k in chosen.items()}
    print("chosen per fold (on the other folds): " + ", ".join(f"{i}: {c}" for i, c in chosen.items()))
    nested_j = float(np.mean(list(heldout_j.values())))
    print(f"nested: J {nested_j:.3f} against the fused map alone's {mean_j(list(rows), 0):.3f} on the same frames")
    for name in sorted(rows):
        print(f"  {name:<18}" + " ".join(f"{j:.3f}" for j in rows[name]["J"]))
    out = args.fused / f"mix-{args.motion.name}.json"
    out.write_text(json.dumps({"every": args.every, "preset": args.preset, "grid": grid, "labels": labels,
                               "sequences": rows, "chosen": chosen, "nested_J": nested_j}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
