"""Motion support of a fused foreground map: appearance may shape an object, not add one that does not move.

EpO+'s fusion (and its self-training) reads appearance features, and appearance alone cannot tell the moving
flamingo from the standing one beside it: both look alike, and the fused map often takes both. The motion map
can: only one of them has motion saliency. :func:`motion_supported` keeps each connected foreground region of the
fused map that holds at least one pixel of clear motion saliency, and lowers the others to the motion map's
value (so where the motion map saw nothing, nothing is left). A frame in which no region has support keeps its
fused map as it is: the fusion's memory carries an object through frames where it stops or blurs, and those are
the frames the motion map misses.

:func:`motion_filled` is the converse for the inside of an object: on a fine appearance grid the fusion can lose
the middle of a large object of even texture (a bear's flank) while the motion map holds it. Inside the convex
hull of each fused region with motion support, it gives back the motion map's foreground; what lies outside
every such hull (spray, ripples, a screen far from the object) stays as the fusion left it.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

__all__ = ["motion_supported", "motion_filled"]


def _regions(probability: np.ndarray, motion: np.ndarray, support: float, level: float):
    """For each frame ``t`` with a region: ``(t, labels, supported)``, ``labels`` int ``(H, W)`` the 8-connected
    components of ``probability[t] > level`` (0 below it) and ``supported`` bool ``(count + 1,)`` whether region
    ``k`` holds a pixel with ``motion >= support`` (``supported[0]`` False). Each frame is labelled as it is when
    the caller takes it, so a caller may change the frames before."""
    if probability.shape != motion.shape or probability.ndim != 3:
        raise ValueError(f"probability and motion must both be (F, H, W), got {probability.shape} and {motion.shape}")
    structure = np.ones((3, 3), bool)
    for t in range(len(probability)):
        labels, count = ndimage.label(probability[t] > level, structure=structure)
        if count:
            supported = np.zeros(count + 1, bool)
            supported[labels[motion[t] >= support]] = True  # the regions with a pixel of clear motion
            supported[0] = False
            yield t, labels, supported


def motion_supported(probability: np.ndarray, motion: np.ndarray, support: float, level: float = 0.5) -> np.ndarray:
    """The fused ``probability`` with the regions that lack motion support lowered to the ``motion`` map.

    Parameters
    ----------
    probability : float array (F, H, W)
        The fused foreground probability, in [0, 1].
    motion : float array (F, H, W)
        The motion net's foreground probability on the same grid.
    support : float
        A region is supported when its largest motion probability reaches this.
    level : float
        Regions are the 8-connected components of ``probability > level``.

    Returns
    -------
    float32 array (F, H, W): a new array; pixels outside unsupported regions, and every pixel of a frame without
    any supported region, keep their probability; inside an unsupported region the pixel takes
    ``min(probability, motion)``.

    >>> p = np.zeros((1, 4, 8), np.float32); p[0, 1:3, 1:3] = 0.9; p[0, 1:3, 5:7] = 0.8
    >>> m = np.zeros_like(p); m[0, 1, 1] = 0.7; m[0, 1, 5] = 0.2
    >>> out = motion_supported(p, m, support=0.5)
    >>> out[0, 1:3, 1:3].astype(float).round(2).tolist(), out[0, 1:3, 5:7].astype(float).round(2).tolist()
    ([[0.9, 0.9], [0.9, 0.9]], [[0.2, 0.0], [0.0, 0.0]])
    >>> bool((motion_supported(p, np.zeros_like(p), support=0.5) == p).all())  # no region supported: unchanged
    True
    """
    out = np.array(probability, np.float32, copy=True)
    for t, labels, supported in _regions(out, motion, support, level):
        if not supported.any():
            continue
        lowered = (labels > 0) & ~supported[labels]
        out[t][lowered] = np.minimum(out[t][lowered], motion[t][lowered])
    return out


def motion_filled(probability: np.ndarray, motion: np.ndarray, support: float, fill: float, share: float = 0.0,
                  level: float = 0.5) -> np.ndarray:
    """The fused ``probability`` with the ``motion`` map's foreground restored inside each supported object.

    Parameters
    ----------
    probability, motion, support, level
        As :func:`motion_supported`: a supported region is an object.
    fill : float
        Inside an object's convex hull, a pixel whose motion probability reaches this is given back ...
    share : float
        ... when there are at least this many such pixels at or below ``level`` per pixel of the region (a lost
        part of the object, not the motion map's blur along its outline).

    Returns
    -------
    float32 array (F, H, W): a new array; inside the convex hull of each supported region that lost enough, a
    pixel with ``motion >= fill`` takes ``max(probability, motion)``; every other pixel keeps its probability.

    >>> p = np.zeros((1, 7, 12), np.float32); p[0, 1:6, 1:6] = 0.9; p[0, 2:6, 2:5] = 0.1  # a C open at the bottom
    >>> m = np.zeros_like(p); m[0, 1:6, 1:6] = 0.8; m[0, 1:6, 8:11] = 0.8  # the whole square, and motion elsewhere
    >>> out = motion_filled(p, m, support=0.5, fill=0.5)
    >>> out[0, 2:6, 2:5].min().item(), out[0, 1:6, 8:11].max().item()  # filled; the far motion stays out
    (0.800000011920929, 0.0)
    """
    out = np.array(probability, np.float32, copy=True)
    for t, labels, supported in _regions(out, motion, support, level):
        boxes = ndimage.find_objects(labels)
        for region in np.flatnonzero(supported):
            box = boxes[region - 1]
            inside, fused, moving = labels[box] == region, out[t][box], motion[t][box]  # views of the region's box
            hull = np.zeros(inside.shape, np.uint8)
            cv2.fillConvexPoly(hull, cv2.convexHull(cv2.findNonZero(inside.astype(np.uint8))), 1)
            lost = (hull > 0) & (moving >= fill) & ~(fused > level)
            if lost.sum() >= share * inside.sum():
                fused[lost] = np.maximum(fused[lost], moving[lost])
    return out
