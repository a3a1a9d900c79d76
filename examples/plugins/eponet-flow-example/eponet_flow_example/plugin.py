"""A flow stage ``dis_fine``: OpenCV DIS run down to the finest pyramid level with more variational
refinement. Slower than the built-in ``dis`` but sharper at motion boundaries.

This is the whole of a third-party plugin: a class with the stage kind's method (``estimate`` for flow) and a
``hookimpl`` returning a ``StageSpec``; ``pyproject.toml`` exposes this module in the ``eponet.plugins``
entry-point group.
"""

import cv2
import numpy as np

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.core.types import FlowPair


class DisFineFlow:
    def __init__(self, *, patch_size: int = 8, refinement_iterations: int = 10):
        self.patch_size = patch_size
        self.refinement_iterations = refinement_iterations

    def _dis(self):
        dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        dis.setFinestScale(0)
        dis.setPatchSize(self.patch_size)
        dis.setPatchStride(max(1, self.patch_size // 2))
        dis.setVariationalRefinementIterations(self.refinement_iterations)
        return dis

    def estimate(self, video) -> FlowPair:
        dis = self._dis()
        grey = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in video.frames]
        forward = np.stack([dis.calc(a, b, None) for a, b in zip(grey[:-1], grey[1:])])
        backward = np.stack([dis.calc(b, a, None) for a, b in zip(grey[:-1], grey[1:])])
        return FlowPair(forward.astype(np.float32), backward.astype(np.float32))


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="flow",
            name="dis_fine",
            factory=DisFineFlow,
            params=(
                Param("patch_size", "int", 8, "DIS patch size in pixels", minimum=4, maximum=32),
                Param("refinement_iterations", "int", 10, "variational refinement iterations", minimum=0, maximum=100),
            ),
            doc="DIS flow at the finest scale (example third-party plugin)",
        )
    ]
