"""Per-frame DAVIS measures: region similarity J and boundary accuracy F (temporal stability T: ``temporal.py``,
re-exported here).

All functions are pure and work on ``(H, W)`` masks (any dtype; non-zero is foreground). The semantics follow
the official DAVIS toolkits (see ``shared/docs/metrics.md``):

- J and F as in the DAVIS-2016 Python/MATLAB code and the DAVIS-2017 code (``void`` pixels).
- T in :mod:`eponet.evaluation.temporal`.

References
----------
.. [1] F. Perazzi, J. Pont-Tuset, B. McWilliams, L. Van Gool, M. Gross, A. Sorkine-Hornung, "A Benchmark Dataset
   and Evaluation Methodology for Video Object Segmentation", CVPR 2016.
.. [2] D. Martin, C. Fowlkes, J. Malik, "Learning to Detect Natural Image Boundaries Using Local Brightness,
   Color, and Texture Cues", PAMI 2004 (``seg2bmap``).
"""

from __future__ import annotations

import math

import numpy as np

from eponet.evaluation.contours import bool_mask
from eponet.evaluation.temporal import (T_SCALE, chi2_cost, contour_upsample, db_eval_t, longest_contour,
                                        mask_contours, match_contours, shape_context)

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
    pred = bool_mask("pred", pred)
    gt = bool_mask("gt", gt)
    void = None if void is None else bool_mask("void", void)
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
    seg = bool_mask("seg", seg)
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
    pred = bool_mask("pred", pred)
    gt = bool_mask("gt", gt)
    void = None if void is None else bool_mask("void", void)
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
