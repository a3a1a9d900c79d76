"""Cross-validated accuracy over the 30 DAVIS-2016 train sequences: every sequence is scored by a model that
never saw it.

Protocol: the 30 sequences of ``ImageSets/train.txt`` are split into 5 folds of 6 (:func:`folds`, fixed; a
seeded shuffle, seed 0, of the sorted names). For fold ``i`` the motion network is trained with the shipped
recipe (``examples/train-epo.yaml``) on the other 24 sequences (``--seeds 0,1``: twice, with seeds 0 and 1, whose
probabilities are averaged as the preset's pair of networks is), and the fold's 6 sequences are run end to end
through the ``epo`` preset (its own CRF, as a user gets it; ``--refiner authors`` for the authors' CRF of the
model cards' ablations) on 480p frames at scale 0.5 (the 240p frames upsampled, see
:func:`epo_ablation.validation_root`) and scored at 480p with the DAVIS-2016 protocol (J, F, and T where
``db_info.yml`` has ``eval_t``). ``--what ed`` needs no training: the mean per-frame ROC AUC of the ED maps
(the rigidity stage's settings, given with ``--rigidity key=value``) per sequence, as
``benchmarks/geometry_davis_auc.py`` computes it.

The report gives every sequence, the mean, the worst, and the means per DAVIS attribute (AC, DB, FM, MB, OCC,
as the paper's Table 3, and any other attribute with ``--attributes``). Usage::

    python benchmarks/kfold.py --what epo [--jobs 2] [--out runs/kfold-epo] [--folds 0,1]
    python benchmarks/kfold.py --what epo --weights runs/kfold-epo --out runs/kfold-epo-new-ed \
        --rigidity degeneracy=parallax border_prior=0.15     # the same networks on other ED
    python benchmarks/kfold.py --what epo --weights runs/kfold-epo --out runs/kfold-epo-st --preset epo-st
        # the same networks through another preset (here with per-video self-training; --fusion key=value)
    python benchmarks/kfold.py --what epo+ --weights runs/kfold-epo --out runs/kfold-epo-plus
        # EpO+: each fold's fusion (examples/train-epo-plus.yaml) trained on the fold's frozen network
    python benchmarks/kfold.py --what epo+ --weights runs/kfold-epo --out runs/kfold-epo-plus-oof --fusion-maps out-of-fold
        # the same, each training sequence's map from the network of the fold that held it out (scouting only:
        # those networks saw the fold's own sequences)
    python benchmarks/kfold.py --what epo --weights runs/kfold-epo --out runs/kfold-ed-video --run ed_window=null \
        --sequences bmx-bumps,car-turn,dance-jump,hockey,paragliding,stroller
        # some sequences only, with other run settings (here the whole video's ED scale)
    python benchmarks/kfold.py --what epo+ --weights runs/kfold-v5 --out runs/kfold-v5-plus-lite2-ens --fusion-seed 0,1 \
        --recipe-rigidity prior_groups=4 --rigidity prior_groups=4 --appearance plugin=efficientnet_lite2
        # two fusions per fold (training seeds 0 and 1; seed 1's in fold<i>/fusion-seed1) scored as their mean
    python benchmarks/kfold.py --what epo+ --weights runs/kfold-epo --out runs/kfold-epo-plus-seed1 --seeds 0,1 --seed 1
        # the same networks with another RANSAC / self-training seed: how far the figures move by chance
    python benchmarks/kfold.py --what ed [--rigidity degeneracy=none] [--trajectories cull_collisions=true] \
        [--flow finest_scale=0] [--flow-cache DIR] [--ed-whiten EPS] [--oracle]
        # the ED on OpenCV's DIS medium as it is (finest level 1), or with the dis stage's settings
        # (finest_scale=0: the presets' flow)
    python benchmarks/kfold.py --what epo --weights runs/kfold-epo --out runs/kfold-epo-bf16 --motion-net precision=bfloat16
        # the same networks with other motion-net (--motion-net) or flow (--flow patch_stride=5) settings
    python benchmarks/kfold.py --what epo --weights runs/kfold-epo --out runs/kfold-epo-pair --seeds 0,1
        # the epo preset as it ships: the mean of two networks per fold (seeds 0 and 1; seed 1's are trained
        # into fold<i>/seed1 of --weights)
    python benchmarks/kfold.py --what epo --out runs/kfold-epo-parallax --preset epo-st \
        --recipe-rigidity degeneracy=parallax border_prior=0.15
        # folds trained on another ED than the recipe's (merged onto its geometry.stages.rigidity)
    python benchmarks/kfold.py --what epo --out runs/kfold-epo-synmix \
        --recipe-data '{rbsf: {dir: runs/rbsf-distractors, sequences: 24, scene: {dynamic_texture_probability: 1.0}}}'
        # synthetic clips (here with moving water in every clip) mixed into each fold's DAVIS phase
    python benchmarks/kfold.py --what epo --out runs/kfold-epo-paste \
        --recipe-data '{paste: {dir: runs/paste, root: ../shared/data/davis2016-train/DAVIS, clips: 24}}'
        # the paper's RBSF on real video: objects of each fold's training sequences pasted over others of them
    python benchmarks/kfold.py --what epo --out runs/kfold-epo-pastepre \
        --recipe-phase '{name: paste, epochs: 2, data: {paste: {dir: runs/paste-pre, root: ../shared/data/davis2016-train/DAVIS}}}'
        # the same clips as a pre-training phase before the DAVIS phase, as the paper trains
    python benchmarks/kfold.py --what epo+ --weights runs/kfold-epo --out runs/kfold-epo-plus-pair-grid --seeds 0,1 \
        --crf backend=grid grid_cell=1.0
        # settings merged onto the refiner (the fold folders' fusion/ linked to an earlier run's: nothing retrained)
    python benchmarks/kfold.py --what epo+ --weights runs/kfold-v5-pair2 --seeds 0,1 --out runs/kfold-v5-pair2-gru \
        --recipe-rigidity prior_groups=4 --rigidity prior_groups=4 --appearance plugin=none --fusion selftrain=0
        # the fusion without appearance (the ConvGRU on the motion map alone; --fusion-model key=value merges onto
        # the fusion recipe's model section, e.g. feature_dropout=0.75; --fusion-dropout onto its input_dropout)

Trained folds (``weights.pt`` present) are reused; ``<out>/kfold.json`` holds every figure, and a later call
with other ``--folds`` and the same settings adds its folds to it.
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

from epo_ablation import (absolutise, authors_crf, recipe_without, run_validation,  # noqa: E402
                          train_variant, validation_root)
from geometry_davis_auc import DAVIS  # noqa: E402

FUSION_RECIPE = ROOT / "examples" / "train-epo-plus.yaml"

#: The paper's Table 3 attributes.
ATTRIBUTES = ("AC", "DB", "FM", "MB", "OCC")


def folds(names: list[str], k: int = 5, seed: int = 0) -> list[list[str]]:
    """``k`` folds of the sorted names after a seeded shuffle (deterministic for a given list)."""
    order = np.random.default_rng(seed).permutation(sorted(names))
    return [sorted(order[i::k].tolist()) for i in range(k)]


def attributes(root: Path = DAVIS) -> dict[str, list[str]]:
    """Sequence name -> its DAVIS attributes, from ``db_info.yml``."""
    info = yaml.safe_load((root / "db_info.yml").read_text())
    return {s["name"]: list(s.get("attributes", [])) for s in info["sequences"]}


def report(per_sequence: dict[str, dict], measures: tuple[str, ...], attrs: dict[str, list[str]],
           wanted: tuple[str, ...] = ATTRIBUTES) -> str:
    """A plain-text table: one row per sequence, then mean, worst, and the mean per attribute."""
    lines = [f"{'sequence':<18}{'fold':>5}" + "".join(f"{m:>8}" for m in measures) + "  attributes"]
    for name, row in sorted(per_sequence.items()):
        values = "".join(f"{row[m]:>8.3f}" if row.get(m) is not None else f"{'-':>8}" for m in measures)
        lines.append(f"{name:<18}{row['fold']:>5}{values}  {' '.join(attrs.get(name, []))}")

    def mean(m, names):
        v = [per_sequence[n][m] for n in names if per_sequence[n].get(m) is not None]
        return f"{np.mean(v):>8.3f}" if v else f"{'-':>8}"

    names = list(per_sequence)
    lines.append(f"{'mean':<18}{len(names):>5}" + "".join(mean(m, names) for m in measures))
    worst = [min((per_sequence[n][m] for n in names if per_sequence[n].get(m) is not None), default=None)
             for m in measures]
    lines.append(f"{'worst':<18}{'':>5}" + "".join(f"{w:>8.3f}" if w is not None else f"{'-':>8}" for w in worst))
    for a in wanted:
        members = [n for n in names if a in attrs.get(n, [])]
        if members:
            lines.append(f"{'attr ' + a:<18}{len(members):>5}" + "".join(mean(m, members) for m in measures))
    return "\n".join(lines)


def key_value(text: str) -> tuple[str, object]:
    """An argparse type: ``k=v`` as ``(k, v)``, the value read as YAML (``0.15`` a number); anything else is a usage
    error naming the option, not a traceback."""
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected key=value, got {text!r}")
    try:
        return key, yaml.safe_load(value)
    except yaml.YAMLError as exc:
        raise argparse.ArgumentTypeError(f"{key}: not YAML: " + " ".join(str(exc).split())) from None


def _finite(value):
    return float(value) if value is not None and np.isfinite(value) else None


def yaml_value(text: str):
    """An argparse type: the YAML value of ``text`` (a syntax error is a usage error, not a traceback)."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise argparse.ArgumentTypeError("not YAML: " + " ".join(str(exc).split())) from None


def _parsed_phases(phases: list[dict], option: str) -> list:
    """``phases`` in the recipe (instead of its own) checked as the training spec checks them: paths made
    absolute, defaults filled in; a problem ends the run with one line naming ``option``."""
    from eponet.core.errors import EponetError
    from eponet.training.config import parse_train_config

    doc = recipe_without(None)
    doc["phases"] = phases
    try:
        return parse_train_config(doc, base_dir=Path.cwd()).phases
    except EponetError as exc:
        raise SystemExit(f"{option}: {exc}") from None


def _source_dict(source) -> dict:
    return {source.kind: {k: str(v) if isinstance(v, Path) else v for k, v in source.options.items()}}


def mixed_sources(sources: list) -> list[dict]:
    """``--recipe-data`` sources, checked in the recipe's DAVIS phase (:func:`_parsed_phases`)."""
    davis = recipe_without(None)["phases"][0]
    [phase] = _parsed_phases([{**davis, "data": [davis["data"], *sources]}], "--recipe-data")
    return [_source_dict(s) for s in phase.data[1:]]


def pre_phases(phases: list) -> list[dict]:
    """``--recipe-phase`` phases, checked (:func:`_parsed_phases`), each data source as ``fold_sources`` takes them."""
    return [{"name": p.name, "epochs": p.epochs, "samples_per_epoch": p.samples_per_epoch,
             "data": [_source_dict(s) for s in (p.data if isinstance(p.data, tuple) else (p.data,))]}
            for p in _parsed_phases(phases, "--recipe-phase")]


def fold_sources(sources: list[dict], i: int, held_out: list[str]) -> list[dict]:
    """``--recipe-data`` sources for fold ``i``: a ``paste`` source draws from the fold's training sequences only
    (its ``exclude`` gets the held-out ones) and writes into ``<dir>/fold<i>``."""
    out = []
    for source in sources:
        if "paste" in source:
            o = source["paste"]
            source = {"paste": {**o, "dir": str(Path(o["dir"]) / f"fold{i}"),
                                "exclude": sorted(set(o["exclude"]) | set(held_out))}}
        out.append(source)
    return out


def run_ed(split: list[list[str]], rigidity: dict, flow_cache: Path | None, trajectories: dict | None = None,
           seed: int = 0, flow: dict | None = None, whiten: float | None = None,
           oracle: bool = False) -> dict[str, dict]:
    """ED ROC AUC per sequence (no training, so the folds only label the rows), the stage seeded with ``seed``;
    ``flow``: settings of the ``dis`` flow stage (default: OpenCV's ``medium`` as it is, finest level 1, where the
    presets run level 0: ``finest_scale=0``); ``whiten``: score ED over the local flow spread (see
    :func:`geometry_davis_auc.sequence_auc`); ``oracle``: each group's model fitted on the annotated background
    (:func:`geometry_davis_auc.background_oracle`), the ceiling of any fit of the stage's model."""
    import logging

    import geometry_davis_auc as g
    from eponet.plugins.rigidity.trifocal import TrifocalRigidity

    logging.basicConfig(level=logging.ERROR)
    g.make_stage = lambda variant: TrifocalRigidity(**rigidity)
    out = {}
    for i, names in enumerate(split):
        for name in names:
            r = g.sequence_auc(name, ("default",), flow_cache=flow_cache, trajectories=trajectories, seed=seed,
                               flow_settings=flow, whiten=whiten, oracle=oracle)
            out[name] = {"fold": i, "AUC": r["default"], "models": r["default_models"]}
            print(f"  {name:<18} AUC {r['default']:.3f} {r['default_models']}", flush=True)
    return out


def listed_sha256(folder: Path) -> dict[Path, str]:
    """``folder/SHA256SUMS`` (``sha256sum``'s format: digest, then the path relative to ``folder``) as resolved
    path -> digest; empty when the folder has none (networks trained here)."""
    sums = folder / "SHA256SUMS"
    if not sums.is_file():
        return {}
    pairs = (line.split(maxsplit=1) for line in sums.read_text().splitlines() if line.strip())
    return {(folder / name.strip().lstrip("*")).resolve(): digest for digest, name in pairs}


def epo_crf() -> dict:
    """The ``epo`` preset's refiner, every parameter spelt out (a spec's refiner merges onto its preset's)."""
    from eponet.core.registry import get_registry

    registry = get_registry()
    defaults = {p.name: p.default for p in registry.get("refiner", "densecrf").params}
    return {**defaults, **registry.resolve_preset("epo")["refiner"]}


def fusion_recipe_without(sequences: list[str], motion_net: list[Path]) -> dict:
    """The EpO+ fusion recipe (``examples/train-epo-plus.yaml``, absolute paths) on top of the frozen
    ``motion_net`` networks (their mean), trained without ``sequences`` and validated on them."""
    doc = absolutise(yaml.safe_load(FUSION_RECIPE.read_text()), FUSION_RECIPE.parent)
    doc["motion_net"]["weights"] = [str(path.resolve()) for path in motion_net]
    doc["phases"][-1]["data"]["davis"]["exclude"] = list(sequences)
    doc["validation"]["davis"]["sequences"] = list(sequences)
    return doc


def run_epo(split: list[list[str]], out: Path, jobs: int, refiner: str, which: list[int], rigidity: dict,
            weights: Path | None = None, save: tuple[str, ...] = ("masks",), preset: str = "epo",
            fusion: dict | None = None, plus: bool = False, recipe_rigidity: dict | None = None,
            run: dict | None = None, only: set[str] | None = None, trajectories: dict | None = None,
            seeds: tuple[int, ...] = (0,), crf_settings: dict | None = None, run_seed: int = 0,
            flow: dict | None = None, motion_net: dict | None = None, recipe_model: dict | None = None,
            teacher: Path | None = None, teacher_seeds: tuple[int, ...] = (0, 1), teacher_share: float = 0.5,
            recipe_data: list[dict] | None = None, recipe_phases: list[dict] | None = None,
            fusion_maps: str = "own", appearance: dict | None = None,
            fusion_seeds: tuple[int, ...] = (0,), recipe_dropout: dict | None = None,
            fusion_model: dict | None = None, fusion_dropout: dict | None = None,
            recipe_augment: dict | None = None) -> dict[str, dict]:
    """Train one network per fold and seed (``jobs`` at once, one thread each; into ``weights`` or ``out``:
    ``fold<i>/weights.pt`` for the first seed, ``fold<i>/seed<s>/weights.pt`` for the others) and score its
    held-out sequences with the mean of the seeds' networks (the ``epo`` preset's pair: ``seeds=(0, 1)``), with the ``rigidity`` settings merged onto the preset's when given
    (``recipe_rigidity``: merged onto the training recipe's rigidity stage, the ED the network learns, and onto
    the fusion recipe's with ``plus``;
    ``recipe_model``: onto its ``model`` section, e.g. ``flow_centring``; ``recipe_dropout``: onto its
    ``input_dropout`` section, e.g. ``probability=0`` for ``inputs=ed``; ``recipe_augment``: onto its ``augment``
    section, e.g. ``zoom``). ``plus``: then
    train each fold's EpO+ fusion on that fold's frozen network (into ``out/fold<i>/fusion``) and score the
    ``epo+`` preset with both. ``run``: the spec's ``run`` settings; ``only``: score these sequences only;
    ``crf_settings``: merged onto the refiner (the preset's, or the one ``refiner`` names); ``run_seed``: the held-out
    runs' spec seed (RANSAC, self-training), not the networks'; ``flow``, ``motion_net``: settings merged onto the
    preset's flow stage and onto the fold's motion network when scoring. ``teacher``: a folder of fold networks
    like ``weights`` (seeds ``teacher_seeds``) that each fold's recipe distils (``teacher: {weights: ..., share:
    teacher_share}``), i.e. networks trained without the same held-out sequences. ``recipe_phases``: phases
    (``pre_phases``) trained before the recipe's DAVIS phase. ``recipe_data``: data sources
    (``{rbsf: {dir: ..., scene: {...}}}``, absolute paths) mixed into the recipe's DAVIS phase.
    ``fusion_maps``: ``own``, the fusion of fold ``i`` learns on fold ``i``'s network's maps of its 24 training
    sequences (maps of sequences that network was trained on); ``out-of-fold``, each of them from the network of the
    fold that held it out (``motion_maps`` of the fusion recipe: maps as unseen video gets them, as stacking asks;
    but those networks were trained on fold ``i``'s sequences, so the figures are not fully held out: a scouting
    measure, not a figure of record). ``appearance``: the appearance stage (``plugin`` and settings) the
    held-out runs use and, with ``plus``, the fusions learn on; ``fusion_seeds``: the fusions' training seeds, one
    fusion per seed (``out/fold<i>/fusion`` for the first, ``fusion-seed<s>`` for the others) whose mean is scored;
    ``fusion_model``, ``fusion_dropout``: merged onto the fusion recipe's ``model`` and ``input_dropout`` sections,
    e.g. ``feature_dropout``, ``probability``."""
    weights = weights or out
    threads = 1 if jobs > 1 else None

    def recipe(i, seed):
        doc = recipe_without(split[i])
        doc["geometry"]["stages"]["rigidity"].update(recipe_rigidity or {})
        doc["model"].update(recipe_model or {})
        doc["input_dropout"].update(recipe_dropout or {})
        doc["augment"].update(recipe_augment or {})
        doc["seed"] = seed
        if recipe_data:
            doc["phases"][0]["data"] = [doc["phases"][0]["data"], *fold_sources(recipe_data, i, split[i])]
        doc["phases"] = [{**p, "data": fold_sources(p["data"], i, split[i])} for p in recipe_phases or []] + doc["phases"]
        if teacher is not None:
            doc["teacher"] = {"share": teacher_share, "weights": [
                str(teacher.resolve() / f"fold{i}" / ("" if s == teacher_seeds[0] else f"seed{s}") / "weights.pt")
                for s in teacher_seeds]}
        return doc

    def folder(i, seed):
        return weights / f"fold{i}" / ("" if seed == seeds[0] else f"seed{seed}")

    def nets(i):
        return [folder(i, seed) / "weights.pt" for seed in seeds]

    def train(job):
        i, seed = job
        return train_variant(folder(i, seed), lambda: recipe(i, seed), threads, retrain=False)

    def fusion_folder(i, seed):
        return out / f"fold{i}" / ("fusion" if seed == fusion_seeds[0] else f"fusion-seed{seed}")

    def train_fusion(job):
        i, seed = job

        def fusion_recipe():
            doc = fusion_recipe_without(split[i], nets(i))
            doc["geometry"]["stages"]["rigidity"].update(recipe_rigidity or {})  # the ED the networks learnt on
            if appearance:
                doc["appearance"] = {**doc["appearance"], **appearance}
            doc["model"].update(fusion_model or {})
            doc["input_dropout"].update(fusion_dropout or {})
            doc["seed"] = seed
            if fusion_maps == "out-of-fold":
                doc["motion_maps"] = [{"weights": [str(path.resolve()) for path in nets(j)], "sequences": split[j]}
                                      for j in range(len(split)) if j != i]
            return doc

        return train_variant(fusion_folder(i, seed), fusion_recipe, threads, retrain=False)

    from eponet.core.errors import EponetError
    from eponet.training.trainer import GENERATORS

    # generated data (RBSF-style clips, the same for every fold; pasted clips, a set per fold) written before the
    # folds' trainings run side by side
    sources = [*(recipe_data or []), *(d for p in recipe_phases or [] for d in p["data"])]
    for i in which:
        for source in fold_sources(sources, i, split[i]):
            [(kind, options)] = source.items()
            try:
                if kind in GENERATORS:
                    GENERATORS[kind](options)
            except EponetError as exc:
                raise SystemExit(f"{kind} data of fold {i}: {exc}") from None
    seconds = dict.fromkeys(which, 0.0)
    trainings = [(i, seed) for seed in seeds for i in which]
    with ThreadPoolExecutor(jobs) as pool:  # every network first, then the fusions that read them
        for (i, _), s in zip(trainings, pool.map(train, trainings)):
            seconds[i] += s
        if plus:
            fusions = [(i, seed) for seed in fusion_seeds for i in which]
            for (i, _), s in zip(fusions, pool.map(train_fusion, fusions)):
                seconds[i] += s
    scored = {i: [n for n in split[i] if not only or n in only] for i in which}
    davis = validation_root(DAVIS, [n for i in which for n in scored[i]], out)
    crf = {"authors": authors_crf, "epo": epo_crf}.get(refiner, lambda: None)()
    if crf_settings:  # (a spec's refiner merges onto its preset's)
        crf = {"plugin": "densecrf", **(crf or {}), **crf_settings}
    per_sequence = {}
    sums = listed_sha256(weights)  # kept networks (benchmarks/fold-networks) are checked before they load
    for i in which:
        paths = nets(i)
        stages = {"motion_net": {"plugin": "epo_unet", "weights": [str(p) for p in paths] if len(paths) > 1
                                 else str(paths[0]), **(motion_net or {})}}
        if sums:
            digests = [sums.get(path.resolve()) for path in paths]
            if None in digests:
                raise SystemExit(f"{paths[digests.index(None)]}: not listed in {weights / 'SHA256SUMS'}")
            stages["motion_net"]["sha256"] = digests if len(digests) > 1 else digests[0]
        if rigidity:
            stages["rigidity"] = {"plugin": "trifocal", **rigidity}
        if trajectories:
            stages["trajectories"] = {"plugin": "dense", **trajectories}
        if flow:
            stages["flow"] = {"plugin": "dis", **flow}
        if crf is not None:
            stages["refiner"] = crf
        if appearance:
            stages["appearance"] = appearance
        if plus:
            fused = [str(fusion_folder(i, seed) / "weights.pt") for seed in fusion_seeds]
            stages["fusion"] = {"plugin": "convgru", "weights": fused if len(fused) > 1 else fused[0], **(fusion or {})}
        elif fusion:
            stages["fusion"] = fusion
        if not scored[i]:
            continue
        try:
            manifest = run_validation(stages, out / f"fold{i}" / "heldout", davis, scored[i], save=save,
                                      preset=preset, evaluate={"dataset": "davis2016", "t": True}, run=run,
                                      seed=run_seed)
        except EponetError as exc:  # e.g. a kept network that is not the one SHA256SUMS lists
            raise SystemExit(f"fold {i}: {exc}") from None
        for name, v in manifest["evaluation"]["sequences"].items():
            per_sequence[name] = {"fold": i, "train_s": round(seconds[i], 1),
                                  **{m: _finite(v.get(m, {}).get("mean")) for m in "JFT"}}
    return per_sequence


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--what", choices=("ed", "epo", "epo+"), required=True)
    parser.add_argument("--out", type=Path, default=None, help="default: runs/kfold-<what>")
    parser.add_argument("--jobs", type=int, default=2, help="folds trained at once (one thread each)")
    parser.add_argument("--folds", default=None, help="comma-separated fold indices (default: all)")
    parser.add_argument("--refiner", choices=("preset", "authors", "epo"), default="preset",
                        help="the preset's CRF, the authors' (the plugin's defaults at 427 px) or the epo preset's")
    parser.add_argument("--crf", nargs="*", default=[], type=key_value,
                        help="epo: key=value settings merged onto that refiner, e.g. backend=grid grid_cell=1.0")
    parser.add_argument("--preset", default="epo", help="epo: the preset the held-out sequences run through (its "
                        "motion network replaced by the fold's), e.g. epo-st")
    parser.add_argument("--fusion", nargs="*", default=[], type=key_value,
                        help="epo: plugin=NAME and key=value settings of the fusion stage (e.g. plugin=selftrain weight=0.5)")
    parser.add_argument("--rigidity", nargs="*", default=[], type=key_value,
                        help="key=value settings of the trifocal stage (epo: merged onto the preset's when scoring)")
    parser.add_argument("--trajectories", nargs="*", default=[], type=key_value,
                        help="key=value settings of the dense trajectory stage (ed and epo), e.g. cull_collisions=true")
    parser.add_argument("--recipe-rigidity", nargs="*", default=[], type=key_value,
                        help="key=value merged onto the training recipe's rigidity stage (the ED the folds learn)")
    parser.add_argument("--recipe-model", nargs="*", default=[], type=key_value,
                        help="key=value merged onto the training recipe's model section, e.g. flow_centring=rigid")
    parser.add_argument("--recipe-dropout", nargs="*", default=[], type=key_value,
                        help="key=value merged onto the training recipe's input_dropout section, e.g. probability=0 "
                        "(with --recipe-model inputs=ed: the ED channel is the only input)")
    parser.add_argument("--recipe-augment", nargs="*", default=[], type=key_value,
                        help="key=value merged onto the training recipe's augment section, e.g. 'zoom=[0.7, 1.4]'")
    parser.add_argument("--seeds", default="0",
                        help="epo: comma-separated training seeds; the held-out sequences run the mean of the seeds' "
                        "networks (0,1: a pair, as the epo+ preset runs; the first seed's are fold<i>/weights.pt)")
    parser.add_argument("--recipe-data", type=yaml_value, action="append", default=[],
                        help="a data source (YAML) mixed into the recipe's DAVIS phase, e.g. '{rbsf: {dir: runs/rbsf-mix, "
                             "sequences: 24, scene: {dynamic_texture_probability: 1.0}}}' or '{paste: {dir: runs/paste, root: "
                             "../shared/data/davis2016-train/DAVIS}}' (objects of each fold's training sequences "
                             "pasted over others, into <dir>/fold<i>); repeatable")
    parser.add_argument("--recipe-phase", type=yaml_value, action="append", default=[],
                        help="a phase (YAML) trained before the recipe's DAVIS phase, e.g. '{name: paste, epochs: 2, data: "
                             "{paste: {dir: runs/paste, root: ../shared/data/davis2016-train/DAVIS}}}' (the paper's "
                             "pre-training); repeatable")
    parser.add_argument("--teacher", type=Path, default=None,
                        help="distil: each fold's recipe learns from this folder's fold networks (like --weights)")
    parser.add_argument("--teacher-seeds", default="0,1", help="the teacher folder's seeds (default: 0,1, a pair)")
    parser.add_argument("--teacher-share", type=float, default=0.5, help="the teachers' share of the target")
    parser.add_argument("--weights", type=Path, default=None,
                        help="epo: folder of already trained fold<i>/weights.pt to score (default: --out)")
    parser.add_argument("--run", nargs="*", default=[], type=key_value,
                        help="epo: key=value settings of the spec's run section (e.g. ed_window=null)")
    parser.add_argument("--sequences", default=None,
                        help="epo: comma-separated sequences to score (default: every sequence of the folds)")
    parser.add_argument("--flow", nargs="*", default=[], type=key_value,
                        help="key=value settings of the dis flow stage (ed: default OpenCV's medium, finest level 1; "
                        "epo: merged onto the preset's, finest_scale 0), e.g. finest_scale=0 patch_stride=5")
    parser.add_argument("--motion-net", nargs="*", default=[], type=key_value,
                        help="epo: key=value settings of the fold's epo_unet stage, e.g. precision=bfloat16")
    parser.add_argument("--flow-cache", type=Path, default=None)
    parser.add_argument("--oracle", action="store_true",
                        help="ed: fit each frame group's model on the annotated background only (the fits' ceiling)")
    parser.add_argument("--ed-whiten", type=float, default=None, metavar="EPS",
                        help="(ed) score ED / (EPS + the local spread of the flow in px) instead of ED")
    parser.add_argument("--seed", type=int, default=0,
                        help="the rigidity stage's seed (ed), or the held-out runs' spec seed (epo, epo+: RANSAC, "
                        "self-training), to measure how far the figures move by chance")
    parser.add_argument("--save", default="masks",
                        help="epo: comma-separated outputs of the held-out runs (output.save), e.g. masks,saliency,ed")
    parser.add_argument("--appearance", nargs="*", default=[], type=key_value,
                        help="epo, epo+: plugin=NAME and key=value settings of the appearance stage the held-out "
                             "runs use (and, for epo+, the fusions learn on), e.g. plugin=efficientnet_lite2")
    parser.add_argument("--fusion-seed", default="0", help="epo+: the fusions' training seed; a comma-separated list "
                        "trains one fusion per seed and scores their mean (fusion-seed<s>/ beside fusion/)")
    parser.add_argument("--fusion-model", nargs="*", default=[], type=key_value,
                        help="epo+: key=value merged onto the fusion recipe's model section, e.g. feature_dropout=0.75")
    parser.add_argument("--fusion-dropout", nargs="*", default=[], type=key_value,
                        help="epo+: key=value merged onto the fusion recipe's input_dropout section, e.g. probability=0")
    parser.add_argument("--fusion-maps", choices=("own", "out-of-fold"), default="own",
                        help="epo+: the maps each fold's fusion learns on: its own network's (trained on those "
                        "sequences) or, for each sequence, the network of the fold that held it out (every fold's "
                        "network must exist: a scouting measure, see run_epo)")
    parser.add_argument("--attributes", nargs="*", default=list(ATTRIBUTES))
    args = parser.parse_args(argv)
    if args.oracle and args.what != "ed":
        parser.error("--oracle fits the ED's models on the annotation: it goes with --what ed only")
    if not (DAVIS / "ImageSets" / "train.txt").exists():
        print(f"DAVIS-2016 train data not found under {DAVIS} (set EPONET_SHARED_DATA)")
        return 1
    split = folds((DAVIS / "ImageSets" / "train.txt").read_text().split())
    which = [int(i) for i in args.folds.split(",")] if args.folds else list(range(len(split)))
    only = set(args.sequences.split(",")) if args.sequences else None
    if only:
        unknown = only - {n for names in split for n in names}
        if unknown:
            raise SystemExit(f"--sequences: not DAVIS-2016 train sequences: {', '.join(sorted(unknown))}")
        which = [i for i in which if only & set(split[i])]
    # training data checked before anything is written under --out
    recipe_data = mixed_sources(args.recipe_data) if args.recipe_data and args.what != "ed" else []
    recipe_phases = pre_phases(args.recipe_phase) if args.recipe_phase and args.what != "ed" else []
    out = args.out or ROOT / "runs" / f"kfold-{args.what}"
    out.mkdir(parents=True, exist_ok=True)
    for i in which:
        print(f"fold {i}: {', '.join(split[i])}")
    rigidity = dict(args.rigidity)
    trajectories = dict(args.trajectories)
    flow = dict(args.flow)
    motion_net = dict(args.motion_net)
    if args.what == "ed":
        per_sequence = run_ed([split[i] if i in which else [] for i in range(len(split))], rigidity, args.flow_cache,
                              trajectories, args.seed, flow, args.ed_whiten, args.oracle)
        measures = ("AUC",)
        meta = {"rigidity": rigidity, **({"ed_whiten": args.ed_whiten} if args.ed_whiten is not None else {}),
                **({"oracle": "background"} if args.oracle else {})}
    else:
        fusion = dict(args.fusion)
        appearance = dict(args.appearance)
        plus = args.what == "epo+"
        preset = "epo+" if plus else args.preset
        recipe_rigidity = dict(args.recipe_rigidity)
        recipe_model = dict(args.recipe_model)
        recipe_dropout = dict(args.recipe_dropout)
        recipe_augment = dict(args.recipe_augment)
        run = dict(args.run)
        seeds = tuple(int(s) for s in args.seeds.split(","))
        fusion_seeds = tuple(int(s) for s in args.fusion_seed.split(","))
        crf = dict(args.crf)
        fusion_model, fusion_dropout = dict(args.fusion_model), dict(args.fusion_dropout)
        per_sequence = run_epo(split, out, args.jobs, args.refiner, which, rigidity, args.weights,
                               tuple(args.save.split(",")), preset, fusion, plus, recipe_rigidity, run, only,
                               trajectories, seeds, crf, args.seed, flow, motion_net, recipe_model,
                               args.teacher, tuple(int(s) for s in args.teacher_seeds.split(",")), args.teacher_share,
                               recipe_data, recipe_phases, args.fusion_maps, appearance, fusion_seeds, recipe_dropout,
                               fusion_model, fusion_dropout, recipe_augment)
        measures = ("J", "F", "T")
        meta = {"recipe": "examples/train-epo.yaml", "refiner": args.refiner, "rigidity": rigidity}
        if recipe_rigidity:
            meta["recipe_rigidity"] = recipe_rigidity
        if recipe_model:
            meta["recipe_model"] = recipe_model
        if recipe_dropout:
            meta["recipe_dropout"] = recipe_dropout
        if recipe_augment:
            meta["recipe_augment"] = recipe_augment
        if recipe_data:
            meta["recipe_data"] = recipe_data
        if recipe_phases:
            meta["recipe_phases"] = recipe_phases
        if args.teacher:
            meta["teacher"] = {"folder": str(args.teacher), "seeds": args.teacher_seeds, "share": args.teacher_share}
        if run:
            meta["run"] = run
        if crf:  # (kept out of the default's record: earlier reports still merge)
            meta["crf"] = crf
        if seeds != (0,):  # (kept out of the default's record: earlier reports still merge)
            meta["seeds"] = list(seeds)
        if plus:
            meta["fusion_recipe"] = "examples/train-epo-plus.yaml"
        # the fusion recipe's overrides, when given (kept out of the default's record: earlier reports still merge)
        meta.update({k: v for k, v in (("fusion_model", fusion_model), ("fusion_dropout", fusion_dropout)) if v})
        if args.fusion_maps != "own":  # (kept out of the default's record: earlier reports still merge)
            meta["fusion_maps"] = args.fusion_maps
        if preset != "epo" or fusion:  # (kept out of the default's record: earlier reports still merge)
            meta.update(preset=preset, fusion=fusion)
        if appearance:  # (kept out of the default's record: earlier reports still merge)
            meta["appearance"] = appearance
        if fusion_seeds != (0,):  # (kept out of the default's record: earlier reports still merge)
            meta["fusion_seed"] = fusion_seeds[0] if len(fusion_seeds) == 1 else list(fusion_seeds)
    if args.seed:  # (kept out of the default's record: earlier reports still merge)
        meta["seed"] = args.seed
    if trajectories:  # (kept out of the default's record: earlier reports still merge)
        meta["trajectories"] = trajectories
    if flow:  # (kept out of the default's record: earlier reports still merge)
        meta["flow"] = flow
    if motion_net:  # (kept out of the default's record: earlier reports still merge)
        meta["motion_net"] = motion_net
    previous = out / "kfold.json"
    if previous.is_file():  # folds scored by an earlier call with the same settings are kept
        earlier = json.loads(previous.read_text())
        if {k: earlier.get(k) for k in meta} == meta:
            per_sequence = {**{n: r for n, r in earlier["sequences"].items() if r["fold"] not in which},
                            **per_sequence}
    text = report(per_sequence, measures, attributes(), tuple(args.attributes))
    print(text)
    (out / "kfold.json").write_text(json.dumps({"folds": split, **meta, "sequences": per_sequence}, indent=2))
    (out / "kfold.txt").write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
