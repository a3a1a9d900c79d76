"""Temporal stability T of DAVIS-2016: how much a mask's contour deforms from one frame to the next.

As in the DAVIS MATLAB ``t_stability.m`` and its C++ helpers (polycont ``mask2poly``, ``mex_match_dijkstra``),
re-implemented in numpy: each mask's longest contour (:mod:`eponet.evaluation.contours`), resampled, described
by shape contexts, matched by a monotone shortest path on the chi-square cost; :func:`db_eval_t` documents
where this re-implementation may differ. Masks are ``(H, W)``, any dtype, non-zero is foreground.

References
----------
.. [1] F. Perazzi et al., "A Benchmark Dataset and Evaluation Methodology for Video Object Segmentation",
   CVPR 2016.
.. [2] S. Belongie, J. Malik, J. Puzicha, "Shape Matching and Object Recognition Using Shape Contexts",
   PAMI 2002 (shape-context descriptors and the chi-square cost).
"""

from __future__ import annotations

import numpy as np

from eponet.evaluation.contours import contour_upsample, longest_contour, mask_contours

__all__ = ["T_SCALE", "shape_context", "chi2_cost", "match_contours", "db_eval_t"]

#: DAVIS-2016 multiplies every per-pair T value by this factor ("magic number" in the official code).
T_SCALE = 5.0

# Shape-context / contour parameters of the official T (t_stability.m).
_NBINS_THETA = 12
_NBINS_R = 5
_R_INNER = 1.0 / 8.0
_R_OUTER = 2.0
_EPS = 2.2204e-16


def shape_context(points: np.ndarray) -> np.ndarray:
    """Shape-context histograms [2]_ at every contour point, as ``sc_compute.m`` with its DAVIS parameters.

    Log-polar histograms of the positions of all points (the point itself included) relative to each point:
    12 absolute-angle bins and 5 radius bins with edges ``logspace(log10(1/8), log10(2), 5)`` times the mean
    pairwise distance; points farther than 2 mean distances are not counted.

    Parameters
    ----------
    points : (N, 2) array
        ``(x, y)`` coordinates.

    Returns
    -------
    (N, 60) int64 array
    """
    from scipy.spatial.distance import pdist

    pts = np.asarray(points, dtype=np.float64)
    n = len(pts)
    nbins = _NBINS_THETA * _NBINS_R
    # mean over the full n x n distance matrix, zero diagonal included (as sc_compute.m)
    mean_dist = 2.0 * pdist(pts).sum() / (n * n) if n > 1 else 0.0
    edges = np.logspace(np.log10(_R_INNER), np.log10(_R_OUTER), _NBINS_R)
    two_pi = 2 * np.pi
    # Radius bin k = number of edges <= r (0 nearest ... 4; 5 = beyond the outer edge, not counted) and angle
    # bin as sc_compute.m; the bins are a fixed permutation of the official order, which the chi-square cost
    # does not see. Column ``wide - 12..`` collects the points that are not counted.
    wide = (_NBINS_R + 1) * _NBINS_THETA
    hist = np.zeros(n * wide, dtype=np.int64)
    step = max(1, (4 << 20) // max(n, 1))
    for s in range(0, n, step):
        rows_idx = np.arange(s, min(s + step, n))
        dx = pts[None, :, 0] - pts[rows_idx, None, 0]  # dx[i, j] = x_j - x_i
        dy = pts[None, :, 1] - pts[rows_idx, None, 1]
        r_n = np.hypot(dx, dy)
        if mean_dist > 0:
            r_n /= mean_dist
        idx = np.searchsorted(edges, r_n, side="right")
        idx *= _NBINS_THETA
        theta = np.arctan2(dy, dx)
        np.fmod(theta, two_pi, out=theta)
        theta += two_pi
        np.fmod(theta, two_pi, out=theta)
        theta /= two_pi / _NBINS_THETA
        theta_q = theta.astype(np.int64)  # floor: theta >= 0
        np.minimum(theta_q, _NBINS_THETA - 1, out=theta_q)
        idx += theta_q
        idx += (rows_idx * wide)[:, None]
        hist += np.bincount(idx.ravel(), minlength=n * wide)
    return hist.reshape(n, wide)[:, :nbins]


def chi2_cost(h1: np.ndarray, h2: np.ndarray) -> np.ndarray:
    """Chi-square cost ``0.5 * sum((a - b)^2 / (a + b + eps))`` between L1-normalised histograms (``hist_cost_2.m``).

    Computed as ``0.5 * (sum(a) + sum(b) - 4 * sum(a b / (a + b)))``, where only bins that are non-zero in both
    histograms contribute to the last sum; this equals the direct formula up to ~1e-15 and is several times
    faster on shape contexts (most bins are empty).

    Parameters
    ----------
    h1 : (N1, B) array
    h2 : (N2, B) array

    Returns
    -------
    (N1, N2) float64 array
    """
    a = h1 / (h1.sum(axis=1, keepdims=True) + _EPS)
    b = h2 / (h2.sum(axis=1, keepdims=True) + _EPS)
    harmonic = np.zeros((a.shape[0], b.shape[0]), dtype=np.float64)
    b_t = np.ascontiguousarray(b.T)
    for k in range(a.shape[1]):
        rows = np.flatnonzero(a[:, k])
        cols = np.flatnonzero(b_t[k])
        if rows.size == 0 or cols.size == 0:
            continue
        x = a[rows, k][:, None]
        y = b_t[k, cols][None, :]
        block = np.zeros((rows.size, b.shape[0]), dtype=np.float64)
        block[:, cols] = x * y / (x + y)
        harmonic[rows] += block
    out = a.sum(axis=1)[:, None] + b.sum(axis=1)[None, :]
    out -= 4.0 * harmonic
    out *= 0.5
    # tiny negative values from rounding when the histograms are identical
    np.maximum(out, 0.0, out=out)
    return out


def _grid_shortest_path(cost: np.ndarray) -> np.ndarray:
    """Cheapest monotone path from cell (0, 0) to (N1-1, N2-1) with steps (+1, 0), (0, +1), (+1, +1).

    The path cost is the sum of the costs of the cells entered (the start cell is free), as the Dijkstra of
    ``mex_match_dijkstra.cpp`` on its grid graph. Returns the cells from the end back to the start, ``(K, 2)``.
    """
    n1, n2 = cost.shape
    acc = np.empty((n1, n2), dtype=np.float64)
    # Row 0: only moves along the row.
    acc[0, 0] = 0.0
    acc[0, 1:] = np.cumsum(cost[0, 1:])
    for i in range(1, n1):
        c = cost[i]
        prev = acc[i - 1]
        # best arrival from the previous row: straight down or diagonal
        a = prev.copy()
        a[1:] = np.minimum(prev[1:], prev[:-1])
        # acc[i, j] = c[j] + min(a[j], acc[i, j-1])  ==  S[j] + min_{k<=j}(a[k] - S[k-1])
        s = np.cumsum(c)
        s_prev = np.concatenate(([0.0], s[:-1]))
        acc[i] = s + np.minimum.accumulate(a - s_prev)
    # Backtrack, preferring the diagonal, then the cell above, then the cell to the left on ties.
    path = [(n1 - 1, n2 - 1)]
    i, j = n1 - 1, n2 - 1
    acc_l = acc  # local alias
    while i > 0 or j > 0:
        if i == 0:
            j -= 1
        elif j == 0:
            i -= 1
        else:
            d, u, l = acc_l[i - 1, j - 1], acc_l[i - 1, j], acc_l[i, j - 1]
            if d <= u and d <= l:
                i, j = i - 1, j - 1
            elif u <= l:
                i -= 1
            else:
                j -= 1
        path.append((i, j))
    return np.asarray(path, dtype=np.int64)


def _bijective(pairs: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """``get_bijective_matching.m``: per first index keep its cheapest pair, then per second index likewise."""
    for side in (0, 1):
        keys = pairs[:, side]
        c = cost[pairs[:, 0], pairs[:, 1]]
        # sort by key, then cost, then original position (MATLAB's min takes the first among equal costs)
        order = np.lexsort((np.arange(len(pairs)), c, keys))
        sorted_keys = keys[order]
        first = np.ones(len(order), dtype=bool)
        first[1:] = sorted_keys[1:] != sorted_keys[:-1]
        pairs = pairs[order[first]]
    return pairs


def match_contours(cost: np.ndarray) -> np.ndarray:
    """Order-preserving matching of two closed contours given their ``(N1, N2)`` cost matrix.

    As ``t_stability.m``: a shortest path from (0, 0) to (N1-1, N2-1); the cost matrix is then rolled so that
    the cheapest cell on that path (excluding the start; nearest the end on ties) becomes the last cell, the
    shortest path is computed again and mapped back, and a bijective subset of the pairs is kept.

    Returns
    -------
    (K, 2) int64 array of ``(i, j)`` pairs.
    """
    path = _grid_shortest_path(cost)
    on_path = path[:-1]  # the start cell (0, 0) is not considered
    values = cost[on_path[:, 0], on_path[:, 1]]
    k = int(np.argmin(values))  # first minimum scanning from the end, as the C++ code
    shift_x = int(on_path[k, 0]) + 1
    shift_y = int(on_path[k, 1]) + 1
    n1, n2 = cost.shape
    rolled = np.roll(np.roll(cost, -shift_x, axis=0), -shift_y, axis=1)
    pairs = _grid_shortest_path(rolled)
    pairs[:, 0] = (pairs[:, 0] + shift_x) % n1
    pairs[:, 1] = (pairs[:, 1] + shift_y) % n2
    return _bijective(pairs, cost)


def db_eval_t(mask_a: np.ndarray, mask_b: np.ndarray) -> float:
    """Temporal (in)stability between two consecutive predicted masks, *before* the DAVIS x5 scaling.

    Following ``t_stability.m`` [1]_: the longest simplified contour of each mask (:func:`mask_contours`,
    :func:`longest_contour`) is resampled so that no segment exceeds 3 px (:func:`contour_upsample`);
    shape-context descriptors (:func:`shape_context`) are compared with the chi-square cost (:func:`chi2_cost`);
    the contours are matched in order (:func:`match_contours`) and the result is the mean cost of the matched
    pairs. Multiply by :data:`T_SCALE` for the value DAVIS-2016 reports. Lower is more stable.

    The contour simplification tolerance is 1.5 px: ``t_stability.m`` passes 3 to polycont, which simplifies
    on its doubled (half-pixel) junction grid and halves the coordinates afterwards (``shared/docs/metrics.md``
    says "tolerance 3 px"). Like psimpl, vertex reduction precedes Douglas-Peucker.

    Differences from the official C++/MATLAB code (why numbers may differ slightly; not verified against it,
    since the official code needs compiled MEX/Boost helpers):

    - Contours are traced here on pixel cracks with the foreground 8-connected at saddle corners; polycont's
      ``lines2jordan`` may resolve saddles the other way. Each path starts at the top-left corner of its first
      crack in row-major order; polycont starts at another corner, which can change which vertices the
      Douglas-Peucker simplification keeps (the cyclic re-alignment of the matching absorbs the rest).
    - Vertices inside straight runs are dropped before Douglas-Peucker (equivalent up to rounding ties);
      psimpl interpolates in float32, this code in float64.
    - Ties in the shortest path are broken diagonal-first, then up, then left; Boost's Dijkstra breaks them in
      its queue order.
    - Points are ``(x, y)`` as in the DAVIS Python port; the MATLAB code uses ``(row, col)``. The angle bins
      are absolute, so the two differ for points at exact bin edges only.
    - The chi-square cost is computed in an algebraically equal form (differences ~1e-15).

    Parameters
    ----------
    mask_a, mask_b : (H, W) array
        Masks of frames t and t+1; non-zero is foreground.

    Returns
    -------
    float
        Mean matched shape-context cost, or NaN when either mask has no contour (empty, or only single
        pixels).
    """
    conts_a = mask_contours(mask_a)
    conts_b = mask_contours(mask_b)
    if not conts_a or not conts_b:
        return float("nan")
    up_a = contour_upsample(longest_contour(conts_a))
    up_b = contour_upsample(longest_contour(conts_b))
    cost = chi2_cost(shape_context(up_a), shape_context(up_b))
    pairs = match_contours(cost)
    return float(cost[pairs[:, 0], pairs[:, 1]].mean())
