"""Per-frame DAVIS measures: region similarity J, boundary accuracy F and temporal stability T.

All functions are pure and work on ``(H, W)`` masks (any dtype; non-zero is foreground). The semantics follow
the official DAVIS toolkits (see ``shared/docs/metrics.md``):

- J and F as in the DAVIS-2016 Python/MATLAB code and the DAVIS-2017 code (``void`` pixels).
- T as in the DAVIS MATLAB ``t_stability.m`` and its C++ helpers (polycont ``mask2poly``, ``mex_match_dijkstra``),
  re-implemented in numpy; :func:`db_eval_t` documents where this re-implementation may differ.

References
----------
.. [1] F. Perazzi, J. Pont-Tuset, B. McWilliams, L. Van Gool, M. Gross, A. Sorkine-Hornung, "A Benchmark Dataset
   and Evaluation Methodology for Video Object Segmentation", CVPR 2016.
.. [2] D. Martin, C. Fowlkes, J. Malik, "Learning to Detect Natural Image Boundaries Using Local Brightness,
   Color, and Texture Cues", PAMI 2004 (``seg2bmap``).
.. [3] S. Belongie, J. Malik, J. Puzicha, "Shape Matching and Object Recognition Using Shape Contexts",
   PAMI 2002 (shape-context descriptors and the chi-square cost).
.. [4] D. Douglas, T. Peucker, "Algorithms for the reduction of the number of points required to represent a
   digitized line or its caricature", Cartographica 1973.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "db_eval_iou",
    "seg2bmap",
    "boundary_tolerance",
    "disk",
    "db_eval_boundary",
    "boundary_precision_recall",
    "iou_matrix",
    "boundary_f_matrix",
    "T_SCALE",
    "mask_contours",
    "longest_contour",
    "contour_upsample",
    "shape_context",
    "chi2_cost",
    "match_contours",
    "db_eval_t",
]

#: DAVIS-2016 multiplies every per-pair T value by this factor ("magic number" in the official code).
T_SCALE = 5.0

# Shape-context / contour parameters of the official T (t_stability.m).
_CONT_TH = 3.0  # polygon simplification tolerance, in polycont's half-pixel grid (= 1.5 px)
_CONT_TH_UP = 3.0  # maximum segment length after resampling, in pixels
_NBINS_THETA = 12
_NBINS_R = 5
_R_INNER = 1.0 / 8.0
_R_OUTER = 2.0
_EPS = 2.2204e-16


def _as_bool(name: str, array: np.ndarray) -> np.ndarray:
    array = np.asarray(array)
    if array.ndim != 2:
        raise ValueError(f"{name}: expected a (H, W) mask, got shape {array.shape}")
    return array if array.dtype == bool else array != 0


def _check_same_shape(pred: np.ndarray, gt: np.ndarray, void: np.ndarray | None) -> None:
    if pred.shape != gt.shape:
        raise ValueError(f"pred and gt: shapes differ, {pred.shape} vs {gt.shape}")
    if void is not None and void.shape != gt.shape:
        raise ValueError(f"void: expected shape {gt.shape}, got {void.shape}")


# ---------------------------------------------------------------------------------------------------------------
# J: region similarity
# ---------------------------------------------------------------------------------------------------------------
def db_eval_iou(pred: np.ndarray, gt: np.ndarray, void: np.ndarray | None = None) -> float:
    """Region similarity J: the intersection over union of two masks.

    Parameters
    ----------
    pred, gt : (H, W) array
        Predicted and ground-truth masks; non-zero is foreground.
    void : (H, W) array, optional
        Pixels to ignore in both masks (DAVIS-2017 label 255).

    Returns
    -------
    float
        ``|P & G| / |P | G|`` over the non-void pixels, and 1.0 when both masks are empty there.

    Examples
    --------
    >>> a = np.zeros((4, 4), bool); a[:2] = True
    >>> b = np.zeros((4, 4), bool); b[:, :2] = True
    >>> db_eval_iou(a, b)
    0.3333333333333333
    """
    pred = _as_bool("pred", pred)
    gt = _as_bool("gt", gt)
    void = None if void is None else _as_bool("void", void)
    _check_same_shape(pred, gt, void)
    inter = pred & gt
    union = pred | gt
    if void is not None:
        keep = ~void
        inter &= keep
        union &= keep
    n_union = int(np.count_nonzero(union))
    if n_union == 0:
        return 1.0
    return int(np.count_nonzero(inter)) / n_union


# ---------------------------------------------------------------------------------------------------------------
# F: boundary accuracy
# ---------------------------------------------------------------------------------------------------------------
def seg2bmap(seg: np.ndarray) -> np.ndarray:
    """One-pixel-wide boundary map of a mask (BSDS ``seg2bmap``, [2]_).

    A pixel is a boundary pixel when it differs from its east, south or south-east neighbour; in the last row
    only the east neighbour is compared, in the last column only the south one, and the bottom-right pixel is
    never a boundary. The image border itself is therefore not a boundary.

    Parameters
    ----------
    seg : (H, W) array
        Mask; non-zero is foreground.

    Returns
    -------
    (H, W) bool array
    """
    seg = _as_bool("seg", seg)
    out = np.zeros(seg.shape, dtype=bool)
    if seg.shape[0] == 0 or seg.shape[1] == 0:
        return out
    core = seg[:-1, :-1]
    out[:-1, :-1] = (core != seg[:-1, 1:]) | (core != seg[1:, :-1]) | (core != seg[1:, 1:])
    out[-1, :-1] = seg[-1, :-1] != seg[-1, 1:]
    out[:-1, -1] = seg[:-1, -1] != seg[1:, -1]
    out[-1, -1] = False
    return out


def boundary_tolerance(shape: tuple[int, int], bound_th: float = 0.008) -> int:
    """The F tolerance in pixels: ``bound_th`` itself when >= 1, else ``ceil(bound_th * diagonal)``.

    >>> boundary_tolerance((480, 854))
    8
    """
    if bound_th >= 1:
        return int(bound_th)
    return int(math.ceil(bound_th * math.hypot(shape[0], shape[1])))


def disk(radius: int) -> np.ndarray:
    """Disk structuring element ``x^2 + y^2 <= radius^2`` as uint8 ``(2r+1, 2r+1)`` (as ``skimage.morphology.disk``)."""
    r = int(radius)
    y, x = np.mgrid[-r : r + 1, -r : r + 1]
    return ((x * x + y * y) <= r * r).astype(np.uint8)


def _dilated(bmap: np.ndarray, radius: int) -> tuple[tuple[slice, slice], np.ndarray]:
    """Dilate a non-empty boundary map with a disk, only inside its bounding box grown by ``radius``.

    Returns ``(box, dilated)`` where ``dilated`` is the dilation restricted to ``box`` (exact: the dilation is
    zero outside that box).
    """
    import cv2

    rows = np.flatnonzero(bmap.any(axis=1))
    cols = np.flatnonzero(bmap.any(axis=0))
    h, w = bmap.shape
    box = (slice(max(int(rows[0]) - radius, 0), min(int(rows[-1]) + radius + 1, h)),
           slice(max(int(cols[0]) - radius, 0), min(int(cols[-1]) + radius + 1, w)))
    crop = np.ascontiguousarray(bmap[box]).view(np.uint8)
    return box, cv2.dilate(crop, disk(radius)).view(bool)


def _precision_recall(n_fg: int, n_gt: int, fg_hits: int, gt_hits: int) -> tuple[float, float, float]:
    """``(F, P, R)`` from boundary pixel counts, with the DAVIS special cases."""
    if n_fg == 0 and n_gt > 0:
        precision, recall = 1.0, 0.0
    elif n_fg > 0 and n_gt == 0:
        precision, recall = 0.0, 1.0
    elif n_fg == 0 and n_gt == 0:
        precision, recall = 1.0, 1.0
    else:
        precision, recall = fg_hits / n_fg, gt_hits / n_gt
    if precision + recall == 0:
        return 0.0, precision, recall
    return 2.0 * precision * recall / (precision + recall), precision, recall


def boundary_precision_recall(
    pred: np.ndarray, gt: np.ndarray, bound_th: float = 0.008, void: np.ndarray | None = None
) -> tuple[float, float, float]:
    """Boundary F-measure with its precision and recall, as ``(F, P, R)``.

    See :func:`db_eval_boundary` for the definition.
    """
    pred = _as_bool("pred", pred)
    gt = _as_bool("gt", gt)
    void = None if void is None else _as_bool("void", void)
    _check_same_shape(pred, gt, void)
    if void is not None:
        pred = pred & ~void
        gt = gt & ~void
    fg_b = seg2bmap(pred)
    gt_b = seg2bmap(gt)
    n_fg = int(np.count_nonzero(fg_b))
    n_gt = int(np.count_nonzero(gt_b))
    fg_hits = gt_hits = 0
    if n_fg and n_gt:
        radius = boundary_tolerance(pred.shape, bound_th)
        box, gt_dil = _dilated(gt_b, radius)
        fg_hits = int(np.count_nonzero(fg_b[box] & gt_dil))
        box, fg_dil = _dilated(fg_b, radius)
        gt_hits = int(np.count_nonzero(gt_b[box] & fg_dil))
    return _precision_recall(n_fg, n_gt, fg_hits, gt_hits)


def iou_matrix(
    pred_labels: np.ndarray, gt_labels: np.ndarray, n_pred: int, n_gt: int, void: np.ndarray | None = None
) -> np.ndarray:
    """J between every predicted object ``1..n_pred`` and every ground-truth object ``1..n_gt``.

    Parameters
    ----------
    pred_labels, gt_labels : (H, W) integer arrays
        Object ids (0 = background); ids above ``n_pred`` / ``n_gt`` are ignored.
    void : (H, W) bool array, optional
        Pixels ignored in both.

    Returns
    -------
    (n_pred, n_gt) float64 array; 1.0 where both objects are empty (outside void).
    """
    p = np.asarray(pred_labels).astype(np.int64, copy=False).ravel()
    g = np.asarray(gt_labels).astype(np.int64, copy=False).ravel()
    if p.shape != g.shape:
        raise ValueError(f"pred and gt: shapes differ, {np.shape(pred_labels)} vs {np.shape(gt_labels)}")
    p = np.where(p > n_pred, 0, p)
    g = np.where(g > n_gt, 0, g)
    if void is not None:
        keep = ~np.asarray(void, dtype=bool).ravel()
        p, g = p[keep], g[keep]
    joint = np.bincount(p * (n_gt + 1) + g, minlength=(n_pred + 1) * (n_gt + 1)).reshape(n_pred + 1, n_gt + 1)
    inter = joint[1:, 1:].astype(np.float64)
    area_p = joint[1:, :].sum(axis=1)[:, None]
    area_g = joint[:, 1:].sum(axis=0)[None, :]
    union = area_p + area_g - inter
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(union > 0, inter / np.maximum(union, 1), 1.0)
    return out


def boundary_f_matrix(
    pred_labels: np.ndarray,
    gt_labels: np.ndarray,
    n_pred: int,
    n_gt: int,
    void: np.ndarray | None = None,
    bound_th: float = 0.008,
) -> np.ndarray:
    """F between every predicted object ``1..n_pred`` and every ground-truth object ``1..n_gt``.

    Each boundary map is computed and dilated once, so this costs ``n_pred + n_gt`` dilations rather than
    ``2 * n_pred * n_gt``; every entry equals :func:`db_eval_boundary` on that pair of objects.

    Returns
    -------
    (n_pred, n_gt) float64 array
    """
    pred_labels = np.asarray(pred_labels)
    gt_labels = np.asarray(gt_labels)
    if pred_labels.shape != gt_labels.shape:
        raise ValueError(f"pred and gt: shapes differ, {pred_labels.shape} vs {gt_labels.shape}")
    keep = None if void is None else ~np.asarray(void, dtype=bool)
    radius = boundary_tolerance(pred_labels.shape, bound_th)

    def boundaries(labels: np.ndarray, n: int):
        out = []
        for k in range(1, n + 1):
            obj = labels == k
            if keep is not None:
                obj &= keep
            b = seg2bmap(obj)
            count = int(np.count_nonzero(b))
            out.append((b, count, _dilated(b, radius) if count else None))
        return out

    preds = boundaries(pred_labels, n_pred)
    gts = boundaries(gt_labels, n_gt)
    result = np.empty((n_pred, n_gt), dtype=np.float64)
    for r, (fb, n_fg, fdil) in enumerate(preds):
        for c, (gb, n_gt_px, gdil) in enumerate(gts):
            fg_hits = gt_hits = 0
            if n_fg and n_gt_px:
                box, dil = gdil
                fg_hits = int(np.count_nonzero(fb[box] & dil))
                box, dil = fdil
                gt_hits = int(np.count_nonzero(gb[box] & dil))
            result[r, c] = _precision_recall(n_fg, n_gt_px, fg_hits, gt_hits)[0]
    return result


def db_eval_boundary(
    pred: np.ndarray, gt: np.ndarray, bound_th: float = 0.008, void: np.ndarray | None = None
) -> float:
    """Boundary accuracy F of the DAVIS benchmark [1]_.

    Boundaries come from :func:`seg2bmap` (no thinning); each is dilated with a disk of radius
    :func:`boundary_tolerance` (8 px at 854x480); a predicted boundary pixel is matched when it lies in the
    dilated ground-truth boundary and vice versa (no bipartite matching). Precision and recall have special
    cases: no predicted boundary but some ground-truth boundary gives P = 1, R = 0; the reverse gives P = 0,
    R = 1; none at all gives P = R = 1. ``F = 2PR / (P + R)``, or 0 when ``P + R = 0``.

    Parameters
    ----------
    pred, gt : (H, W) array
        Predicted and ground-truth masks; non-zero is foreground.
    bound_th : float, optional
        Tolerance as a fraction of the image diagonal (< 1) or in pixels (>= 1).
    void : (H, W) array, optional
        Pixels removed from both masks before the boundaries are taken (DAVIS-2017).

    Returns
    -------
    float
        F in [0, 1].

    Examples
    --------
    >>> a = np.zeros((48, 85), bool); a[10:30, 10:40] = True
    >>> db_eval_boundary(a, np.roll(a, 1, axis=1))
    1.0
    """
    return boundary_precision_recall(pred, gt, bound_th, void)[0]


# ---------------------------------------------------------------------------------------------------------------
# T: temporal stability
# ---------------------------------------------------------------------------------------------------------------
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
    """psimpl Douglas-Peucker [4]_ (after vertex reduction) on an open polyline, with segment distances."""
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
    mask = _as_bool("mask", mask)
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


def shape_context(points: np.ndarray) -> np.ndarray:
    """Shape-context histograms [3]_ at every contour point, as ``sc_compute.m`` with its DAVIS parameters.

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
