"""Temporal averaging of a foreground probability along the optical flow, before the refiner.

A motion network decides frame by frame, so a frame where the object stops, blurs or is partly hidden loses it
while its neighbours keep it. :func:`temporal_mean` averages frame ``t``'s probability with those of ``t - 1``
and ``t + 1`` warped into frame ``t`` along the flow the pipeline already has; where the flow fails its
forward-backward test (occlusion, flow errors; Sundaram, Brox & Keutzer, ECCV 2010), frame ``t``'s own value
stands in for the neighbour's.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from .imaging import fb_consistent

__all__ = ["warp_into", "temporal_mean"]


@lru_cache(maxsize=4)
def _grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates x, y float32 ``(h, w)`` of a frame of ``shape`` (read-only: shared between calls)."""
    h, w = shape
    grid = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    for axis in grid:
        axis.flags.writeable = False
    return grid[0], grid[1]


def warp_into(probability: np.ndarray, there: np.ndarray, back: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Another frame's probability seen from frame ``t``.

    Parameters
    ----------
    probability : float32 (h, w)
        The other frame's foreground probability.
    there : float32 (h, w, 2)
        Flow in pixels from frame ``t`` to the other frame, on frame ``t``'s grid.
    back : float32 (h, w, 2)
        Flow in pixels from the other frame to frame ``t``, on the other frame's grid.

    Returns
    -------
    warped : float32 (h, w)
        ``probability`` sampled at ``x + there(x)``.
    consistent : bool (h, w)
        Where ``there`` passes the forward-backward test against ``back``.

    >>> p = np.zeros((4, 6), np.float32); p[:, 3] = 1.0
    >>> shift = np.zeros((4, 6, 2), np.float32); shift[..., 0] = 1.0   # everything moves 1 px right
    >>> warped, ok = warp_into(p, shift, -shift)
    >>> warped[0].tolist(), bool(ok.all())
    ([0.0, 0.0, 1.0, 0.0, 0.0, 0.0], True)
    """
    there = np.asarray(there, np.float32)
    gx, gy = _grid(there.shape[:2])
    mx, my = gx + there[..., 0], gy + there[..., 1]  # where each pixel of t lies in the other frame
    def sample(values):  # bilinear at (mx, my); outside the frame the nearest edge value
        return cv2.remap(np.ascontiguousarray(values, np.float32), mx, my, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)
    warped, returned = sample(probability), sample(back)
    return warped, fb_consistent(there[..., 0], there[..., 1], returned[..., 0], returned[..., 1])


def temporal_mean(probability: np.ndarray, before: tuple | None, after: tuple | None) -> np.ndarray:
    """Frame ``t``'s probability averaged with its neighbours' warped into it, float32 ``(h, w)``.

    ``before`` and ``after`` are ``(probability, there, back)`` of frame ``t - 1`` and ``t + 1`` as
    :func:`warp_into` takes them, or ``None`` (the first and last frames: the mean of the frames there are). Each
    neighbour's pixel that fails the forward-backward test counts with frame ``t``'s own value, so the mean is
    ``(p_t + p'_{t-1} + p'_{t+1}) / 3`` with equal weights.

    >>> p = np.full((3, 3), 0.9, np.float32)
    >>> still = np.zeros((3, 3, 2), np.float32)
    >>> round(float(temporal_mean(p, (np.zeros_like(p), still, still), None)[1, 1]), 3)  # (0.9 + 0) / 2
    0.45
    """
    probability = np.asarray(probability, np.float32)
    total, count = probability.copy(), 1
    for neighbour in (before, after):
        if neighbour is None:
            continue
        warped, consistent = warp_into(*neighbour)
        total += np.where(consistent, warped, probability)
        count += 1
    return total / count
