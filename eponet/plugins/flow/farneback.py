"""Flow stage ``farneback``: OpenCV's polynomial-expansion optical flow (Farneback, SCIA 2003)."""

from __future__ import annotations

import cv2

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.plugins.flow._common import pairwise_flow

__all__ = ["FarnebackFlow"]


class FarnebackFlow:
    """Forward and backward Farneback flow on grey frames."""

    def __init__(self, *, pyr_scale: float = 0.5, levels: int = 5, winsize: int = 15, iterations: int = 3,
                 poly_n: int = 5, poly_sigma: float = 1.2):
        self.args = (pyr_scale, levels, winsize, iterations, poly_n, poly_sigma, 0)

    def estimate(self, video):
        return pairwise_flow(video, lambda a, b: cv2.calcOpticalFlowFarneback(a, b, None, *self.args), desc="flow (farneback)")


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="flow",
            name="farneback",
            factory=FarnebackFlow,
            params=(
                Param("pyr_scale", "float", 0.5, "image scale between pyramid levels", minimum=0.1, maximum=0.9),
                Param("levels", "int", 5, "number of pyramid levels", minimum=1, maximum=10),
                Param("winsize", "int", 15, "averaging window size in pixels", minimum=3, maximum=101),
                Param("iterations", "int", 3, "iterations per pyramid level", minimum=1, maximum=50),
                Param("poly_n", "choice", 5, "pixel neighbourhood of the polynomial expansion", choices=(5, 7)),
                Param("poly_sigma", "float", 1.2, "Gaussian sigma of the polynomial expansion", minimum=0.5, maximum=3.0),
            ),
            doc="OpenCV Farneback optical flow",
        )
    ]
