"""Motion support of a fused foreground map: appearance may shape an object, not add one that does not move.

EpO+'s fusion (and its self-training) reads appearance features, and appearance alone cannot tell the moving
flamingo from the standing one beside it: both look alike, and the fused map often takes both. The motion map
can: only one of them has motion saliency. :func:`motion_supported` keeps each connected foreground region of the
fused map that holds at least one pixel of clear motion saliency, and lowers the others to the motion map's
value (so where the motion map saw nothing, nothing is left). A frame in which no region has support keeps its
fused map as it is: the fusion's memory carries an object through frames where it stops or blurs, and those are
the frames the motion map misses.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["motion_supported"]


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
    if probability.shape != motion.shape or probability.ndim != 3:
        raise ValueError(f"probability and motion must both be (F, H, W), got {probability.shape} and {motion.shape}")
    out = np.array(probability, np.float32, copy=True)
    structure = np.ones((3, 3), bool)
    for t in range(len(out)):
        labels, count = ndimage.label(out[t] > level, structure=structure)
        if count == 0:
            continue
        keep = np.zeros(count + 1, bool)
        keep[labels[motion[t] >= support]] = True  # the regions with a pixel of clear motion
        if not keep[1:].any():
            continue
        keep[0] = True  # (label 0, below the level, is never lowered)
        lowered = ~keep[labels]
        out[t][lowered] = np.minimum(out[t][lowered], motion[t][lowered])
    return out
