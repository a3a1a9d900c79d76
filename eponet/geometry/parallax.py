"""Plane + parallax evidence of a frame triplet: is a second plane near rigid structure or a moving object?

Used by ``degeneracy="parallax"`` of :func:`eponet.geometry.triplets.estimate_triplet`, which documents the
rule and its priors. The second plane is the set of points the epipolar (trifocal) model explains as rigid
that the dominant homography does not; it is read as near rigid structure when it holds enough of the
points, moves clearly faster in the image than the dominant plane (parallax grows as depth shrinks) and
reaches the frame border.

References
----------
.. [IA98] M. Irani and P. Anandan, "A unified approach to moving object detection in 2D and 3D scenes", IEEE
   TPAMI 20(6), 1998.
"""

from __future__ import annotations

import numpy as np

from .robust import inlier_bound

__all__ = [
    "PARALLAX_MIN_FRACTION",
    "PARALLAX_MIN_BORDER_RATIO",
    "PARALLAX_MIN_SPEED_RATIO",
    "border_ratio",
    "rigid_second_plane",
    "is_parallax",
]

#: The smallest fraction of the points a rigid second plane must hold to count as near rigid structure.
PARALLAX_MIN_FRACTION = 0.1
#: Width of the border band, as a fraction of the frame's shorter side.
BORDER_BAND = 0.05
#: The :func:`border_ratio` the plane must reach.
PARALLAX_MIN_BORDER_RATIO = 0.5
#: The speed ratio (its image motion over the dominant plane's) it must reach.
PARALLAX_MIN_SPEED_RATIO = 2.0
#: Displacements below this (pixels) count as this.
SPEED_FLOOR_PX = 0.05
#: Fewest points of a plane whose border ratio and speed are measured.
MIN_PLANE_POINTS = 20


def border_ratio(x: np.ndarray, member: np.ndarray, frame_size: tuple[int, int], band: float = BORDER_BAND) -> float:
    """How much more often the ``member`` points (bool (N,)) lie near the frame border than all N points.

    A point is near the border when it is within ``band * min(height, width)`` pixels of an edge. The ratio is
    1 when the members are spread like the points, > 1 when they crowd the border, 0 when none is there.
    """
    h, w = frame_size
    b = band * min(h, w)
    near = (x[:, 0] < b) | (x[:, 0] > w - 1 - b) | (x[:, 1] < b) | (x[:, 1] > h - 1 - b)
    base = near.mean()
    if base == 0 or not member.any():
        return 0.0
    return float(near[member].mean() / base)


def rigid_second_plane(e2t, e2h, e2h2, x1, x3, sigma2, frame_size) -> dict:
    """Plane + parallax evidence of a triplet (``degeneracy="parallax"`` of
    :func:`eponet.geometry.triplets.estimate_triplet`).

    The second plane is the set of points the epipolar model explains as rigid that the dominant homography
    does not: outliers of the dominant homography, inliers of the second one and of the trifocal model.
    Returns its fraction of the points (``plane``), its :func:`border_ratio` (``border``) and ``speed``: the
    median displacement of its points from the first to the third frame over that of the dominant plane's
    inliers (border and speed are 0 when either set has fewer than ``MIN_PLANE_POINTS`` points).

    Parameters
    ----------
    e2t, e2h, e2h2 : arrays (N,)
        Squared residuals (pixels^2) of the trifocal model (3 dof), the dominant and the second homography
        pair (4 dof).
    x1, x3 : arrays (N, 2)
        Pixel positions in the triplet's first and last frame.
    sigma2 : float
        Noise variance (pixels^2) of the inlier bounds.
    frame_size : (height, width)
    """
    dominant = e2h <= inlier_bound(sigma2, 4)
    plane = ~dominant & (e2h2 <= inlier_bound(sigma2, 4)) & (e2t <= inlier_bound(sigma2, 3))
    out = {"plane": round(float(plane.mean()), 4), "border": 0.0, "speed": 0.0}
    if plane.sum() >= MIN_PLANE_POINTS and dominant.sum() >= MIN_PLANE_POINTS:
        moved = np.hypot(*(x3 - x1).T)
        out["border"] = round(border_ratio(x1, plane, frame_size), 3)
        out["speed"] = round(float(np.median(moved[plane]) / max(np.median(moved[dominant]), SPEED_FLOOR_PX)), 3)
    return out


def is_parallax(evidence: dict) -> bool:
    """Whether the evidence of :func:`rigid_second_plane` shows near rigid structure (see the module)."""
    return (evidence["plane"] >= PARALLAX_MIN_FRACTION and evidence["border"] >= PARALLAX_MIN_BORDER_RATIO
            and evidence["speed"] >= PARALLAX_MIN_SPEED_RATIO)
