"""EpO against EpO+ on eponet's 6-sequence DAVIS validation split, and EpO+ with and without motion-map dropout.

Trains one fusion per variant from ``examples/train-epo-plus.yaml`` (the shipped recipe, minus the validation
sequences) on top of a motion network trained without them (by default the ``ed+flow+dropout`` variant of
``benchmarks/epo_ablation.py``), then runs both presets end to end exactly as ``benchmarks/epo_ablation.py``
scores EpO: 854x480 frames processed at scale 0.5, masks at 480p, DAVIS-2016 J, F and T against the 480p
ground truth, with the threshold refiner (no CRF) and with the dense CRF of the presets. Several motion networks
(comma-separated) are averaged, as the ``epo`` preset averages its two.

    python benchmarks/epo_plus_ablation.py [--motion-net runs/ablation/ed+flow+dropout/weights.pt[,more.pt]]
                                           [--variants dropout,no-dropout] [--jobs 2] [--out runs/ablation-plus]

Variants: ``dropout`` (the recipe, with the paper's input-dropout: the motion map zeroed on 20% of the training
frames), ``no-dropout`` and ``paper`` (the paper's network: input-dropout, and neither of eponet's two
extensions, motion residual and feature dropout).
Prints a table and writes ``<out>/ablation.json``; trained variants (``weights.pt`` present) are reused unless
``--retrain``.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from epo_ablation import ROOT, run_validation, summarise, train_variant, validation_root  # noqa: E402

RECIPE = ROOT / "examples" / "train-epo-plus.yaml"
VARIANTS = ("dropout", "no-dropout", "paper")


def variant_document(base: dict, name: str, motion_net: list[str]) -> dict:
    doc = copy.deepcopy(base)
    if name == "no-dropout":
        doc["input_dropout"]["probability"] = 0.0
    if name == "paper":
        doc["model"].update(motion_residual=False, feature_dropout=0.0)
    if name not in VARIANTS:
        raise SystemExit(f"unknown variant {name!r}; known: {', '.join(VARIANTS)}")
    doc["motion_net"]["weights"] = motion_net
    for phase in doc["phases"]:
        phase["data"]["davis"]["root"] = str((RECIPE.parent / phase["data"]["davis"]["root"]).resolve())
    doc["validation"]["davis"]["root"] = str((RECIPE.parent / doc["validation"]["davis"]["root"]).resolve())
    return doc


def train(name: str, motion_net: list[str], out: Path, threads: int | None, retrain: bool) -> tuple[str, float]:
    return name, train_variant(out / name, lambda: variant_document(yaml.safe_load(RECIPE.read_text()), name, motion_net),
                               threads, retrain)


def score(preset: str, stages: dict, out: Path, davis: Path, sequences: list[str]) -> dict:
    return summarise(run_validation(stages, out, davis, sequences, preset=preset, save=("masks", "saliency"),
                                    evaluate={"dataset": "davis2016", "t": True})["evaluation"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--motion-net", default=str(ROOT / "runs" / "ablation" / "ed+flow+dropout" / "weights.pt"),
                        help="EpO weights trained without the validation sequences (comma-separated: averaged)")
    parser.add_argument("--variants", default="dropout,no-dropout")
    parser.add_argument("--jobs", type=int, default=2, help="variants trained at once (one thread each)")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "ablation-plus")
    parser.add_argument("--retrain", action="store_true")
    args = parser.parse_args()
    motion_net = [str(Path(p).resolve()) for p in args.motion_net.split(",") if p]
    for path in motion_net:
        if not Path(path).is_file():
            raise SystemExit(f"{path}: no motion network; train it with benchmarks/epo_ablation.py "
                             "--variants ed+flow+dropout")
    names = [n for n in args.variants.split(",") if n]
    base = yaml.safe_load(RECIPE.read_text())
    for name in names:
        variant_document(base, name, motion_net)  # fail early on unknown names
    threads = 1 if args.jobs > 1 else None
    with ThreadPoolExecutor(args.jobs) as pool:
        seconds = dict(pool.map(lambda n: train(n, motion_net, args.out, threads, args.retrain), names))

    davis = (RECIPE.parent / base["validation"]["davis"]["root"]).resolve()
    sequences = base["validation"]["davis"]["sequences"]
    davis = validation_root(davis, sequences, args.out)
    refiners = {"no CRF": {"plugin": "threshold"}, "CRF": {"plugin": "densecrf"}}  # the presets' CRF parameters
    rows = {"EpO": ("epo", {"motion_net": {"plugin": "epo_unet", "weights": motion_net}}, None)}
    for name in names:
        rows[f"EpO+ {name}"] = ("epo+", {"motion_net": {"plugin": "epo_unet", "weights": motion_net},
                                         "fusion": {"plugin": "convgru", "weights": str(args.out / name / "weights.pt")}},
                                name)
    results = {}
    for label, (preset, stages, name) in rows.items():
        results[label] = {"train_seconds": round(seconds[name], 1) if name else None}
        for refiner_label, refiner in refiners.items():
            folder = args.out / "scores" / label.replace(" ", "_").replace("+", "plus") / refiner_label.replace(" ", "-")
            results[label][refiner_label] = score(preset, {**stages, "refiner": refiner}, folder, davis, sequences)
    print(f"validation split: {', '.join(sequences)} (240p frames upsampled to 480p, processed at scale 0.5, "
          "scored against the 480p ground truth; T: lower is better)")
    print(f"{'method':<20}" + "".join(f"{m + ' ' + r:>11}" for r in refiners for m in ("J", "F", "T")))
    for label, row in results.items():
        print(f"{label:<20}" + "".join(f"{row[r][m]:>11.3f}" for r in refiners for m in ("J", "F", "T")))
    (args.out / "ablation.json").write_text(json.dumps({"sequences": sequences, "motion_net": motion_net,
                                                        "results": results}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
