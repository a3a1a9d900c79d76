"""Closed contour polygons of a binary mask, as polycont's ``mask2pce`` computes them for DAVIS's T.

Contours run along the pixel cracks, closed, then simplified as psimpl does (vertex reduction, then
Douglas-Peucker [1]_), and resampled so that no segment is longer than a given step. Masks are ``(H, W)``, any
dtype, non-zero is foreground; points are ``(x, y)`` in pixels, pixel ``(r, c)`` spanning ``[c, c+1] x [r, r+1]``.

.. [1] D. Douglas, T. Peucker, "Algorithms for the reduction of the number of points required to represent a
   digitized line or its caricature", Cartographica 1973.
"""

from __future__ import annotations

import numpy as np

__all__ = ["bool_mask", "mask_contours", "longest_contour", "contour_upsample"]

_CONT_TH = 3.0  # polygon simplification tolerance, in polycont's half-pixel grid (= 1.5 px)
_CONT_TH_UP = 3.0  # maximum segment length after resampling, in pixels


def bool_mask(name: str, array: np.ndarray) -> np.ndarray:
    """``array`` as a bool ``(H, W)`` mask (non-zero is foreground); ValueError naming ``name`` otherwise."""
    array = np.asarray(array)
    if array.ndim != 2:
        raise ValueError(f"{name}: expected a (H, W) mask, got shape {array.shape}")
    return array if array.dtype == bool else array != 0


def _crack_edges(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Directed crack edges between foreground and background pixels, foreground always on the same side.

    Corners of the zero-padded ``(H+2, W+2)`` mask are numbered ``row * (W + 3) + col``. Returns the start and
    end corner of every edge and the number of corner columns.
    """
    m = np.pad(mask, 1)
    ncols = m.shape[1] + 1
    # Horizontal cracks between pixel rows i-1 and i at column j: corners (i, j) - (i, j+1).
    up, down = m[:-1, :], m[1:, :]
    i, j = np.nonzero(~up & down)  # foreground below: walk east
    starts = [(i + 1) * ncols + j]
    ends = [(i + 1) * ncols + j + 1]
    i, j = np.nonzero(up & ~down)  # foreground above: walk west
    starts.append((i + 1) * ncols + j + 1)
    ends.append((i + 1) * ncols + j)
    # Vertical cracks between pixel columns j-1 and j at row i: corners (i, j) - (i+1, j).
    left, right = m[:, :-1], m[:, 1:]
    i, j = np.nonzero(~left & right)  # foreground on the east side: walk north
    starts.append((i + 1) * ncols + j + 1)
    ends.append(i * ncols + j + 1)
    i, j = np.nonzero(left & ~right)  # foreground on the west side: walk south
    starts.append(i * ncols + j + 1)
    ends.append((i + 1) * ncols + j + 1)
    return np.concatenate(starts), np.concatenate(ends), ncols


def _trace_loops(starts: np.ndarray, ends: np.ndarray, ncols: int) -> list[np.ndarray]:
    """Chain directed crack edges into closed loops of corner ids (each loop listed once, not closed)."""
    order = np.argsort(starts, kind="stable")
    s_sorted = starts[order]
    # Out-edges of a corner, looked up by corner id; a corner has one out-edge, or two at a saddle.
    n = starts.size
    succ = np.full(n, -1, dtype=np.int64)
    lookup_first = np.searchsorted(s_sorted, ends, side="left")
    lookup_count = np.searchsorted(s_sorted, ends, side="right") - lookup_first
    single = lookup_count == 1
    succ[single] = order[lookup_first[single]]
    saddle = np.flatnonzero(lookup_count == 2)
    if saddle.size:
        # At a saddle (two diagonal foreground pixels) keep turning away from the foreground side, so that the
        # diagonal pixels are one 8-connected region with one contour.
        d_in = ends[saddle] - starts[saddle]
        for k, e in enumerate(saddle):
            cands = order[lookup_first[e] : lookup_first[e] + 2]
            d_out = ends[cands] - starts[cands]
            din = _direction(d_in[k], ncols)
            # cross(d_in, d_out) < 0 is a turn away from the foreground (which is on the +cross side)
            crosses = [din[0] * _direction(d, ncols)[1] - din[1] * _direction(d, ncols)[0] for d in d_out]
            succ[e] = cands[int(np.argmin(crosses))]
    visited = np.zeros(n, dtype=bool)
    loops = []
    succ_list = succ.tolist()
    for e0 in range(n):
        if visited[e0]:
            continue
        loop = []
        e = e0
        while not visited[e]:
            visited[e] = True
            loop.append(e)
            e = succ_list[e]
        loops.append(starts[np.asarray(loop, dtype=np.int64)])
    return loops


def _direction(delta: int, ncols: int) -> tuple[int, int]:
    """(dx, dy) of a unit corner step given its id difference."""
    if delta == 1:
        return 1, 0
    if delta == -1:
        return -1, 0
    if delta == ncols:
        return 0, 1
    return 0, -1


def _radial_reduce(points: np.ndarray, tol: float) -> np.ndarray:
    """psimpl vertex reduction: drop points closer than ``tol`` to the last kept one (first and last kept)."""
    n = len(points)
    if n < 3:
        return points
    tol2 = tol * tol
    keep = [0]
    key = points[0]
    pts = points.tolist()
    kx, ky = key
    for idx in range(1, n - 1):
        x, y = pts[idx]
        if (x - kx) ** 2 + (y - ky) ** 2 < tol2:
            continue
        keep.append(idx)
        kx, ky = x, y
    keep.append(n - 1)
    return points[keep]


def _drop_collinear(closed: np.ndarray) -> np.ndarray:
    """Remove the vertices inside straight runs of a closed path (first == last), keeping the first vertex.

    Such vertices are never the unique farthest point from a Douglas-Peucker chord (the distance is convex
    along a straight run), so dropping them first leaves the result unchanged (up to rounding ties between
    equally distant points) and saves most of the work.
    """
    pts = closed[:-1]
    if len(pts) < 3:
        return closed
    d_in = pts - np.roll(pts, 1, axis=0)
    d_out = np.roll(pts, -1, axis=0) - pts
    turn = (d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0]) != 0
    turn[0] = True
    kept = pts[turn]
    return np.concatenate([kept, kept[:1]], axis=0)


def _farthest_py(xs: list, ys: list, a: int, b: int) -> tuple[int, float]:
    """Farthest point of ``a+1 .. b-1`` from segment ``(a, b)`` (last one on ties), plain Python for short runs."""
    x0, y0 = xs[a], ys[a]
    ux, uy = xs[b] - x0, ys[b] - y0
    cu = ux * ux + uy * uy
    best, best_d2 = a, -1.0
    for i in range(a + 1, b):
        wx, wy = xs[i] - x0, ys[i] - y0
        cw = wx * ux + wy * uy
        if cw <= 0 or cu <= 0:
            d2 = wx * wx + wy * wy
        elif cu <= cw:
            ex, ey = xs[i] - xs[b], ys[i] - ys[b]
            d2 = ex * ex + ey * ey
        else:
            f = cw / cu
            ex, ey = wx - f * ux, wy - f * uy
            d2 = ex * ex + ey * ey
        if d2 >= best_d2:
            best, best_d2 = i, d2
    return best, best_d2


def _douglas_peucker(points: np.ndarray, tol: float) -> np.ndarray:
    """psimpl Douglas-Peucker [1]_ (after vertex reduction) on an open polyline, with segment distances."""
    points = _radial_reduce(points, tol)
    n = len(points)
    if n < 3:
        return points
    tol2 = tol * tol
    keys = np.zeros(n, dtype=bool)
    keys[0] = keys[-1] = True
    xs = points[:, 0]
    ys = points[:, 1]
    xl, yl = xs.tolist(), ys.tolist()
    stack = [(0, n - 1)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            continue
        if b - a < 48:
            idx, d2max = _farthest_py(xl, yl, a, b)
        else:
            x0, y0 = xs[a], ys[a]
            ux, uy = xs[b] - x0, ys[b] - y0
            wx = xs[a + 1 : b] - x0
            wy = ys[a + 1 : b] - y0
            cu = ux * ux + uy * uy
            cw = wx * ux + wy * uy
            if cu > 0:
                frac = cw / cu
                np.maximum(frac, 0.0, out=frac)
                np.minimum(frac, 1.0, out=frac)
            else:
                frac = np.zeros_like(cw)
            ex = wx - frac * ux
            ey = wy - frac * uy
            d2 = ex * ex + ey * ey
            # psimpl keeps the *last* point among equal maxima
            k = d2.size - 1 - int(d2[::-1].argmax())
            idx, d2max = a + 1 + k, float(d2[k])
        if d2max > tol2:
            keys[idx] = True
            stack.append((idx, b))
            stack.append((a, idx))
    return points[keys]


def mask_contours(mask: np.ndarray, tolerance: float = _CONT_TH / 2) -> list[np.ndarray]:
    """Simplified closed contour polygons of a mask, as polycont's ``mask2pce`` (DAVIS T) computes them.

    Contours run along the pixel cracks (vertices on pixel corners, ``(x, y)`` with pixel ``(r, c)`` spanning
    ``[c, c+1] x [r, r+1]``); outer boundaries and holes run in opposite directions. Each closed path (first
    vertex repeated at the end) is simplified twice with psimpl's Douglas-Peucker (tolerance 0.05 px, then
    ``tolerance``); paths left with 3 points or fewer (single pixels) are dropped.

    Parameters
    ----------
    mask : (H, W) array
        Non-zero is foreground.
    tolerance : float, optional
        Simplification tolerance in pixels. polycont works on a half-pixel grid with tolerance 3 there, i.e.
        1.5 px here (the default).

    Returns
    -------
    list of (N, 2) float64 arrays
        ``(x, y)`` vertices, closed (first == last).
    """
    mask = bool_mask("mask", mask)
    rows_any = np.flatnonzero(mask.any(axis=1))
    if rows_any.size == 0:
        return []
    cols_any = np.flatnonzero(mask.any(axis=0))
    top, left = int(rows_any[0]), int(cols_any[0])
    crop = mask[top : rows_any[-1] + 1, left : cols_any[-1] + 1]
    starts, ends, ncols = _crack_edges(crop)
    contours = []
    for loop in _trace_loops(starts, ends, ncols):
        rows, cols = np.divmod(loop, ncols)
        pts = np.stack([cols - 1 + left, rows - 1 + top], axis=1).astype(np.float64)
        pts = _drop_collinear(np.concatenate([pts, pts[:1]], axis=0))
        # polycont's first pass with 0.1 (half-pixel units) removes collinear points
        pts = _douglas_peucker(pts, 0.05)
        if tolerance > 0.05:
            pts = _douglas_peucker(pts, tolerance)
        if len(pts) > 3:
            contours.append(pts)
    return contours


def longest_contour(contours: list[np.ndarray]) -> np.ndarray:
    """The contour with the most vertices (the first one on ties, as ``get_longest_cont.m``)."""
    best = contours[0]
    for cont in contours[1:]:
        if len(cont) > len(best):
            best = cont
    return best


def contour_upsample(contour: np.ndarray, max_step: float = _CONT_TH_UP) -> np.ndarray:
    """Insert evenly spaced points so that no segment of the closed polygon is longer than ``max_step``.

    Follows ``contour_upsample.m``: the polygon is closed back to its first vertex and a segment of length
    ``L > max_step`` gets ``ceil(L / max_step) - 1`` points inserted.
    """
    pts = np.concatenate([contour, contour[:1]], axis=0).astype(np.float64)
    seg = np.diff(pts, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    n_segm = np.where(length > max_step, np.ceil(length / max_step), 1).astype(np.int64)
    out = []
    for k in range(len(seg)):
        out.append(pts[k : k + 1])
        if n_segm[k] > 1:
            steps = np.arange(1, n_segm[k])[:, None] / n_segm[k]
            out.append(pts[k] + steps * seg[k])
    return np.concatenate(out, axis=0)
