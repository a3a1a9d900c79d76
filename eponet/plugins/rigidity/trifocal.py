"""Rigidity stage ``trifocal`` (default): trifocal tensors of frame triplets, with degenerate-motion handling."""

from __future__ import annotations

import numpy as np

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.geometry.rigidity import GRIC_PARAMS, GROUP_PARAMS, ROBUST_PARAMS, STATIC_PARAMS, RigidityStage
from eponet.geometry.fits import FittedModel
from eponet.geometry.triplets import DEGENERACY, estimate_triplet

__all__ = ["TrifocalRigidity", "eponet_stages"]


class TrifocalRigidity(RigidityStage):
    """Epipolar distances from one trifocal tensor per triplet of frames (t, t+k, t+2k) (the paper's Sec. 3).

    Per triplet: the trajectories present in all three frames; a seeded sample of at most ``max_points``;
    the static-camera test (fixed skew-symmetric F's); else six-point RANSAC ([HZ] Alg. 20.1), a linear
    refit on the inliers and ``F21, F31, F32`` in pixels ([HZ] Alg. 15.1). With ``degeneracy="gric"`` two
    homographies are fitted too and GRIC chooses (a homography wins when the camera only rotates or the
    scene is far or planar: there the epipolar model would absorb moving objects); points then score their
    six transfer distances instead of the six epipolar distances. ``"parallax"`` (the default) overrules a
    homography choice when the rigid scene shows plane + parallax (see
    :func:`eponet.geometry.triplets.estimate_triplet`). ``"none"`` is the paper's behaviour.

    Output ``ed`` is the mean over a trajectory's triplets of the summed six distances, in pixels of the
    processing resolution, painted to every pixel the trajectory covers.
    """

    views = 3

    def __init__(
        self,
        *,
        degeneracy: str = "parallax",
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
        if degeneracy not in DEGENERACY:
            raise ValueError(f"degeneracy must be one of {', '.join(DEGENERACY)}, got {degeneracy!r}")
        super().__init__(
            max_points=max_points, stride=stride, sampling=sampling, border_prior=border_prior,
            prior_groups=prior_groups,
            static_threshold=static_threshold,
            confidence=confidence,
            max_trials=max_trials, threshold=threshold, min_sigma=min_sigma,
        )
        self.degeneracy = degeneracy

    def estimate(self, points: list[np.ndarray], rng: np.random.Generator, frame_size=None) -> FittedModel:
        models = ("trifocal",) if self.degeneracy == "none" else ("trifocal", "homography")
        return estimate_triplet(
            *points, rng, degeneracy=self.degeneracy, static_threshold=self.static_threshold, models=models,
            settings=self.settings, frame_size=frame_size,
        )


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="rigidity",
            name="trifocal",
            factory=TrifocalRigidity,
            params=(
                Param(
                    "degeneracy",
                    "choice",
                    "parallax",
                    "'gric': per triplet choose between the trifocal model and one or two homographies by Torr's "
                    "GRIC (handles camera rotation and distant/planar scenes); 'parallax' (default): GRIC, except "
                    "that a second plane the epipolar model explains as rigid, holding at least 10% of the points, "
                    "moving at least twice as far as the dominant plane and reaching the frame border (near rigid "
                    "structure: plane + parallax), keeps the trifocal model; 'none': always the trifocal model "
                    "(the paper)",
                    choices=DEGENERACY,
                ),
            )
            + GROUP_PARAMS
            + STATIC_PARAMS
            + GRIC_PARAMS
            + ROBUST_PARAMS,
            doc="Epipolar distances of dense trajectories from per-triplet trifocal tensors (six-point RANSAC), "
            "plane + parallax test and GRIC vs homographies",
        )
    ]
