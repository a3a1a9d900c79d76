"""Known answers for J and F, and agreement with a direct transcription of the official DAVIS code."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.ndimage as ndi

from eponet.evaluation.metrics import (
    boundary_f_matrix,
    boundary_precision_recall,
    boundary_tolerance,
    db_eval_boundary,
    db_eval_iou,
    disk,
    iou_matrix,
    seg2bmap,
)

H, W = 480, 854


def rect(r0, r1, c0, c1, shape=(H, W)):
    m = np.zeros(shape, bool)
    m[r0:r1, c0:c1] = True
    return m


# ---------------------------------------------------------------------------------------------------------------
# J
# ---------------------------------------------------------------------------------------------------------------
def test_iou_both_empty_is_one():
    empty = np.zeros((10, 12), bool)
    assert db_eval_iou(empty, empty) == 1.0


def test_iou_one_empty_is_zero():
    empty = np.zeros((10, 12), bool)
    full = rect(2, 5, 3, 9, (10, 12))
    assert db_eval_iou(empty, full) == 0.0
    assert db_eval_iou(full, empty) == 0.0


def test_iou_hand_computed_overlap():
    # 40 x 60 rectangle shifted 3 px right: intersection 40*57, union 40*63
    gt = rect(100, 140, 200, 260)
    pred = rect(100, 140, 203, 263)
    assert db_eval_iou(pred, gt) == pytest.approx(57 / 63, abs=1e-12)


def test_iou_accepts_any_nonzero_dtype():
    gt = rect(1, 4, 1, 4, (6, 6)).astype(np.uint8) * 255
    pred = rect(1, 4, 1, 3, (6, 6)).astype(np.float32)
    assert db_eval_iou(pred, gt) == pytest.approx(6 / 9)


def test_iou_void_pixels_ignored():
    gt = rect(0, 4, 0, 4, (8, 8))
    pred = rect(0, 4, 0, 6, (8, 8))  # 8 extra pixels in columns 4-5
    void = rect(0, 8, 4, 8, (8, 8))
    assert db_eval_iou(pred, gt) == pytest.approx(16 / 24)
    assert db_eval_iou(pred, gt, void) == 1.0
    # everything void: both empty -> 1
    assert db_eval_iou(pred, gt, np.ones((8, 8), bool)) == 1.0


def test_iou_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="shapes differ"):
        db_eval_iou(np.zeros((4, 5)), np.zeros((5, 4)))


# ---------------------------------------------------------------------------------------------------------------
# seg2bmap and the tolerance
# ---------------------------------------------------------------------------------------------------------------
def test_seg2bmap_rectangle_hand_counted():
    # fg rows 2..4, cols 3..6 (h=3, w=4): boundary = left column c0-1 (rows r0-1..r1: h+1), top row r0-1
    # (cols c0..c1: w), right column c1 (h) and bottom row r1 (w-1) = 2h + 2w pixels
    m = rect(2, 5, 3, 7, (8, 10))
    b = seg2bmap(m)
    assert b.sum() == 2 * 3 + 2 * 4
    assert b[1:5, 2].all() and b[1, 3:7].all() and b[2:5, 6].all() and b[4, 3:6].all()
    assert not b[2:4, 3:6].any()  # interior


def test_seg2bmap_image_border_is_not_a_boundary():
    assert not seg2bmap(np.ones((5, 7), bool)).any()
    # a mask touching the right and bottom border: the border pixels themselves are not boundary
    m = rect(2, 5, 3, 7, (5, 7))
    b = seg2bmap(m)
    assert not b[-1, -1]
    assert not b[4, 6]


def test_seg2bmap_last_row_and_column_rules():
    m = np.zeros((4, 4), bool)
    m[3, 1] = True  # last row: compares east only
    b = seg2bmap(m)
    assert b[3, 0] and b[3, 1] and not b[3, 2]
    m = np.zeros((4, 4), bool)
    m[1, 3] = True  # last column: compares south only
    b = seg2bmap(m)
    assert b[0, 3] and b[1, 3] and not b[2, 3]


def test_boundary_tolerance():
    assert boundary_tolerance((480, 854)) == 8
    assert boundary_tolerance((240, 427)) == 4  # ceil(0.008 * 489.86) = ceil(3.92)
    assert boundary_tolerance((480, 854), 3) == 3
    assert boundary_tolerance((480, 854), 1.0) == 1


def test_disk_footprint():
    d = disk(2)
    expected = np.array([[0, 0, 1, 0, 0], [0, 1, 1, 1, 0], [1, 1, 1, 1, 1], [0, 1, 1, 1, 0], [0, 0, 1, 0, 0]])
    assert (d == expected).all()
    assert disk(8).sum() == sum(1 for y in range(-8, 9) for x in range(-8, 9) if x * x + y * y <= 64)


# ---------------------------------------------------------------------------------------------------------------
# F: special cases
# ---------------------------------------------------------------------------------------------------------------
def test_f_both_empty_is_one():
    empty = np.zeros((H, W), bool)
    assert boundary_precision_recall(empty, empty) == (1.0, 1.0, 1.0)


def test_f_prediction_empty():
    f, p, r = boundary_precision_recall(np.zeros((H, W), bool), rect(100, 140, 200, 260))
    assert (p, r) == (1.0, 0.0)
    assert f == 0.0


def test_f_ground_truth_empty():
    f, p, r = boundary_precision_recall(rect(100, 140, 200, 260), np.zeros((H, W), bool))
    assert (p, r) == (0.0, 1.0)
    assert f == 0.0


def test_f_prediction_without_boundary():
    # a full-frame prediction has no boundary pixel: P = 1, R = 0
    f, p, r = boundary_precision_recall(np.ones((H, W), bool), rect(100, 140, 200, 260))
    assert (f, p, r) == (0.0, 1.0, 0.0)


def test_f_both_without_boundary_is_one():
    assert db_eval_boundary(np.ones((H, W), bool), np.ones((H, W), bool)) == 1.0


def test_f_far_apart_is_zero():
    f, p, r = boundary_precision_recall(rect(10, 50, 10, 60), rect(200, 240, 400, 460))
    assert (f, p, r) == (0.0, 0.0, 0.0)


def test_f_extra_far_object_halves_precision():
    gt = rect(100, 140, 200, 260)
    pred = gt | rect(300, 340, 600, 660)  # same size, far away: half of the predicted boundary is unmatched
    f, p, r = boundary_precision_recall(pred, gt)
    assert p == 0.5 and r == 1.0
    assert f == pytest.approx(2 * 0.5 * 1.0 / 1.5)
    assert db_eval_iou(pred, gt) == pytest.approx(0.5)


# ---------------------------------------------------------------------------------------------------------------
# F: tolerance
# ---------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("shift", [1, 3, 5, 8])
def test_shift_within_tolerance_keeps_f_one_while_j_drops(shift):
    gt = rect(100, 140, 200, 260)  # 40 x 60
    pred = rect(100, 140, 200 + shift, 260 + shift)
    assert db_eval_boundary(pred, gt) == 1.0
    assert db_eval_iou(pred, gt) == pytest.approx((60 - shift) / (60 + shift), abs=1e-12)


def test_diagonal_shift_within_tolerance():
    gt = rect(100, 140, 200, 260)
    pred = rect(105, 145, 205, 265)  # 5 px down and right: sqrt(50) = 7.07 <= 8
    assert db_eval_boundary(pred, gt) == 1.0
    assert db_eval_iou(pred, gt) == pytest.approx(35 * 55 / (2 * 40 * 60 - 35 * 55), abs=1e-12)


def test_shift_beyond_tolerance_drops_f():
    gt = rect(100, 140, 200, 260)
    f9 = db_eval_boundary(rect(100, 140, 209, 269), gt)
    f20 = db_eval_boundary(rect(100, 140, 220, 280), gt)
    assert f9 < 1.0
    assert f20 < f9


def test_f_is_symmetric():
    rng = np.random.default_rng(3)
    a = ndi.gaussian_filter(rng.random((60, 80)), 3) > 0.5
    b = ndi.gaussian_filter(rng.random((60, 80)), 3) > 0.5
    fa, pa, ra = boundary_precision_recall(a, b)
    fb, pb, rb = boundary_precision_recall(b, a)
    assert fa == pytest.approx(fb) and pa == rb and ra == pb


# ---------------------------------------------------------------------------------------------------------------
# Agreement with the official code, transcribed directly (full-frame skimage-style dilation, no cropping)
# ---------------------------------------------------------------------------------------------------------------
def _official_seg2bmap(seg):
    seg = seg.astype(bool)
    e = np.zeros_like(seg)
    s = np.zeros_like(seg)
    se = np.zeros_like(seg)
    e[:, :-1] = seg[:, 1:]
    s[:-1, :] = seg[1:, :]
    se[:-1, :-1] = seg[1:, 1:]
    b = seg ^ e | seg ^ s | seg ^ se
    b[-1, :] = seg[-1, :] ^ e[-1, :]
    b[:, -1] = seg[:, -1] ^ s[:, -1]
    b[-1, -1] = 0
    return b


def _official_f(fg, gt, bound_th=0.008):
    bound_pix = bound_th if bound_th >= 1 else np.ceil(bound_th * np.linalg.norm(fg.shape))
    fb, gb = _official_seg2bmap(fg), _official_seg2bmap(gt)
    fp = ndi.binary_dilation(fb, disk(int(bound_pix)).astype(bool))
    gp = ndi.binary_dilation(gb, disk(int(bound_pix)).astype(bool))
    n_fg, n_gt = fb.sum(), gb.sum()
    if n_fg == 0 and n_gt > 0:
        p, r = 1, 0
    elif n_fg > 0 and n_gt == 0:
        p, r = 0, 1
    elif n_fg == 0 and n_gt == 0:
        p, r = 1, 1
    else:
        p, r = (fb & gp).sum() / n_fg, (gb & fp).sum() / n_gt
    return 0.0 if p + r == 0 else 2 * p * r / (p + r)


def test_matches_official_transcription_on_random_masks():
    rng = np.random.default_rng(0)
    for k in range(60):
        h, w = rng.integers(5, 90, 2)
        a = ndi.gaussian_filter(rng.random((h, w)), 2) > 0.5
        b = ndi.gaussian_filter(rng.random((h, w)), 2) > 0.5
        th = [0.008, 0.05, 2, 3][k % 4]
        assert (seg2bmap(a) == _official_seg2bmap(a)).all()
        assert db_eval_boundary(a, b, th) == pytest.approx(_official_f(a, b, th), abs=1e-12)


# ---------------------------------------------------------------------------------------------------------------
# Multi-object matrices (DAVIS-2017)
# ---------------------------------------------------------------------------------------------------------------
def test_matrices_equal_pairwise_functions_with_void():
    rng = np.random.default_rng(5)
    shape = (50, 70)
    pred = np.zeros(shape, np.uint8)
    gt = np.zeros(shape, np.uint8)
    for k in range(1, 4):
        pred[ndi.gaussian_filter(rng.random(shape), 3) > 0.55] = k
    for k in range(1, 3):
        gt[ndi.gaussian_filter(rng.random(shape), 3) > 0.55] = k
    void = np.zeros(shape, bool)
    void[:, :8] = True
    j = iou_matrix(pred, gt, 4, 2, void)  # id 4 absent in pred: an empty object
    f = boundary_f_matrix(pred, gt, 4, 2, void)
    for r in range(4):
        for c in range(2):
            assert j[r, c] == pytest.approx(db_eval_iou(pred == r + 1, gt == c + 1, void))
            assert f[r, c] == pytest.approx(db_eval_boundary(pred == r + 1, gt == c + 1, void=void))
    assert (j[3] == 0).all() and (f[3] == 0).all()
    assert not math.isnan(j.sum())


def test_f_void_removes_boundary_inside_void():
    gt = rect(10, 30, 10, 30, (48, 64))
    pred = rect(10, 30, 10, 50, (48, 64))  # extends 20 px to the right, into the void
    void = rect(0, 48, 31, 64, (48, 64))
    assert db_eval_boundary(pred, gt) < 1.0
    # with the void, the prediction is cut at column 31: its right edge is 1 px from the ground truth's
    assert db_eval_boundary(pred, gt, void=void) == 1.0
