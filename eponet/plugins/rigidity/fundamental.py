"""Rigidity stage ``fundamental``: one fundamental matrix per pair of frames (the pairwise baseline)."""

from __future__ import annotations

import numpy as np

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.geometry.rigidity import GRIC_PARAMS, GROUP_PARAMS, ROBUST_PARAMS, STATIC_PARAMS, RigidityStage
from eponet.geometry.fits import FittedModel
from eponet.geometry.triplets import estimate_pair

__all__ = ["FundamentalRigidity", "eponet_stages"]


class FundamentalRigidity(RigidityStage):
    """Per pair (t, t+k), a fundamental matrix by OpenCV USAC with MAGSAC++ scoring (seeded from ``rng``,
    inlier threshold ``f_threshold`` pixels); a point scores ``d(x2, F x1) + d(x1, F^T x2)`` in pixels,
    averaged over the trajectory's pairs. With ``degeneracy="gric"`` a homography competes through GRIC as
    in the ``trifocal`` stage. Static pairs use the identity homography. For the ablation "trifocal vs
    pairwise"; ``f_threshold`` is MAGSAC's and independent of ``threshold`` (used by the homography fit).
    """

    views = 2

    def __init__(
        self,
        *,
        degeneracy: str = "none",
        f_threshold: float = 1.0,
        max_points: int = 10000,
        stride: int = 1,
        sampling: str = "guided",
        border_prior: float = 0.15,
        prior_groups: float = 0.0,
        static_threshold: float = 0.25,
        confidence: float = 0.99,
        max_trials: int = 1000,
        threshold: float | None = None,
        min_sigma: float = 0.5,
    ):
        if degeneracy not in ("gric", "none"):
            raise ValueError(f"degeneracy must be 'gric' or 'none', got {degeneracy!r}")
        super().__init__(
            max_points=max_points, stride=stride, sampling=sampling, border_prior=border_prior,
            prior_groups=prior_groups,
            static_threshold=static_threshold,
            confidence=confidence,
            max_trials=max_trials, threshold=threshold, min_sigma=min_sigma,
        )
        self.degeneracy = degeneracy
        self.f_threshold = float(f_threshold)

    def estimate(self, points: list[np.ndarray], rng: np.random.Generator, frame_size=None) -> FittedModel:
        return estimate_pair(*points, rng, degeneracy=self.degeneracy, static_threshold=self.static_threshold,
                             threshold=self.f_threshold, settings=self.settings)


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="rigidity",
            name="fundamental",
            factory=FundamentalRigidity,
            params=(
                Param(
                    "degeneracy",
                    "choice",
                    "none",
                    "'none': always the fundamental matrix (the pairwise baseline); 'gric': choose between F and a "
                    "homography per pair by GRIC",
                    choices=("gric", "none"),
                ),
                Param(
                    "f_threshold", "float", 1.0, "MAGSAC++ inlier threshold in pixels for F", minimum=0.0,
                    exclusive_min=True,
                ),
            )
            + GROUP_PARAMS
            + STATIC_PARAMS
            + GRIC_PARAMS
            + ROBUST_PARAMS,
            doc="Pairwise baseline: one fundamental matrix per pair of frames (USAC MAGSAC++)",
        )
    ]
