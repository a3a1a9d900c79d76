"""Hartley's point normalisation for estimation (the ED scaling for the motion net is in ``eponet.core.motion``).

References
----------
.. [HZ] R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2003.
"""

from __future__ import annotations

import numpy as np

__all__ = ["hartley_normalisation"]


def hartley_normalisation(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Similarity that moves the centroid to the origin and makes the mean distance sqrt(2) ([HZ] Sec. 4.4.4).

    Parameters
    ----------
    points : array (..., N, 2)
        Pixel coordinates; leading axes are independent batches.

    Returns
    -------
    normalised : array (..., N, 2) float64
        ``T @ [x, y, 1]`` (inhomogeneous).
    T : array (..., 3, 3) float64
        The similarity, so that ``x_hat = T x``.

    Examples
    --------
    >>> xn, t = hartley_normalisation(np.array([[0.0, 0.0], [2.0, 0.0]]))
    >>> xn.tolist()
    [[-1.4142135623730951, 0.0], [1.4142135623730951, 0.0]]
    """
    points = np.asarray(points, dtype=np.float64)
    n = points.shape[-2]
    centre = points.sum(axis=-2, keepdims=True) / n
    d = points - centre
    sq = d * d  # the two coordinates added by hand: a reduction over a last axis of 2 is slow in numpy
    mean_dist = np.sqrt(sq[..., 0] + sq[..., 1]).sum(-1) / n
    scale = np.sqrt(2.0) / np.maximum(mean_dist, 1e-12)
    t = np.zeros(points.shape[:-2] + (3, 3))
    t[..., 0, 0] = t[..., 1, 1] = scale
    t[..., 0, 2] = -scale * centre[..., 0, 0]
    t[..., 1, 2] = -scale * centre[..., 0, 1]
    t[..., 2, 2] = 1.0
    d *= scale[..., None, None]
    return d, t
