"""Trajectory stage ``dense``: every pixel of every frame on a trajectory, with a forward-backward occlusion test."""

from __future__ import annotations

import numpy as np

from eponet.core.errors import InputError
from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.core.types import MIN_FRAMES, FlowPair, Trajectories
from eponet.geometry.trajectories import MAX_LIVE, DenseTrajectoryStream, build_dense_trajectories

__all__ = ["DenseTrajectories", "eponet_stages"]


class DenseTrajectories:
    """Dense point trajectories (see :func:`eponet.geometry.build_dense_trajectories`).

    Parameters
    ----------
    consistency : {"tolerance", "exact"}
        Occlusion test: ``|f(p) + b(p + f(p))|^2 < 0.01 (|f|^2 + |b|^2) + 0.5`` at the sub-pixel position
        (Sundaram et al. 2010), or the original code's exact rounded round trip.
    cull_collisions : bool
        End all but the oldest of the trajectories that land on one pixel.
    max_live : float or None
        Without culling, the most trajectories alive at once in multiples of the pixel count (the youngest of
        those that cover no pixel end first); ``None``: unbounded, as the original.
    """

    def __init__(self, *, consistency: str = "tolerance", cull_collisions: bool = False,
                 max_live: float | None = MAX_LIVE):
        if consistency not in ("tolerance", "exact"):
            raise ValueError(f"consistency must be 'tolerance' or 'exact', got {consistency!r}")
        self.consistency = consistency
        self.cull_collisions = bool(cull_collisions)
        self.max_live = max_live

    def build(self, flow: FlowPair) -> Trajectories:
        """Trajectories of a video from its forward/backward flow ``(F-1, H, W, 2)``.

        Raises :class:`~eponet.core.errors.InputError` for flow that is not ``(N, H, W, 2)`` with matching
        forward and backward shapes or covers fewer than 3 frames. Non-finite flow vectors are treated as
        occlusions (with a warning).
        """
        forward, backward = np.asarray(flow.forward), np.asarray(flow.backward)
        if forward.ndim != 4 or forward.shape[-1] != 2 or backward.shape != forward.shape:
            raise InputError(
                "flow must be (F-1, H, W, 2) forward and backward of equal shapes, got "
                f"{forward.shape} and {backward.shape}"
            )
        if forward.shape[0] + 1 < MIN_FRAMES:
            raise InputError(f"trajectories need at least {MIN_FRAMES} frames, got {forward.shape[0] + 1}")
        if forward.shape[1] < 1 or forward.shape[2] < 1:
            raise InputError(f"flow has an empty frame size {forward.shape[2]}x{forward.shape[1]}")
        return build_dense_trajectories(
            forward.astype(np.float32, copy=False),
            backward.astype(np.float32, copy=False),
            consistency=self.consistency,
            cull_collisions=self.cull_collisions,
            max_live=self.max_live,
        )

    def stream(self, shape: tuple[int, int]) -> DenseTrajectoryStream:
        """The builder's live state for a stream of flow pairs on frames of ``shape`` ``(H, W)``: the same
        trajectories as :meth:`build`, one frame at a time (:class:`~eponet.core.protocols.TrajectoryStream`)."""
        if shape[0] < 1 or shape[1] < 1:
            raise InputError(f"flow has an empty frame size {shape[1]}x{shape[0]}")
        return DenseTrajectoryStream(shape, consistency=self.consistency, cull_collisions=self.cull_collisions,
                                     max_live=self.max_live)


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="trajectories",
            name="dense",
            factory=DenseTrajectories,
            params=(
                Param(
                    "consistency",
                    "choice",
                    "tolerance",
                    "occlusion test: 'tolerance' (|f+b|^2 < 0.01(|f|^2+|b|^2)+0.5, Sundaram et al.) or 'exact' "
                    "(the original code's rounded round trip)",
                    choices=("tolerance", "exact"),
                ),
                Param(
                    "cull_collisions",
                    "bool",
                    False,
                    "end all but the oldest of the trajectories that land on one pixel (bounds their number)",
                ),
                Param(
                    "max_live",
                    "float",
                    MAX_LIVE,
                    "without culling, the most trajectories alive at once, in multiples of the frame's pixels: "
                    "beyond it the youngest of those an older one hides end (their number grows with the video: "
                    "2.2x the pixels after 80 DAVIS frames, 4x after 1200 of a camera panning to and fro); "
                    "null: unbounded (the original)",
                    minimum=1.0,
                    nullable=True,
                ),
            ),
            doc="Dense trajectories: every pixel of every frame, bilinear advection, forward-backward occlusion test",
        )
    ]
