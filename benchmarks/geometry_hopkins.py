"""Rigidity on real point tracks: Hopkins155 background/foreground classification by ED.

For every sequence the largest motion group is taken as the background. The tracks (complete over all F
frames) become trajectories, a rigidity stage scores every frame group, and a point is classified as
moving when its log ED is above the Otsu threshold of the sequence's log ED values (a two-class split
with no tuning and no labels). Prints the per-sequence and mean misclassification rate, and the rate at
the best possible threshold ("oracle", an upper bound of what any single threshold achieves). Usage::

    python benchmarks/geometry_hopkins.py [--variant default] [--stride 4] [--every 1]
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("EPONET_SHARED_DATA") or REPO.parent / "shared" / "data")
HOPKINS = DATA / "hopkins155" / "Hopkins155"


def load_tracks(path: Path):
    """(Trajectories, labels) of one ``*_truth.mat``: P complete tracks over F frames, pixel coordinates."""
    import scipy.io

    from eponet.core.types import Trajectories

    mat = scipy.io.loadmat(str(path))
    y = mat["y"]  # 3 x P x F homogeneous pixels
    labels = mat["s"].ravel().astype(int)
    p, f = y.shape[1], y.shape[2]
    xy = (y[:2] / y[2:]).transpose(1, 2, 0).reshape(-1, 2).astype(np.float32)  # track-major
    traj = Trajectories(
        start=np.zeros(p, np.int32), length=np.full(p, f, np.int32), offsets=np.arange(p + 1, dtype=np.int64) * f,
        positions=xy, labels=np.zeros((f, 1, 1), np.int32),  # no pixel grid: only per-trajectory values are used
    )
    return traj, labels


def otsu_threshold(values: np.ndarray) -> float:
    """Threshold maximising the between-class variance of a 1-D sample (Otsu 1979), exact over all splits."""
    v = np.sort(np.asarray(values, np.float64))
    n = len(v)
    c = np.cumsum(v)
    i = np.arange(1, n)
    m0 = c[:-1] / i
    m1 = (c[-1] - c[:-1]) / (n - i)
    between = (i / n) * (1 - i / n) * (m0 - m1) ** 2
    k = int(np.argmax(between))
    return float((v[k] + v[k + 1]) / 2)


def make_stage(variant: str, stride: int):
    from eponet.plugins.rigidity.fundamental import FundamentalRigidity
    from eponet.plugins.rigidity.homography import HomographyRigidity
    from eponet.plugins.rigidity.trifocal import TrifocalRigidity

    return {
        "default": lambda: TrifocalRigidity(stride=stride),
        "none": lambda: TrifocalRigidity(degeneracy="none", stride=stride),
        "fundamental": lambda: FundamentalRigidity(stride=stride),
        "homography": lambda: HomographyRigidity(stride=stride),
    }[variant]()


def classify_sequence(path: Path, variant: str = "default", stride: int = 4, seed: int = 0) -> dict:
    """Per-trajectory ED of one sequence and its misclassification rates (Otsu and oracle thresholds)."""
    from eponet.geometry import frame_groups, score_frame_groups

    traj, labels = load_tracks(path)
    background = labels == np.bincount(labels).argmax()
    stage = make_stage(variant, stride)
    groups = frame_groups(traj.num_frames, stage.views, stage.stride)
    sums, counts, infos = score_frame_groups(traj, groups, stage.estimate, np.random.default_rng(seed),
                                             max_points=stage.max_points)
    ed = sums / np.maximum(counts, 1)
    log_ed = np.log(ed + 1e-3)
    moving = log_ed > otsu_threshold(log_ed)
    error = float(np.mean(moving == background))
    cuts = np.r_[-np.inf, np.sort(log_ed)]
    oracle = float(min(np.mean((log_ed > c) == background) for c in cuts))
    models = [i["model"] for i in infos]
    return {"name": path.parent.name, "points": len(labels), "frames": traj.num_frames, "groups": len(groups),
            "error": error, "oracle": oracle, "models": {m: models.count(m) for m in sorted(set(models))}}


def sequences(every: int = 1) -> list[Path]:
    return sorted(HOPKINS.glob("*/*_truth.mat"))[::every]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variant", default="default", choices=["default", "none", "fundamental", "homography"])
    parser.add_argument("--stride", type=int, default=4)
    parser.add_argument("--every", type=int, default=1, help="only every N-th sequence (alphabetical)")
    args = parser.parse_args(argv)
    if not HOPKINS.is_dir():
        print(f"Hopkins155 not found under {HOPKINS} (set EPONET_SHARED_DATA)")
        return 1
    logging.basicConfig(level=logging.ERROR)
    rows = []
    t0 = time.perf_counter()
    print(f"Hopkins155, rigidity '{args.variant}', stride {args.stride}: "
          "misclassification (largest group = background)")
    print(f"{'sequence':<22} {'points':>6} {'frames':>6} {'error':>7} {'oracle':>7}  models")
    for path in sequences(args.every):
        r = classify_sequence(path, args.variant, args.stride)
        rows.append(r)
        print(f"{r['name']:<22} {r['points']:>6} {r['frames']:>6} {r['error']:>7.3f} {r['oracle']:>7.3f}  "
              f"{r['models']}", flush=True)
    errors = np.array([r["error"] for r in rows])
    oracles = np.array([r["oracle"] for r in rows])
    print(f"{len(rows)} sequences: mean error {errors.mean():.3f} (median {np.median(errors):.3f}; oracle threshold "
          f"{oracles.mean():.3f}); {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
