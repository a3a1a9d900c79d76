"""Rigidity stage ``homography``: residuals to the dominant homographies of each triplet (a baseline)."""

from __future__ import annotations

import numpy as np

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.geometry.rigidity import GROUP_PARAMS, ROBUST_PARAMS, RigidityStage
from eponet.geometry.fits import FittedModel
from eponet.geometry.triplets import estimate_triplet

__all__ = ["HomographyRigidity", "eponet_stages"]


class HomographyRigidity(RigidityStage):
    """Per triplet (t, t+k, t+2k), two robust homographies ``H21, H31`` (4-point RANSAC, DLT refit); a point
    scores the sum of its six transfer distances in pixels, averaged over the trajectory's triplets.

    Exact for a rotating camera or a planar scene; with parallax the background itself scores high. The
    static-camera test is not applied (a static camera is the identity homography).
    """

    views = 3

    def __init__(
        self,
        *,
        max_points: int = 10000,
        stride: int = 1,
        sampling: str = "guided",
        border_prior: float = 0.15,
        prior_groups: float = 0.0,
        confidence: float = 0.99,
        max_trials: int = 1000,
        threshold: float | None = None,
    ):
        super().__init__(
            max_points=max_points, stride=stride, sampling=sampling, border_prior=border_prior,
            prior_groups=prior_groups,
            static_threshold=0.0, confidence=confidence,
            max_trials=max_trials, threshold=threshold,
        )

    def estimate(self, points: list[np.ndarray], rng: np.random.Generator, frame_size=None) -> FittedModel:
        return estimate_triplet(*points, rng, degeneracy="none", static_threshold=self.static_threshold,
                                models=("homography",), settings=self.settings)


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="rigidity",
            name="homography",
            factory=HomographyRigidity,
            params=GROUP_PARAMS + ROBUST_PARAMS,
            doc="Baseline: transfer residuals to the dominant homographies of each triplet",
        )
    ]
