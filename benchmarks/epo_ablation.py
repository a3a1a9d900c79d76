"""The EpO ablation of the paper (Table 1 style) on eponet's 6-sequence DAVIS validation split.

Trains one motion network per variant from ``examples/train-epo.yaml`` (the shipped recipe) and scores each
end to end with ``python -m eponet.run``'s pipeline: 854x480 frames processed at scale 0.5, masks at 480p,
J mean with the DAVIS-2016 protocol against the 480p ground truth, with the threshold refiner (no CRF) and
with the authors' dense CRF (:func:`authors_crf`, the CRF of the model cards' ablation tables; the ``epo``
preset's own CRF is chosen by ``benchmarks/epo_crf_sweep.py``). (The shared data holds 480p frames of only three sequences, so the
480p inputs are the 240p frames upsampled; see :func:`validation_root`.)

    python benchmarks/epo_ablation.py [--variants ed+flow+dropout,flow,...] [--jobs 2] [--out runs/ablation]

Variants (all with the recipe's DAVIS schedule):
    ed+flow+dropout      the shipped recipe: ED + flow inputs with input-dropout of ED
    ed+flow              no input-dropout
    flow                 flow only (dx, dy)
    ed                   ED only
    ed+flow+dropout+rbsf the recipe after an RBSF pre-training phase (RBSF_PHASE)

Prints a table and writes ``<out>/ablation.json``; training curves stay in ``<out>/<variant>/``.
Already trained variants (``weights.pt`` present) are not retrained unless ``--retrain``.
"""

from __future__ import annotations

import argparse
import copy
import json
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
RECIPE = ROOT / "examples" / "train-epo.yaml"


def variant_document(base: dict, name: str) -> dict:
    doc = copy.deepcopy(base)
    if name == "ed+flow":
        doc["input_dropout"]["probability"] = 0.0
    elif name == "flow":
        doc["model"]["inputs"], doc["input_dropout"]["probability"] = "flow", 0.0
    elif name == "ed":
        doc["model"]["inputs"], doc["input_dropout"]["probability"] = "ed", 0.0
    elif name == "ed+flow+dropout+rbsf":
        doc["phases"] = [copy.deepcopy(RBSF_PHASE)] + doc["phases"]
    elif name != "ed+flow+dropout":
        raise SystemExit(f"unknown variant {name!r}; known: {', '.join(VARIANTS)}")
    return doc


VARIANTS = ("ed+flow+dropout", "ed+flow", "flow", "ed", "ed+flow+dropout+rbsf")
#: Stage 1 of the paper: generated RBSF-style clips (relative to examples/), before the DAVIS phase.
RBSF_PHASE = {"name": "rbsf", "data": {"rbsf": {"dir": "../runs/rbsf-train", "sequences": 60, "frames": 30,
                                                "size": "427x240", "seed": 1}}, "epochs": 2}


def recipe_without(sequences: list[str] | None) -> dict:
    """The recipe with absolute paths, trained without ``sequences`` and validated on them (None: as it is)."""
    doc = absolutise(yaml.safe_load(RECIPE.read_text()), RECIPE.parent)
    if sequences:
        doc["phases"][-1]["data"]["davis"]["exclude"] = list(sequences)
        doc["validation"]["davis"]["sequences"] = list(sequences)
    return doc


def authors_crf() -> dict:
    """The refiner of the authors' dense CRF (the plugin's defaults) at the presets' size cap (the ``epo+``
    preset's refiner), every parameter spelt out, since a spec's refiner merges onto the preset's."""
    from eponet.core.registry import get_registry

    registry = get_registry()
    defaults = {p.name: p.default for p in registry.get("refiner", "densecrf").params}
    return {"plugin": "densecrf", **defaults, **registry.resolve_preset("epo+")["refiner"]}


def absolutise(doc: dict, base_dir: Path) -> dict:
    """Rewrite the recipe's relative paths against its own folder, so the variant spec can live anywhere."""
    def fix(value):
        return str((base_dir / value).resolve()) if value and not Path(value).is_absolute() else value

    for phase in doc["phases"]:
        for kind, options in phase["data"].items():
            key = "root" if kind == "davis" else "dir"
            options[key] = fix(options[key])
    for kind, options in doc["validation"].items():
        options["root"] = fix(options["root"])
    return doc


def train(name: str, out: Path, threads: int, retrain: bool) -> tuple[str, float]:
    return name, train_variant(out / name, lambda: absolutise(variant_document(yaml.safe_load(RECIPE.read_text()), name),
                                                              RECIPE.parent), threads, retrain)


def train_variant(folder: Path, document, threads: int | None, retrain: bool) -> float:
    """Train the spec ``document()`` (a callable: only built when needed) into ``folder`` with ``python -m
    eponet.train`` (resuming from its checkpoint when one is there); returns the training seconds. A folder
    with ``weights.pt`` is reused unless ``retrain``."""
    if (folder / "weights.pt").is_file() and not retrain:
        return json.loads((folder / "summary.json").read_text())["train_seconds"]
    doc = document()
    doc["output"] = {"dir": str(folder.resolve())}  # the spec sits in the folder: a relative path would nest
    doc["threads"] = threads
    folder.mkdir(parents=True, exist_ok=True)
    spec = folder / "train.yaml"
    spec.write_text(yaml.safe_dump(doc, sort_keys=False))
    resume = ["--resume"] if (folder / "checkpoint-last.pt").is_file() and not retrain else []
    tick = time.time()
    with open(folder / "train.log", "w") as log:
        subprocess.run([sys.executable, "-m", "eponet.train", str(spec), "-q", *resume], check=True, stdout=log,
                       stderr=subprocess.STDOUT)
    return time.time() - tick


def validation_root(davis: Path, sequences: list[str], out: Path) -> Path:
    """A DAVIS-layout root whose ``JPEGImages/480p`` holds the 240p validation frames upsampled to 854x480
    (bicubic, lossless PNG), next to links to the real 480p annotations: the shared data has 480p frames of
    only three sequences, and scoring at 480p is the DAVIS protocol. Processed at scale 0.5, the network sees
    (almost exactly) the 240p frames it was trained on."""
    import cv2

    root = out / "davis-480p-from-240p"
    for name in sequences:
        folder = root / "JPEGImages" / "480p" / name
        if folder.is_dir():
            continue
        tmp = folder.with_name(name + ".tmp")
        tmp.mkdir(parents=True, exist_ok=True)
        for frame in sorted((davis / "JPEGImages" / "240p" / name).glob("*.jpg")):
            image = cv2.imread(str(frame), cv2.IMREAD_COLOR)
            cv2.imwrite(str(tmp / (frame.stem + ".png")), cv2.resize(image, (854, 480), interpolation=cv2.INTER_CUBIC))
        tmp.rename(folder)
    for item in ("Annotations", "ImageSets", "db_info.yml"):
        if not (root / item).exists() and (davis / item).exists():
            (root / item).symlink_to((davis / item).resolve())
    return root


def run_validation(stages: dict, out: Path, davis: Path, sequences: list[str], *, preset: str = "epo",
                   save: tuple = ("masks",), evaluate: dict | None = None, run: dict | None = None,
                   seed: int = 0) -> dict:
    """Run ``preset`` with ``stages`` (and the spec's ``run`` settings, when given) on the validation root's 480p
    frames at scale 0.5 (the setting of every held-out figure), saving ``save`` under ``out``; returns the run's
    manifest (with ``evaluation`` when ``evaluate`` is given). ``seed`` is the spec's (RANSAC, self-training)."""
    from eponet.core.pipeline import Pipeline
    from eponet.core.progress import set_quiet
    from eponet.core.spec import parse_spec

    set_quiet(True)
    document = {"preset": preset,
                "input": {"path": str(davis), "resolution": "480p", "sequences": sequences, "scale": 0.5},
                "stages": stages, "output": {"dir": str(out), "save": list(save)}, "seed": seed}
    if evaluate is not None:
        document["evaluate"] = evaluate
    if run:
        document["run"] = run
    return Pipeline(parse_spec(document, base_dir=ROOT)).run()


def summarise(evaluation: dict) -> dict:
    """The figures every held-out benchmark reports from an evaluation: J, F and T means (T only when it was
    computed) and J per sequence."""
    overall = evaluation["overall"]
    figures = {"J": overall["J"]["mean"], "F": overall["F"]["mean"]}
    if "T" in overall:
        figures["T"] = overall["T"]["mean"]
    figures["per_sequence_J"] = {s: v["J"]["mean"] for s, v in evaluation["sequences"].items()}
    return figures


def score(weights: Path, refiner: dict, out: Path, davis: Path, sequences: list[str]) -> dict:
    stages = {"motion_net": {"plugin": "epo_unet", "weights": str(weights)}, "refiner": refiner}
    return summarise(run_validation(stages, out, davis, sequences,
                                    evaluate={"dataset": "davis2016", "t": False})["evaluation"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--jobs", type=int, default=2, help="variants trained at once (one thread each)")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "ablation")
    parser.add_argument("--retrain", action="store_true")
    parser.add_argument("--no-crf", action="store_true", help="score without the CRF only")
    args = parser.parse_args()
    names = [n for n in args.variants.split(",") if n]
    for name in names:
        variant_document(yaml.safe_load(RECIPE.read_text()), name)  # fail early on unknown names
    threads = 1 if args.jobs > 1 else 0
    with ThreadPoolExecutor(args.jobs) as pool:
        seconds = dict(pool.map(lambda n: train(n, args.out, threads or None, args.retrain), names))

    recipe = yaml.safe_load(RECIPE.read_text())
    davis = (RECIPE.parent / recipe["validation"]["davis"]["root"]).resolve()
    sequences = recipe["validation"]["davis"]["sequences"]
    davis = validation_root(davis, sequences, args.out)
    refiners = {"no CRF": {"plugin": "threshold"}}
    if not args.no_crf:
        refiners["CRF"] = authors_crf()
    results = {}
    for name in names:
        history = json.loads((args.out / name / "summary.json").read_text())
        results[name] = {"train_seconds": round(seconds[name], 1), "epochs": history["epochs"]}
        for label, refiner in refiners.items():
            results[name][label] = score(args.out / name / "weights.pt", refiner, args.out / name / label.replace(" ", "-"),
                                         davis, sequences)
    print(f"validation split: {', '.join(sequences)} (240p frames upsampled to 480p, processed at scale 0.5, "
          "scored against the 480p ground truth)")
    print(f"{'variant':<24}" + "".join(f"{'J ' + label:>12}" for label in refiners) + f"{'train min':>11}")
    for name, row in results.items():
        print(f"{name:<24}" + "".join(f"{row[label]['J']:>12.3f}" for label in refiners)
              + f"{row['train_seconds'] / 60:>11.1f}")
    (args.out / "ablation.json").write_text(json.dumps({"sequences": sequences, "results": results}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
