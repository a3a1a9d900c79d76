"""Appearance stage ``none``: no appearance features, for a motion-only fusion (the ablation without appearance)."""

from __future__ import annotations

import math

import numpy as np

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.core.types import Video

__all__ = ["NoAppearance"]


class NoAppearance:
    """Zero-channel features: float32 ``(F, 0, ceil(H/stride), ceil(W/stride))`` for frames ``(F, H, W, 3)``.

    The array holds no values; its shape gives the fusion stage the grid to run on. The ``convgru`` fusion
    trained on it has no bottleneck and reads the motion map alone (resized to that grid).
    """

    def __init__(self, *, stride: int = 8):
        self.stride = stride

    def features(self, video: Video) -> np.ndarray:
        height, width = video.shape
        return np.zeros((video.num_frames, 0, math.ceil(height / self.stride), math.ceil(width / self.stride)),
                        np.float32)


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="appearance",
            name="none",
            factory=NoAppearance,
            params=(Param("stride", "int", 8, "grid of the (empty) features: frame size / stride, rounded up",
                          minimum=1),),
            doc="no appearance features (zero channels on a stride-8 grid): motion-only fusion",
        )
    ]
