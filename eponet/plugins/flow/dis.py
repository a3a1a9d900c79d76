"""Flow stage ``dis``: OpenCV's Dense Inverse Search optical flow (Kroeger et al., ECCV 2016)."""

from __future__ import annotations

import cv2

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.plugins.flow._common import pairwise_flow

__all__ = ["DisFlow", "PRESETS"]

PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


class DisFlow:
    """Forward and backward DIS flow on grey frames.

    ``finest_scale`` overrides the preset's finest pyramid level (0: the frame itself; OpenCV's ``medium``
    stops at 1, half the frame size, and ``fast``/``ultrafast`` at 2), e.g. 0 for sharper object boundaries
    at about three times the cost. ``patch_stride`` (px between the patches searched; ``medium``: 3) and
    ``refinement_iterations`` (fixed-point iterations of the variational refinement at every level;
    ``medium``: 5) override the preset's: the patch search's cost falls with the square of the stride.
    ``backward_finest_scale`` sets the backward flow's finest level apart (default: ``finest_scale``); the
    backward flow only tests where trajectories end (and moves the last frame), so it may be coarser."""

    def __init__(self, *, preset: str = "medium", finest_scale: int | None = None, patch_stride: int | None = None,
                 refinement_iterations: int | None = None, backward_finest_scale: int | None = None):
        self.preset = preset
        self.finest_scale = finest_scale
        self.patch_stride = patch_stride
        self.refinement_iterations = refinement_iterations
        self.backward_finest_scale = backward_finest_scale

    def create(self, finest_scale: int | None = None) -> cv2.DISOpticalFlow:
        """A configured OpenCV DIS object (one per thread: it keeps buffers between calls), at ``finest_scale``
        when given instead of the stage's."""
        dis = cv2.DISOpticalFlow_create(PRESETS[self.preset])
        finest_scale = self.finest_scale if finest_scale is None else finest_scale
        if finest_scale is not None:
            dis.setFinestScale(finest_scale)
        if self.patch_stride is not None:
            dis.setPatchStride(self.patch_stride)
        if self.refinement_iterations is not None:
            dis.setVariationalRefinementIterations(self.refinement_iterations)
        return dis

    def calculators(self):
        """``(forward, backward)``: two-frame functions ``calc(a, b) -> (H, W, 2)`` on grey frames, the second at
        ``backward_finest_scale`` when it is set (each a configured DIS object of its own then)."""
        dis = self.create()
        back = dis if self.backward_finest_scale is None else self.create(self.backward_finest_scale)
        return (lambda a, b: dis.calc(a, b, None)), (lambda a, b: back.calc(a, b, None))

    def estimate(self, video):
        forward, backward = self.calculators()
        return pairwise_flow(video, forward, desc="flow (dis)", calc_backward=backward)


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="flow",
            name="dis",
            factory=DisFlow,
            params=(
                Param("preset", "choice", "medium", "OpenCV DIS preset (speed/accuracy)", choices=tuple(PRESETS)),
                Param("finest_scale", "int", None, "finest pyramid level, 0 = full frame size (default: the preset's)",
                      minimum=0, maximum=6, nullable=True),
                Param("patch_stride", "int", None, "pixels between searched patches (default: the preset's, 3 for "
                      "medium; at most the presets' patch size, 8)", minimum=1, maximum=8, nullable=True),
                Param("refinement_iterations", "int", None, "fixed-point iterations of the variational refinement "
                      "per level (default: the preset's, 5 for medium; 0: none)", minimum=0, maximum=100,
                      nullable=True),
                Param("backward_finest_scale", "int", None, "finest pyramid level of the backward flow (default: "
                      "finest_scale's)", minimum=0, maximum=6, nullable=True),
            ),
            doc="OpenCV DIS optical flow (default; preset medium forward+backward is R, the benchmarks' speed unit)",
        )
    ]
