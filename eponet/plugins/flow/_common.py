"""Helpers shared by the flow plugins."""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

from eponet.core.progress import track
from eponet.core.types import FlowPair, Video

__all__ = ["pairwise_flow"]


def pairwise_flow(video: Video, calc: Callable[[np.ndarray, np.ndarray], np.ndarray], desc: str,
                  calc_backward: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> FlowPair:
    """Run a two-frame grey-level flow method ``calc(a, b) -> (H, W, 2)`` (flow a -> b on a's grid) in both
    directions over consecutive frames (``calc_backward``, when given, for the backward direction)."""
    calc_backward = calc_backward or calc
    grey = [cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY) for frame in video.frames]
    count, (height, width) = len(grey) - 1, video.shape
    forward = np.empty((count, height, width, 2), np.float32)
    backward = np.empty_like(forward)
    for t in track(range(count), desc=desc, total=count):
        forward[t] = calc(grey[t], grey[t + 1])
        backward[t] = calc_backward(grey[t + 1], grey[t])
    return FlowPair(forward, backward)
