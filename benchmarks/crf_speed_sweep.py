"""Cheaper dense CRFs against the ``epo`` preset's, held out: J and cost of each setting on the k-fold saliency.

Reads the held-out saliency maps of a k-fold run (``benchmarks/kfold.py --what epo --save masks,saliency``: every
one of the 30 DAVIS-2016 train sequences scored by a network trained without it, 8-bit maps at 480p) and refines
them with each setting of the grid: the preset's CRF (427 px wide, 5 iterations, the whole frame), a lower CRF size
(``max_size``), fewer ``iterations``, and the CRF only on the box around the object (``crop_margin`` bilateral
widths around the pixels above 0.5). Every ``--every``-th scored frame of every sequence is used (J per sequence is
the mean over those frames, DAVIS-2016 J against the 480p ground truth). Cost: the CRF's milliseconds per frame in
the same process, in units of R (OpenCV DIS ``medium`` forward+backward per frame at 427x240 on the same frames,
measured before and after).

Selection without choosing on the reported sequences: for each fold, the cheapest setting whose mean J over the
other 24 sequences is at most ``--tolerance`` (0.002) below the preset's there (``--choose best``: the setting
with the best mean J there); that fold's six sequences are then reported with the setting chosen for them.

``--preset epo+`` starts from that preset's CRF instead (on an ``--what epo+`` k-fold's saliency, the fused
maps), ``--grid weights`` tries the bilateral kernel's colour width and weight instead of the cheaper sizes, and
``--grid backend`` the bilateral-grid CRF (``backend: grid``) with several cell sizes; ``--grid-json`` takes any
list of settings.

    python benchmarks/crf_speed_sweep.py --dump runs/kfold-epo-dump [--every 4] [--jobs 2]
    python benchmarks/crf_speed_sweep.py --dump runs/kfold-epo-plus --preset epo+ --grid weights --choose best
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_run import reference_ms  # noqa: E402

#: (label, changes to the preset's refiner); the first is the preset itself.
GRID = [("preset (427 px, 5 it.)", {}),
        ("crop 3", {"crop_margin": 3.0}),
        ("320 px", {"max_size": 320}),
        ("320 px, crop 3", {"max_size": 320, "crop_margin": 3.0}),
        ("214 px, crop 3", {"max_size": 214, "crop_margin": 3.0}),
        ("crop 3, 3 it.", {"crop_margin": 3.0, "iterations": 3})]
#: ``--grid weights``: the bilateral kernel's colour width (srgb) and weight (compat), the first the preset's.
WEIGHTS_GRID = [("preset", {}),
                ("srgb 5, compat 8", {"bilateral_srgb": 5.0, "bilateral_compat": 8.0}),
                ("srgb 5, compat 5", {"bilateral_srgb": 5.0, "bilateral_compat": 5.0}),
                ("srgb 10, compat 8", {"bilateral_srgb": 10.0, "bilateral_compat": 8.0}),
                ("srgb 15, compat 5", {"bilateral_srgb": 15.0, "bilateral_compat": 5.0}),
                ("srgb 10, compat 3", {"bilateral_srgb": 10.0, "bilateral_compat": 3.0})]

#: ``--grid backend``: the same CRF with its bilateral kernel on a bilateral grid (numpy), cells of 1 to 2 kernel
#: standard deviations (a larger cell is a coarser, cheaper and wider kernel), against pydensecrf's lattice.
BACKEND_GRID = [("preset", {}), ("pydensecrf", {"backend": "pydensecrf"})] + [
    (f"grid, cell {cell}", {"backend": "grid", "grid_cell": cell}) for cell in (1.0, 1.25, 1.5, 2.0)]


def preset_crf(name: str = "epo") -> dict:
    """The keyword arguments of ``densecrf_mask`` that preset ``name``'s refiner runs with (defaults filled in)."""
    import inspect

    from eponet.core.registry import get_registry
    from eponet.plugins.refiner.densecrf import densecrf_mask

    registry = get_registry()
    defaults = {p.name: p.default for p in registry.get("refiner", "densecrf").params}
    refiner = dict(registry.resolve_preset(name)["refiner"])
    refiner.pop("plugin")
    # what densecrf_mask takes (the stage's helper_process and the run loop's temporal averaging are not the CRF's)
    return {k: v for k, v in {**defaults, **refiner}.items() if k in inspect.signature(densecrf_mask).parameters}


def nested(rows: dict, folds: list[list[str]], pick) -> tuple[dict[int, int], dict[str, float]]:
    """Per fold ``i``, the setting ``pick(others)`` chooses on the other folds' sequences (``others``: their names)
    and its J on fold ``i``'s sequences: ``({fold: setting index}, {sequence: J})``. ``rows[name]["J"][k]`` is
    sequence ``name``'s J with setting ``k``."""
    fold_of = {name: i for i, names in enumerate(folds) for name in names}
    chosen, heldout_j = {}, {}
    for i, names in enumerate(folds):
        k = chosen[i] = pick([n for n in rows if fold_of[n] != i])
        heldout_j.update({n: rows[n]["J"][k] for n in names})
    return chosen, heldout_j


def scored_frames(root: Path, name: str, every: int):
    """``(frame, image, ground truth, void)`` of every ``every``-th scored frame of DAVIS sequence ``name`` under
    ``root`` (480p frames, RGB uint8 ``(H, W, 3)``; masks bool ``(H, W)``), and their count first."""
    from eponet.core.io import read_image
    from eponet.evaluation.datasets import load_dataset

    sequence = load_dataset("davis2016", root, sequences=[name])[name]
    frames = list(sequence.scored)[::every]
    yield len(frames)
    for frame in frames:
        yield (frame, read_image(root / "JPEGImages" / "480p" / name / f"{frame}.png"), *sequence.read_gt(frame))


def saved_map(heldout: Path, name: str, frame: str) -> np.ndarray:
    """A k-fold run's saved saliency map of ``frame`` of ``name`` as float64 ``(H, W)`` in [0, 1]."""
    return cv2.imread(str(heldout / name / "saliency" / f"{frame}.png"), cv2.IMREAD_GRAYSCALE) / 255.0


def _score_sequence(job: tuple) -> dict:
    """J mean and CRF seconds per frame of one sequence for each setting of the grid."""
    cv2.setNumThreads(1)
    from eponet.evaluation.metrics import db_eval_iou
    from eponet.plugins.refiner.densecrf import densecrf_mask

    root, heldout, name, every, preset_name, grid = job
    preset = preset_crf(preset_name)
    frames = scored_frames(root, name, every)
    count = next(frames)
    scores, seconds = [[] for _ in grid], [0.0 for _ in grid]
    for frame, image, gt, void in frames:
        probability = saved_map(heldout, name, frame)
        for i, (_, changes) in enumerate(grid):
            tick = time.perf_counter()
            mask = densecrf_mask(image, probability, **{**preset, **changes})
            seconds[i] += time.perf_counter() - tick
            scores[i].append(db_eval_iou(mask.astype(bool), gt, void))
    return {"name": name, "frames": count, "J": [float(np.mean(s)) for s in scores],
            "ms": [1000 * s / count for s in seconds]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dump", type=Path, required=True, help="output folder of kfold.py --save ...,saliency")
    parser.add_argument("--every", type=int, default=4)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--tolerance", type=float, default=0.002)
    parser.add_argument("--preset", default="epo", help="the preset whose CRF is the first setting (epo, epo+)")
    parser.add_argument("--grid", choices=("speed", "weights", "backend"), default="speed")
    parser.add_argument("--grid-json", help="instead of --grid: a JSON list of [label, {refiner settings}] pairs "
                        "(the preset's CRF is put first)")
    parser.add_argument("--choose", choices=("cheapest", "best"), default="cheapest",
                        help="per fold: the cheapest setting within --tolerance of the preset's J, or the best J")
    args = parser.parse_args()
    grid = {"speed": GRID, "weights": WEIGHTS_GRID, "backend": BACKEND_GRID}[args.grid]
    if args.grid_json:
        try:
            grid = [("preset", {})] + [(str(label), dict(changes)) for label, changes in json.loads(args.grid_json)]
        except (ValueError, TypeError) as error:
            parser.error(f"--grid-json: expected a JSON list of [label, {{settings}}] pairs ({error})")
    record = json.loads((args.dump / "kfold.json").read_text())
    root = args.dump / "davis-480p-from-240p"
    folds = record["folds"]
    jobs = [(root, args.dump / f"fold{i}" / "heldout", name, args.every, args.preset, grid)
            for i, names in enumerate(folds)
            for name in names]
    files = sorted((root / "JPEGImages" / "480p" / folds[0][0]).glob("*.png"))[:20]
    cv2.setNumThreads(1)
    before = reference_ms(files, 0.5, 1)
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = {r["name"]: r for r in pool.map(_score_sequence, jobs)}
    after = reference_ms(files, 0.5, 1)
    reference = 0.5 * (before + after)
    labels = [label for label, _ in grid]
    mean_j = lambda names, k: float(np.mean([rows[n]["J"][k] for n in names]))  # noqa: E731
    weights = np.array([rows[n]["frames"] for n in rows], float)
    cost = [float(np.average([rows[n]["ms"][k] for n in rows], weights=weights)) for k in range(len(grid))]
    print(f"R = {reference:.1f} ms ({before:.1f} before, {after:.1f} after); every {args.every}th scored frame, "
          f"{int(weights.sum())} frames of {len(rows)} sequences")
    print(f"{'setting':<26}{'J':>7}{'ms':>8}{'R':>7}")
    for k, label in enumerate(labels):
        print(f"{label:<26}{mean_j(list(rows), k):>7.3f}{cost[k]:>8.1f}{cost[k] / reference:>7.2f}")
    def pick(others: list[str]) -> int:
        if args.choose == "best":
            return max(range(len(grid)), key=lambda k: mean_j(others, k))
        floor = mean_j(others, 0) - args.tolerance
        return min((k for k in range(len(grid)) if mean_j(others, k) >= floor), key=lambda k: cost[k])

    chosen, heldout_j = nested(rows, folds, pick)
    chosen = {i: labels[k] for i, k in chosen.items()}
    print("chosen per fold (on the other folds): " + ", ".join(f"{i}: {c}" for i, c in chosen.items()))
    nested_j = float(np.mean(list(heldout_j.values())))
    print(f"nested: J {nested_j:.3f} against the preset's {mean_j(list(rows), 0):.3f} on the same frames")
    out = args.dump / f"crf-{args.grid}-sweep.json"
    out.write_text(json.dumps({"reference_ms": reference, "every": args.every, "preset": args.preset,
                               "choose": args.choose, "grid": grid, "cost_ms": cost,
                               "sequences": rows, "chosen": chosen, "nested_J": nested_j}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
