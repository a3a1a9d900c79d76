"""Fusion stage ``selftrain``: a per-window appearance classifier self-trained on the motion map's confident
pixels and mixed with it (:mod:`eponet.fusion.selftrain`). No weights: it learns from the video itself."""

from __future__ import annotations

import numpy as np

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.plugins.fusion import example_params, threshold_problems, window_problems

__all__ = ["SelfTrainStage"]


class SelfTrainStage:
    """Self-training per overlapping window of ``window`` frames (the run engine streams the windows and
    stitches them, each frame from the window where it is most central); ``window: null`` fits one classifier
    over the whole video."""

    def __init__(self, *, window: int | None = 64, overlap: int = 16, foreground: float = 0.9,
                 background: float = 0.05, weight: float = 0.5, l2: float = 1e-3, iterations: int = 60,
                 samples: int = 60000, seed: int = 0, foreground_share: float = 0.0, foreground_floor: float = 0.5):
        self.window, self.overlap = window, overlap
        self.settings = dict(foreground=foreground, background=background, weight=weight, l2=l2,
                             iterations=iterations, samples=samples, seed=seed, foreground_share=foreground_share,
                             foreground_floor=foreground_floor)

    def fuse(self, features: np.ndarray, saliency: np.ndarray) -> np.ndarray:
        """Foreground probability float32 ``(F, H, W)`` from features ``(F, C, h, w)`` and saliency ``(F, H, W)``."""
        from eponet.fusion.selftrain import self_trained_probability

        return self_trained_probability(features, saliency, **self.settings)


def _check(params: dict) -> list[str]:
    return window_problems(params) + threshold_problems(params)


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="fusion",
            name="selftrain",
            factory=SelfTrainStage,
            params=(
                Param("window", "int", 64, "frames per self-trained window (memory grows with it); null: one "
                      "classifier for the whole video", minimum=2, nullable=True),
                Param("overlap", "int", 16, "frames shared by consecutive windows", minimum=0),
                *example_params("", "saliency"),
                Param("weight", "float", 0.5, "share of the appearance probability in the output (0 = the "
                      "saliency unchanged, 1 = appearance only)", minimum=0.0, maximum=1.0),
                Param("iterations", "int", 60, "L-BFGS iterations", minimum=1),
                Param("seed", "int", 0, "seed of the training cells' draw", minimum=0),
            ),
            doc="per-video appearance classifier self-trained on the motion map's confident pixels (no weights)",
            check=_check,
        )
    ]
