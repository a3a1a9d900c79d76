"""Normalisations: Hartley's point normalisation for estimation, and the per-video ED scaling for the motion net.

References
----------
.. [HZ] R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2003.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "hartley_normalisation",
    "ED_PERCENTILE",
    "ED_TARGET",
    "ED_FLOOR_PX",
    "ed_scale",
    "normalise_ed",
]


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
    centre = points.mean(axis=-2, keepdims=True)
    mean_dist = np.sqrt(((points - centre) ** 2).sum(-1)).mean(-1)
    scale = np.sqrt(2.0) / np.maximum(mean_dist, 1e-12)
    t = np.zeros(points.shape[:-2] + (3, 3))
    t[..., 0, 0] = t[..., 1, 1] = scale
    t[..., 0, 2] = -scale * centre[..., 0, 0]
    t[..., 1, 2] = -scale * centre[..., 0, 1]
    t[..., 2, 2] = 1.0
    return (points - centre) * scale[..., None, None], t


#: Percentile of the video's ED values (over all pixels of all frames) that sets the scale.
ED_PERCENTILE = 95.0
#: The value the percentile is mapped to (as in the original: 250 of 255).
ED_TARGET = 250.0 / 255.0
#: Lowest scale in pixels, so that a video whose ED is only flow noise is not stretched to full range.
ED_FLOOR_PX = 1.0


def ed_scale(ed_maps: np.ndarray, *, percentile: float = ED_PERCENTILE, floor: float = ED_FLOOR_PX) -> float:
    """Robust per-video ED scale in pixels: the ``percentile`` of all finite values, at least ``floor``."""
    ed_maps = np.asarray(ed_maps)
    finite = ed_maps[np.isfinite(ed_maps)]
    if finite.size == 0:
        return float(floor)
    # Sub-sample very large videos: the percentile of a 1M-value systematic subset differs negligibly.
    step = max(1, finite.size // 1_000_000)
    return float(max(np.percentile(finite[::step], percentile), floor))


def normalise_ed(
    ed_maps: np.ndarray,
    *,
    percentile: float = ED_PERCENTILE,
    target: float = ED_TARGET,
    floor: float = ED_FLOOR_PX,
    saturate: bool = True,
) -> np.ndarray:
    """Per-video ED scaling consumed by the motion net.

    ``out = clip(ed * target / s, 0, 1)`` with ``s = max(P_percentile(ed), floor)`` over every pixel of every
    frame of the video. With the defaults the 95th percentile maps to 250/255 and values above about
    1.02 x P95 saturate at 1, as in the original (which did the same per video, over trajectories, in uint8).
    The floor (1 px) keeps a static or perfectly rigid video, whose ED is only flow noise, near 0 instead of
    stretching its noise to the full range. NaN/inf become 0 and ``2 * target``.

    With ``saturate=False`` nothing is clipped above: the strongest 5% keep their values above 1 (the ED of a
    small, fast object can be tens of times the percentile). This is what the pipeline gives the motion net,
    whose :attr:`~eponet.nets.EpoUNet` ``ed_encoding`` then saturates the channel its own way.

    Parameters
    ----------
    ed_maps : array (F, H, W)
        Epipolar distances in pixels.

    Returns
    -------
    array (F, H, W) float32 in [0, 1] (``saturate``) or [0, inf)
    """
    ed_maps = np.asarray(ed_maps, dtype=np.float32)
    s = ed_scale(ed_maps, percentile=percentile, floor=floor)
    out = np.nan_to_num(ed_maps, nan=0.0, posinf=np.float32(2 * s / target), neginf=0.0) * np.float32(target / s)
    return np.clip(out, 0.0, 1.0 if saturate else None, out=out).astype(np.float32, copy=False)
