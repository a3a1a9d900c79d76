"""Dense-CRF parameters of the ``epo`` preset, measured on a held-out split.

Trains the recipe (``examples/train-epo.yaml``) without the split's six sequences, once per seed (a folder with
``weights.pt`` is reused), runs the ``epo`` pipeline on them with the networks' mean probability (``weights`` as a
list; one seed: one network) and saves its saliency maps, then refines those maps with each CRF setting of a grid
and scores J (DAVIS-2016 protocol, 480p ground truth). The frames are the 240p frames upsampled to 854x480 and
processed at scale 0.5, as for every held-out figure (``epo_ablation.validation_root``); the CRF runs at most 427
px wide, as in the preset, on the saved 8-bit maps (the pipeline's own CRF pass on its float maps gives the same J
to 0.001).

    python benchmarks/epo_crf_sweep.py [--split A|B|name,name,...] [--seeds 0,1] [--grid JSON] [--out DIR]

The preset's parameters were chosen on split B and then measured on split A (the recipe's validation split), so
that split A's figure is not selected on split A itself. Prints one row per setting (J mean, J per sequence;
``threshold`` is the motion net's probability > 0.5 without a CRF) and writes ``<out>/sweep.json``.
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from epo_ablation import RECIPE, ROOT, authors_crf, recipe_without, run_validation, train_variant, validation_root  # noqa: E402

#: Split A is the recipe's validation split; B the second held-out split of the model cards.
SPLITS = {
    "A": yaml.safe_load(RECIPE.read_text())["validation"]["davis"]["sequences"],
    "B": ["breakdance-flare", "drift-turn", "horsejump-low", "motocross-bumps", "rhino", "scooter-gray"],
}
#: The authors' values ({}), each parameter moved on its own, and the preset's setting.
GRID = [{}, {"bilateral_compat": 3}, {"bilateral_compat": 8}, {"bilateral_compat": 12},
        {"bilateral_srgb": 5}, {"bilateral_srgb": 7}, {"bilateral_srgb": 20},
        {"bilateral_sxy": 25}, {"bilateral_sxy": 80}, {"gaussian_compat": 1}, {"gaussian_compat": 6},
        {"iterations": 10}, {"bilateral_srgb": 5, "bilateral_compat": 8}]


def _score_sequence(job: tuple) -> list[float]:
    """J mean of one sequence for each setting (None: threshold at 0.5; a dict: changes to the authors' CRF) of
    ``job``."""
    from eponet.core.io import read_image
    from eponet.evaluation.datasets import load_dataset
    from eponet.evaluation.metrics import db_eval_iou
    from eponet.plugins.refiner.densecrf import densecrf_mask

    root, saliency, name, settings = job
    authors = {k: v for k, v in authors_crf().items() if k not in ("plugin", "helper_process")}
    sequence = load_dataset("davis2016", root, sequences=[name])[name]
    scores = [[] for _ in settings]
    for frame in sequence.scored:
        image = read_image(root / "JPEGImages" / "480p" / name / f"{frame}.png")
        probability = cv2.imread(str(saliency / name / "saliency" / f"{frame}.png"), cv2.IMREAD_GRAYSCALE) / 255.0
        gt, void = sequence.read_gt(frame)
        for scored, setting in zip(scores, settings):
            mask = probability > 0.5 if setting is None else densecrf_mask(image, probability, **{**authors, **setting})
            scored.append(db_eval_iou(mask.astype(bool), gt, void))
    return [float(np.mean(s)) for s in scores]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--split", default="A", help="A, B or comma-separated DAVIS-2016 train sequences")
    parser.add_argument("--seeds", default="0", help="comma-separated training seeds; several: their mean")
    parser.add_argument("--grid", help="JSON list of densecrf parameter sets ({} = the authors' values)")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--jobs", type=int, default=2, help="processes for the CRF")
    args = parser.parse_args()
    sequences = SPLITS.get(args.split) or [s for s in args.split.split(",") if s]
    seeds = [int(s) for s in args.seeds.split(",")]
    grid = json.loads(args.grid) if args.grid else GRID
    out = args.out or ROOT / "runs" / f"crf-sweep-{args.split if args.split in SPLITS else 'custom'}"

    weights = []
    for seed in seeds:
        folder = out / f"seed{seed}"
        seconds = train_variant(folder, lambda seed=seed: {**recipe_without(sequences), "seed": seed}, None, False)
        print(f"seed {seed}: {folder / 'weights.pt'} ({seconds / 60:.1f} min of training)", flush=True)
        weights.append(str(folder / "weights.pt"))

    recipe = yaml.safe_load(RECIPE.read_text())
    davis = validation_root((RECIPE.parent / recipe["validation"]["davis"]["root"]).resolve(), sequences, out)
    saliency = out / f"saliency-seeds-{'-'.join(map(str, seeds))}"
    if not (saliency / "run.json").is_file():
        run_validation({"motion_net": {"plugin": "epo_unet", "weights": weights}, "refiner": {"plugin": "threshold"}},
                       saliency, davis, sequences, save=("saliency",))

    settings = [None] + grid
    with ProcessPoolExecutor(args.jobs) as pool:
        per_sequence = list(pool.map(_score_sequence, [(davis, saliency, s, settings) for s in sequences]))
    rows = []
    print(f"{'setting':52s} {'J':>6s}  " + " ".join(f"{s[:10]:>10s}" for s in sequences))
    for i, setting in enumerate(settings):
        js = {s: per_sequence[k][i] for k, s in enumerate(sequences)}
        mean = float(np.mean(list(js.values())))
        label = "threshold (no CRF)" if setting is None else json.dumps(setting) if setting else "authors' values"
        print(f"{label:52s} {mean:6.3f}  " + " ".join(f"{j:10.3f}" for j in js.values()), flush=True)
        rows.append({"setting": setting, "J": mean, "per_sequence_J": js})
    (out / "sweep.json").write_text(json.dumps({"sequences": sequences, "seeds": seeds, "weights": weights,
                                                "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
