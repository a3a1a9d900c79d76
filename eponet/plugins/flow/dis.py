"""Flow stage ``dis``: OpenCV's Dense Inverse Search optical flow (Kroeger et al., ECCV 2016)."""

from __future__ import annotations

import cv2
import numpy as np

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
    """Forward and backward DIS flow on grey frames."""

    def __init__(self, *, preset: str = "medium"):
        self.preset = preset

    def estimate(self, video):
        dis = cv2.DISOpticalFlow_create(PRESETS[self.preset])
        return pairwise_flow(video, lambda a, b: dis.calc(a, b, None), desc="flow (dis)")


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="flow",
            name="dis",
            factory=DisFlow,
            params=(Param("preset", "choice", "medium", "OpenCV DIS preset (speed/accuracy)", choices=tuple(PRESETS)),),
            doc="OpenCV DIS optical flow (default; ~26 ms per 854x480 pair at preset medium)",
        )
    ]
