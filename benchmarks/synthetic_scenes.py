"""The rigidity stage on the synthetic scenes with exact ground truth that the tests use (``tests/geometry/scenes.py``,
240x180, DIS flow): mean per-frame ED ROC AUC against the moving object's mask, per scene and setting, for several
RANSAC seeds (the stage's ``rng``), since a rule that holds for one seed only is luck. Usage::

    python benchmarks/synthetic_scenes.py [--seeds 6] [--robust epipolar_msac=false]

Settings (columns): ``gric`` (GRIC alone, no border prior: eponet's default before the plane + parallax test),
``paper`` (``degeneracy: none``, uniform sampling, no border prior), ``default`` (the trifocal stage's defaults).
``--robust key=value`` replaces fields of every column's ``RobustSettings`` (e.g. the previous LMedS scoring).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

COLUMNS = {
    "gric": {"degeneracy": "gric", "border_prior": 0.0},
    "paper": {"degeneracy": "none", "sampling": "uniform", "border_prior": 0.0},
    "default": {},
}


def main(argv=None) -> int:
    from eponet.core.types import FlowPair
    from eponet.plugins.rigidity.trifocal import TrifocalRigidity
    from eponet.plugins.trajectories.dense import DenseTrajectories
    from tests.geometry import scenes

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=6, help="RANSAC seeds 0..N-1 per scene and setting")
    parser.add_argument("--robust", nargs="*", default=[], help="key=value fields of RobustSettings")
    args = parser.parse_args(argv)
    robust = {k: yaml.safe_load(v) for k, v in (item.split("=", 1) for item in args.robust)}
    print(f"mean per-frame ED ROC AUC, seed 0 (min / mean over seeds 0-{args.seeds - 1})")
    print(f"{'scene':<26}" + "".join(f"{name:>26}" for name in COLUMNS))
    for make in (scenes.parallax_scene, scenes.large_object_scene, scenes.static_distractor_scene,
                 scenes.rotation_scene):
        video = make()
        flow = FlowPair(*scenes.dis_flow(video.frames))
        tracks = DenseTrajectories().build(flow)
        cells = []
        for settings in COLUMNS.values():
            stage = TrifocalRigidity(**settings)
            stage.settings = dataclasses.replace(stage.settings, **robust)
            aucs = []
            for seed in range(args.seeds):
                ed = stage.score(tracks, flow, np.random.default_rng(seed)).ed
                aucs.append(np.nanmean([scenes.roc_auc(ed[t], video.masks[t]) for t in range(len(ed))]))
            cells.append(f"{aucs[0]:.3f} ({min(aucs):.3f} / {np.mean(aucs):.3f})")
        print(f"{make.__name__:<26}" + "".join(f"{c:>26}" for c in cells), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
