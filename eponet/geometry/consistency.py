"""Flow sampling and forward-backward consistency (occlusion) tests.

Flow conventions are those of :mod:`eponet.core.types`: ``forward`` maps frame t -> t+1 on the grid of frame
t, ``backward`` maps t+1 -> t on the grid of frame t+1, both float32 ``(H, W, 2)`` holding ``(dx, dy)``.

References
----------
.. [S10] N. Sundaram, T. Brox and K. Keutzer, "Dense point trajectories by GPU-accelerated large displacement
   optical flow", ECCV 2010 (the tolerance test).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..core.imaging import fb_consistent

__all__ = [
    "sample_bilinear",
    "round_half_up",
    "fb_consistent_points",
    "exact_round_trip",
    "forward_backward_consistency",
]

_REMAP_COLS = 4096  # cv2.remap needs maps smaller than 32767 on each side: fold point lists into rows


def sample_bilinear(field: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Bilinearly sample a multi-channel image at sub-pixel points (border values replicated).

    Uses OpenCV's ``remap``, whose interpolation weights are quantised to 1/32 pixel (an error far below
    the noise of estimated flow; constant fields are reproduced exactly).

    Parameters
    ----------
    field : array (H, W, C) float32
    points : array (N, 2)
        ``(x, y)`` pixel coordinates.

    Returns
    -------
    array (N, C) float32
    """
    n = len(points)
    c = field.shape[2]
    if n == 0:
        return np.zeros((0, c), np.float32)
    rows = -(-n // _REMAP_COLS)
    maps = np.zeros((rows * _REMAP_COLS, 2), np.float32)
    maps[:n] = points
    out = cv2.remap(
        np.ascontiguousarray(field, dtype=np.float32),
        maps.reshape(rows, _REMAP_COLS, 2),
        None,
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return out.reshape(-1, c)[:n]


def round_half_up(values: np.ndarray) -> np.ndarray:
    """``floor(v + 0.5)`` as int64: MATLAB's ``round`` for the non-negative coordinates that matter here."""
    return np.floor(np.asarray(values) + 0.5).astype(np.int64)


def fb_consistent_points(
    forward: np.ndarray,
    backward: np.ndarray,
    points: np.ndarray,
    *,
    relative: float = 0.01,
    absolute: float = 0.5,
) -> tuple[np.ndarray, np.ndarray]:
    """Advect points one frame and apply the tolerance forward-backward test ([S10]).

    With ``f = forward(p)`` and ``b = backward(p + f)`` (both bilinearly sampled), ``p`` is consistent iff
    ``|f + b|^2 < relative (|f|^2 + |b|^2) + absolute`` (pixels^2; defaults 0.01 and 0.5 as in [S10]).

    Parameters
    ----------
    forward, backward : array (H, W, 2) float32
        Flow of one pair (t -> t+1 on grid t, t+1 -> t on grid t+1).
    points : array (N, 2) float32
        Positions in frame t.

    Returns
    -------
    targets : array (N, 2) float32
        ``p + f``, positions in frame t+1.
    ok : bool array (N,)
        The test result (targets outside the frame are not excluded here).
    """
    f = sample_bilinear(forward, points)
    targets = points + f
    b = sample_bilinear(backward, targets)
    return targets, fb_consistent(f[:, 0], f[:, 1], b[:, 0], b[:, 1], relative=relative, absolute=absolute)


def exact_round_trip(forward: np.ndarray, backward: np.ndarray) -> np.ndarray:
    """The original code's occlusion test: an exact rounded round trip (``findConsistentflow``).

    Pixel ``p`` of frame t is consistent iff ``round(p + f(p)) == c*``, where ``c*`` is the pixel of frame t+1
    whose rounded backward target is ``p`` (the largest linear index wins when several land on ``p``; the
    original's linear index is column-major, here it is the row-major index ``y W + x``).

    Parameters
    ----------
    forward, backward : array (H, W, 2) float32

    Returns
    -------
    bool array (H, W)
    """
    h, w = forward.shape[:2]
    ys, xs = np.mgrid[0:h, 0:w]
    fx = round_half_up(xs + forward[..., 0]).ravel()
    fy = round_half_up(ys + forward[..., 1]).ravel()
    bx = round_half_up(xs + backward[..., 0]).ravel()
    by = round_half_up(ys + backward[..., 1]).ravel()
    f_in = (fx >= 0) & (fx < w) & (fy >= 0) & (fy < h)
    b_in = (bx >= 0) & (bx < w) & (by >= 0) & (by < h)
    inverse = np.full(h * w, -1, np.int64)
    src = np.flatnonzero(b_in)
    np.maximum.at(inverse, by[src] * w + bx[src], src)
    target = np.where(f_in, fy * w + fx, -2)
    return (target == inverse).reshape(h, w)


def forward_backward_consistency(
    forward: np.ndarray, backward: np.ndarray, *, method: str = "tolerance"
) -> np.ndarray:
    """Per-pixel occlusion mask of frame t: True where the flow t -> t+1 is forward-backward consistent and
    the target stays inside the frame.

    Parameters
    ----------
    forward, backward : array (H, W, 2) float32
    method : {"tolerance", "exact"}
        ``"tolerance"``: :func:`fb_consistent_points` at pixel centres ([S10]); ``"exact"``: the original
        rounded round trip, :func:`exact_round_trip`.

    Returns
    -------
    bool array (H, W)

    Examples
    --------
    >>> flow = np.zeros((4, 5, 2), np.float32); flow[..., 0] = 1.0
    >>> int(forward_backward_consistency(flow, -flow).sum())  # the last column leaves the frame
    16
    """
    h, w = forward.shape[:2]
    if method == "exact":
        return exact_round_trip(forward, backward)
    if method != "tolerance":
        raise ValueError(f"forward_backward_consistency: method must be 'tolerance' or 'exact', got {method!r}")
    ys, xs = np.mgrid[0:h, 0:w]
    grid = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32)
    targets, ok = fb_consistent_points(forward, backward, grid)
    r = round_half_up(targets)
    inside = (r[:, 0] >= 0) & (r[:, 0] < w) & (r[:, 1] >= 0) & (r[:, 1] < h)
    return (ok & inside).reshape(h, w)
