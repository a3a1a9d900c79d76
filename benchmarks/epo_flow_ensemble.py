"""EpO on two flows: held-out motion networks on motion images from DIS flow at OpenCV's ``medium`` preset (its
finest pyramid level is half the frame: the recipe of the v2 weights) and at the full frame size
(``finest_scale: 0``: the recipe and the presets since v3), each alone and with their saliency maps averaged,
on eponet's 6-sequence DAVIS validation split.

Each network is trained with ``examples/train-epo.yaml`` minus the validation sequences, with its flow stage
set as in ``FLOWS``, and run with the ``epo`` pipeline on the same flow it was trained on: 854x480 frames (the
240p frames upsampled, see ``epo_ablation.validation_root``) at scale 0.5. The masks are the saliency
thresholded at 0.5 (no CRF) or refined by the authors' dense CRF (``epo_ablation.authors_crf``); J, F and T
follow the DAVIS-2016 protocol against the 480p ground truth.

    python benchmarks/epo_flow_ensemble.py [--out runs/flow-ensemble] [--jobs 2] [--retrain] [--split a,b,...]

``--split`` holds out other sequences instead of the recipe's validation split (train on the rest, score on
them): a check that what the split shows is not the split's alone.

Already trained networks (``<out>/<flow>/weights.pt``) are reused unless ``--retrain``. Prints a table and
writes ``<out>/ensemble.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from epo_ablation import (RECIPE, ROOT, authors_crf, recipe_without, run_validation, summarise,  # noqa: E402
                          train_variant, validation_root)

#: The flow stage of each network (the rest of the geometry is the recipe's).
FLOWS = {"medium": {"plugin": "dis", "preset": "medium", "finest_scale": None},
         "fine": {"plugin": "dis", "preset": "medium", "finest_scale": 0}}


def flow_document(flow: str, split: list[str] | None = None) -> dict:
    doc = recipe_without(split)
    doc["geometry"]["stages"]["flow"] = dict(FLOWS[flow])
    return doc


def saliency_maps(weights: Path, flow: str, out: Path, davis: Path, sequences: list[str]) -> None:
    """Run the ``epo`` pipeline with ``flow`` and these weights, saving the saliency maps under ``out``."""
    stages = {"flow": FLOWS[flow], "motion_net": {"plugin": "epo_unet", "weights": str(weights)},
              "refiner": {"plugin": "threshold"}}
    run_validation(stages, out, davis, sequences, save=("saliency",))


def score_mean(folders: list[Path], davis: Path, sequences: list[str], out: Path, crf: dict) -> dict:
    """Masks from the mean of the saliency maps in ``folders``, thresholded at 0.5 (``no CRF``) and refined by
    the CRF with ``crf`` (``CRF``), written under ``out/<refiner>`` in one pass; J, F and T of each."""
    import cv2

    from eponet.core.io import read_image
    from eponet.evaluation.evaluator import evaluate
    from eponet.plugins.refiner.densecrf import densecrf_mask

    targets = {"no CRF": out / "no-CRF", "CRF": out / "CRF"}
    for name in sequences:
        for target in targets.values():
            (target / name / "masks").mkdir(parents=True, exist_ok=True)
        for path in sorted((folders[0] / name / "saliency").glob("*.png")):
            maps = [cv2.imread(str(f / name / "saliency" / path.name), cv2.IMREAD_GRAYSCALE) for f in folders]
            probability = np.mean([m.astype(np.float32) / 255.0 for m in maps], axis=0)
            frame = read_image(davis / "JPEGImages" / "480p" / name / path.name)
            masks = {"no CRF": probability >= 0.5, "CRF": densecrf_mask(frame, probability, **crf) > 0}
            for refiner, mask in masks.items():
                cv2.imwrite(str(targets[refiner] / name / "masks" / path.name), mask.astype(np.uint8) * 255)
    results = {}
    for refiner, target in targets.items():
        results[refiner] = summarise(evaluate("davis2016", davis, target, sequences, "480p"))
    return results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "flow-ensemble")
    parser.add_argument("--jobs", type=int, default=2, help="networks trained at once (one thread each)")
    parser.add_argument("--retrain", action="store_true")
    parser.add_argument("--split", default=None, help="comma-separated sequences to hold out instead of the recipe's")
    args = parser.parse_args()
    split = [s for s in args.split.split(",") if s] if args.split else None
    threads = 1 if args.jobs > 1 else None
    with ThreadPoolExecutor(args.jobs) as pool:
        seconds = dict(zip(FLOWS, pool.map(
            lambda f: train_variant(args.out / f, lambda: flow_document(f, split), threads, args.retrain), FLOWS)))

    recipe = yaml.safe_load(RECIPE.read_text())
    sequences = split or recipe["validation"]["davis"]["sequences"]
    davis = validation_root((RECIPE.parent / recipe["validation"]["davis"]["root"]).resolve(), sequences,
                            ROOT / "runs" / "ablation")
    for flow in FLOWS:
        saliency_maps(args.out / flow / "weights.pt", flow, args.out / flow / "saliency", davis, sequences)
    crf = {k: v for k, v in authors_crf().items() if k not in ("plugin", "helper_process")}
    combos = {"medium": ["medium"], "fine": ["fine"], "mean of both": list(FLOWS)}
    results = {}
    for label, flows in combos.items():
        folders = [args.out / f / "saliency" for f in flows]
        results[label] = score_mean(folders, davis, sequences, args.out / "masks" / label.replace(" ", "-"), crf)
    print(f"validation split: {', '.join(sequences)} (240p frames upsampled to 480p, processed at scale 0.5, "
          "scored against the 480p ground truth; T: lower is better)")
    print(f"{'flow':<14}" + "".join(f"{m + ' ' + r:>12}" for r in ("no CRF", "CRF") for m in ("J", "F", "T")))
    for label, row in results.items():
        print(f"{label:<14}" + "".join(f"{row[r][m]:>12.3f}" for r in ("no CRF", "CRF") for m in ("J", "F", "T")))
        print(" " * 14 + "CRF J per sequence: " + ", ".join(f"{s} {v:.3f}" for s, v in row["CRF"]["per_sequence_J"].items()))
    (args.out / "ensemble.json").write_text(json.dumps(
        {"sequences": sequences, "flows": FLOWS, "crf": crf, "train_seconds": seconds, "results": results}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
