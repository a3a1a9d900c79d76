"""How well ED separates the moving object on real video: per-frame ROC AUC of ED maps against the
DAVIS-2016 ground-truth masks, per sequence, for four rigidity variants.

Variants: ``default`` (trifocal, degeneracy parallax, guided sampling with the border prior), ``gric`` (the
previous default: degeneracy gric, no border prior), ``none`` (trifocal, degeneracy none),
``paper`` (trifocal, degeneracy none and uniform sampling: the paper's estimation), ``fundamental`` (pairwise
F, USAC MAGSAC++) and ``homography`` (dominant homographies only); all other parameters at their defaults. All use the
``dense`` trajectories (defaults) on OpenCV DIS flow (preset medium) of the 427x240 frames; masks are
reduced to 427x240 by area averaging (a pixel is foreground when more than half of it is). Frames whose mask
is empty are skipped (AUC undefined).

``--oracle`` fits every group's model on the annotated background only (:func:`background_oracle`): the AUC
that no better fit of the same model (sampling, robust scoring, model selection) can exceed by more than
chance. Where it is low too, the background is not rigid (water, reflections) and no fit of that model helps.
Usage::

    python benchmarks/geometry_davis_auc.py [--sequences bear boat ...] [--frames N] [--variants default none]
        [--flow-cache DIR] [--oracle]
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("EPONET_SHARED_DATA") or REPO.parent / "shared" / "data")
DAVIS = DATA / "davis2016-train" / "DAVIS"
VARIANTS = ("default", "gric", "none", "paper", "fundamental", "homography")


def roc_auc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``score`` for boolean labels (Mann-Whitney; ties count one half)."""
    from scipy.stats import rankdata

    pos = np.asarray(positive, bool).ravel()
    n_pos = int(pos.sum())
    n_neg = pos.size - n_pos
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(np.asarray(score, np.float64).ravel())
    return float((ranks[pos].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def make_stage(variant: str):
    from eponet.plugins.rigidity.fundamental import FundamentalRigidity
    from eponet.plugins.rigidity.homography import HomographyRigidity
    from eponet.plugins.rigidity.trifocal import TrifocalRigidity

    return {
        "default": TrifocalRigidity,
        "gric": lambda: TrifocalRigidity(degeneracy="gric", border_prior=0.0),
        "none": lambda: TrifocalRigidity(degeneracy="none"),
        "paper": lambda: TrifocalRigidity(degeneracy="none", sampling="uniform"),
        "fundamental": FundamentalRigidity,
        "homography": HomographyRigidity,
    }[variant]()


def background_oracle(stage, masks: np.ndarray):
    """``stage`` (a rigidity stage) with each frame group's model fitted on the annotated background only.

    The stage's sample of a group is cut to its points whose position in the group's first frame lies outside
    that frame's mask (bool ``(F, H, W)``, the trajectories' frame size); scoring, sampling and painting stay the
    stage's own. The ED's AUC then measures the model and its distance with a fit that knows the answer: an upper
    bound, up to the RANSAC seed, for any way of fitting the same model. The stage is changed in place and
    returned; it serves one :meth:`score` call (its groups are counted off as the fits come)."""
    from dataclasses import replace

    from eponet.geometry.scoring import frame_groups

    groups = iter(frame_groups(len(masks), stage.views, stage.stride))
    fit = stage.estimate
    h, w = masks.shape[1:]

    def spread(model, keep):  # inlier flags over the whole sample, as the stage's scoring reads them
        if model is None or model.inliers is None:
            return model
        inliers = np.zeros(len(keep), bool)
        inliers[keep] = model.inliers
        return replace(model, inliers=inliers, general=spread(model.general, keep))

    def estimate(points, rng, frame_size=None):
        first = next(groups)[0]
        x = np.clip(np.floor(points[0] + 0.5).astype(np.int64), 0, [w - 1, h - 1])
        keep = ~masks[first][x[:, 1], x[:, 0]]
        return spread(fit([p[keep] for p in points], rng, frame_size), keep)

    stage.estimate = estimate
    return stage


def load_sequence(name: str, frames: int | None = None, root: Path = DAVIS):
    """Grey 240p frames (F, 240, 427) and boolean masks at the same size."""
    files = sorted((root / "JPEGImages" / "240p" / name).glob("*.jpg"))[:frames]
    gray = np.stack([cv2.imread(str(f), cv2.IMREAD_GRAYSCALE) for f in files])
    h, w = gray.shape[1:]
    masks = []
    for f in sorted((root / "Annotations" / "480p" / name).glob("*.png"))[: len(files)]:
        m = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0
        masks.append(cv2.resize(m, (w, h), interpolation=cv2.INTER_AREA) > 0.5)
    return gray, np.stack(masks)


def dis_flow(gray: np.ndarray, flow: dict | None = None):
    """Forward and backward DIS flow of grey frames (F, H, W); ``flow``: settings of the ``dis`` flow stage
    (default: OpenCV's ``medium`` preset as it is, finest level 1)."""
    from eponet.core.types import FlowPair
    from eponet.plugins.flow.dis import DisFlow

    forward, backward = DisFlow(**(flow or {})).calculators()
    fw = np.stack([forward(gray[t], gray[t + 1]) for t in range(len(gray) - 1)])
    bw = np.stack([backward(gray[t + 1], gray[t]) for t in range(len(gray) - 1)])
    return FlowPair(fw.astype(np.float32), bw.astype(np.float32))


def flow_spread(flow: np.ndarray, window: int = 9) -> np.ndarray:
    """Float32 ``(H, W)``: the standard deviation in pixels of the flow vectors ``(H, W, 2)`` in the ``window`` x
    ``window`` pixels around each pixel, the motion network's spread channel before its log
    (:func:`eponet.nets.unet.flow_spread`) except at the border, which this mirrors and that one cuts."""
    mean = cv2.blur(flow, (window, window), borderType=cv2.BORDER_REFLECT)
    square = cv2.blur(flow * flow, (window, window), borderType=cv2.BORDER_REFLECT)
    return np.sqrt(np.clip(square - mean * mean, 0, None).sum(-1))


def flow_tag(flow: dict | None) -> str:
    """The part of a flow cache's file name that tells its settings apart (empty for the default)."""
    return "".join(f"_{k}{v}" for k, v in sorted((flow or {}).items()))


def sequence_auc(name: str, variants=VARIANTS, frames: int | None = None, flow_cache: Path | None = None,
                 seed: int = 0, root: Path = DAVIS, trajectories: dict | None = None,
                 flow_settings: dict | None = None, whiten: float | None = None, oracle: bool = False) -> dict:
    """Mean per-frame ROC AUC of each variant's ED for one sequence (and timings); ``trajectories``: settings of
    the ``dense`` trajectory stage, ``flow_settings``: of the ``dis`` flow stage (see :func:`dis_flow`). With
    ``whiten`` the score is ``ED / (whiten + s)``, ``s`` the local spread of the frame's forward flow
    (:func:`flow_spread`): the distance in units of how incoherent the flow around the pixel is. ``oracle``: each
    group's model fitted on the annotated background (:func:`background_oracle`)."""
    from eponet.core.types import FlowPair
    from eponet.plugins.trajectories.dense import DenseTrajectories

    gray, masks = load_sequence(name, frames, root)
    cached = flow_cache / f"{name}_{len(gray)}{flow_tag(flow_settings)}.npz" if flow_cache else None
    if cached is not None and cached.exists():
        data = np.load(cached)
        flow = FlowPair(data["forward"], data["backward"])
    else:
        flow = dis_flow(gray, flow_settings)
        if cached is not None:
            cached.parent.mkdir(parents=True, exist_ok=True)
            np.savez(cached, forward=flow.forward, backward=flow.backward)
    t0 = time.perf_counter()
    traj = DenseTrajectories(**(trajectories or {})).build(flow)
    out = {"frames": len(gray), "traj_s": time.perf_counter() - t0}
    for variant in variants:
        t0 = time.perf_counter()
        stage = make_stage(variant)
        if oracle:
            stage = background_oracle(stage, masks)
        result = stage.score(traj, flow, np.random.default_rng(seed))
        scores = result.ed
        if whiten is not None:
            forward = np.concatenate([flow.forward, flow.forward[-1:]])  # the last frame takes the one before it
            scores = [ed / (whiten + flow_spread(f)) for ed, f in zip(result.ed, forward)]
        out[variant] = float(np.nanmean([roc_auc(scores[t], masks[t]) for t in range(len(masks))]))
        out[variant + "_s"] = time.perf_counter() - t0
        models = [t.get("model") for t in result.triplets]
        out[variant + "_models"] = {m: models.count(m) for m in sorted(set(models))}
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", nargs="*", help="default: the 30 DAVIS-2016 train sequences")
    parser.add_argument("--frames", type=int, default=None, help="only the first N frames of each sequence")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    parser.add_argument("--flow-cache", type=Path, default=None, help="folder to keep DIS flow between runs")
    parser.add_argument("--models", action="store_true", help="also print the models chosen per sequence")
    parser.add_argument("--oracle", action="store_true",
                        help="fit each group's model on the annotated background only (the ceiling of the fits)")
    args = parser.parse_args(argv)
    if not (DAVIS / "ImageSets" / "train.txt").exists():
        print(f"DAVIS-2016 train data not found under {DAVIS} (set EPONET_SHARED_DATA)")
        return 1
    logging.basicConfig(level=logging.ERROR)
    names = args.sequences or (DAVIS / "ImageSets" / "train.txt").read_text().split()
    fits = "; models fitted on the annotated background" if args.oracle else ""
    print(f"ED ROC AUC on DAVIS-2016 train, 427x240, DIS flow, seed 0{fits}; mean per-frame AUC per sequence")
    header = " ".join(f"{v:>11}" for v in args.variants)
    print(f"{'sequence':<18} {'frames':>6} {header}   s/frame (traj + each variant)")
    rows = []
    for name in names:
        r = sequence_auc(name, args.variants, args.frames, args.flow_cache, oracle=args.oracle)
        rows.append(r)
        per_frame = (r["traj_s"] + sum(r[v + "_s"] for v in args.variants) / len(args.variants)) / r["frames"]
        values = " ".join(f"{r[v]:>11.3f}" for v in args.variants)
        print(f"{name:<18} {r['frames']:>6} {values}   {per_frame:.3f}", flush=True)
        if args.models:
            print("    " + "; ".join(f"{v}: {r[v + '_models']}" for v in args.variants))
    means = " ".join(f"{np.mean([r[v] for r in rows]):>11.3f}" for v in args.variants)
    print(f"{'mean':<18} {sum(r['frames'] for r in rows):>6} {means}")
    print(f"{'median':<18} {'':>6} " + " ".join(f"{np.median([r[v] for r in rows]):>11.3f}" for v in args.variants))
    return 0


if __name__ == "__main__":
    sys.exit(main())
