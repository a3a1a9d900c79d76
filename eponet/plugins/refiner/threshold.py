"""Refiner ``threshold``: foreground where the probability reaches a threshold."""

from __future__ import annotations

import numpy as np

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param

__all__ = ["ThresholdRefiner"]


class ThresholdRefiner:
    """``mask = probability >= threshold``."""

    def __init__(self, *, threshold: float = 0.5):
        self.threshold = threshold

    def refine(self, frames: np.ndarray, probability: np.ndarray) -> np.ndarray:
        return (probability >= self.threshold).astype(np.uint8)


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="refiner",
            name="threshold",
            factory=ThresholdRefiner,
            params=(Param("threshold", "float", 0.5, "foreground where probability >= threshold", minimum=0.0, maximum=1.0),),
            doc="plain threshold of the foreground probability",
        )
    ]
