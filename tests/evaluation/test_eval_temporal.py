"""Temporal stability T: contours, descriptors, matching, and the measure itself on synthetic shapes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from eponet.evaluation import metrics
from eponet.evaluation.contours import contour_upsample, longest_contour, mask_contours
from eponet.evaluation.temporal import chi2_cost, db_eval_t, match_contours, shape_context


def ellipse(shape, centre, axes, angle=0.0):
    yy, xx = np.mgrid[: shape[0], : shape[1]].astype(float)
    x, y = xx - centre[0], yy - centre[1]
    c, s = math.cos(angle), math.sin(angle)
    u, v = c * x + s * y, -s * x + c * y
    return (u / axes[0]) ** 2 + (v / axes[1]) ** 2 <= 1.0


def signed_area(poly):
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]))


# ---------------------------------------------------------------------------------------------------------------
# Contours
# ---------------------------------------------------------------------------------------------------------------
def test_rectangle_contour_is_its_four_pixel_corners():
    m = np.zeros((10, 12), bool)
    m[2:5, 3:7] = True  # rows 2..4, cols 3..6 -> corners x in {3, 7}, y in {2, 5}
    (cont,) = mask_contours(m)
    assert (cont[0] == cont[-1]).all()
    assert sorted(map(tuple, cont[:-1].tolist())) == [(3, 2), (3, 5), (7, 2), (7, 5)]


def test_hole_gives_a_second_contour_of_opposite_orientation():
    m = np.zeros((20, 20), bool)
    m[3:15, 3:15] = True
    m[6:10, 6:10] = False
    conts = mask_contours(m)
    assert len(conts) == 2
    areas = sorted(signed_area(c) for c in conts)
    assert areas[0] * areas[1] < 0
    assert sorted(abs(a) for a in areas) == [16.0, 144.0]


def test_single_pixels_are_dropped_and_diagonal_pixels_join():
    m = np.zeros((10, 10), bool)
    m[2, 2] = True
    assert mask_contours(m) == []
    assert mask_contours(np.zeros((5, 5), bool)) == []
    # two 3x3 blocks touching at a corner form one 8-connected region: one contour
    m = np.zeros((12, 12), bool)
    m[2:5, 2:5] = True
    m[5:8, 5:8] = True
    assert len(mask_contours(m)) == 1


def test_simplification_tolerance_is_one_and_a_half_pixels():
    m = ellipse((200, 300), (150, 100), (80, 50))
    (cont,) = mask_contours(m)
    # psimpl drops points within the tolerance of the last kept one, then runs Douglas-Peucker with the same
    # tolerance: every crack-contour corner lies within 2 x 1.5 px of the simplified polygon
    assert 8 < len(cont) < 80
    (fine,) = mask_contours(m, tolerance=0.0)
    seg_a, seg_b = cont[:-1], cont[1:]
    d = np.min(
        [_point_segment_distance(fine[:-1], a, b) for a, b in zip(seg_a, seg_b)], axis=0)
    assert d.max() <= 3.0 + 1e-9
    assert len(fine) > 3 * len(cont)


def _point_segment_distance(p, a, b):
    ab = b - a
    denom = float(ab @ ab)
    t = np.clip(((p - a) @ ab) / denom, 0, 1) if denom else np.zeros(len(p))
    return np.hypot(*(p - (a + t[:, None] * ab)).T)


def test_longest_contour_counts_vertices_first_on_ties():
    a = np.zeros((5, 2))
    b = np.ones((5, 2))
    c = np.ones((7, 2))
    assert longest_contour([a, b]) is a
    assert longest_contour([a, c, b]) is c


def test_contour_upsample_limits_segment_length():
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], float)
    up = contour_upsample(square, 3.0)
    steps = np.hypot(*np.diff(up, axis=0).T)
    assert steps.max() <= 3.0 + 1e-12
    # each 10 px side gets ceil(10/3) = 4 segments; the closing duplicate of the first point is kept
    assert len(up) == 4 * 4 + 1
    assert (up[0] == up[-1]).all()


# ---------------------------------------------------------------------------------------------------------------
# Descriptors and cost
# ---------------------------------------------------------------------------------------------------------------
def test_shape_context_counts_points_within_two_mean_distances():
    pts = np.array([[0, 0], [1, 0], [0, 1], [1, 1], [30, 30]], float)
    h = shape_context(pts)
    assert h.shape == (5, 60)
    # the far point is beyond 2 mean distances of the cluster points; each point counts itself
    assert h[:4].sum(axis=1).tolist() == [4, 4, 4, 4]
    assert h[4].sum() == 1


def test_chi2_cost_equals_direct_formula():
    rng = np.random.default_rng(2)
    a = rng.integers(0, 5, (30, 60)) * (rng.random((30, 60)) < 0.4)
    b = rng.integers(0, 5, (25, 60)) * (rng.random((25, 60)) < 0.4)
    eps = 2.2204e-16
    an = a / (a.sum(1, keepdims=True) + eps)
    bn = b / (b.sum(1, keepdims=True) + eps)
    direct = 0.5 * (((an[:, None] - bn[None]) ** 2) / (an[:, None] + bn[None] + eps)).sum(2)
    assert np.allclose(chi2_cost(a, b), direct, atol=1e-12)
    assert np.allclose(np.diag(chi2_cost(a, a)), 0.0, atol=1e-12)


def test_matching_recovers_a_cyclic_shift():
    n = 40
    cost = np.ones((n, n))
    cost[np.arange(n), (np.arange(n) + 7) % n] = 0.0
    pairs = match_contours(cost)
    assert len(pairs) == n
    assert cost[pairs[:, 0], pairs[:, 1]].sum() == 0.0
    assert len(set(pairs[:, 0].tolist())) == n and len(set(pairs[:, 1].tolist())) == n


def test_matching_is_order_preserving_and_bijective():
    rng = np.random.default_rng(1)
    cost = rng.random((25, 31))
    pairs = match_contours(cost)
    assert len(set(pairs[:, 0].tolist())) == len(pairs)
    assert len(set(pairs[:, 1].tolist())) == len(pairs)


# ---------------------------------------------------------------------------------------------------------------
# T
# ---------------------------------------------------------------------------------------------------------------
SHAPE = (240, 320)


def test_t_is_zero_for_identical_masks():
    m = ellipse(SHAPE, (160, 120), (70, 45), 0.3)
    assert db_eval_t(m, m) == pytest.approx(0.0, abs=1e-12)


def test_t_is_zero_for_a_translated_mask():
    m = ellipse(SHAPE, (150, 120), (70, 45), 0.3)
    moved = np.roll(np.roll(m, 9, axis=1), -4, axis=0)
    assert db_eval_t(m, moved) == pytest.approx(0.0, abs=1e-12)


def test_t_grows_with_deformation():
    circle = ellipse(SHAPE, (160, 120), (60, 60))
    slightly = ellipse(SHAPE, (160, 120), (66, 55))
    strongly = ellipse(SHAPE, (160, 120), (95, 38))
    t1 = db_eval_t(circle, slightly)
    t2 = db_eval_t(circle, strongly)
    assert 0.0 < t1 < t2
    # a non-convex deformation (a notch) is unstable too
    notched = circle.copy()
    notched[100:140, 150:230] = False
    assert db_eval_t(circle, notched) > t1


def test_t_is_nan_without_contour():
    m = ellipse(SHAPE, (160, 120), (60, 60))
    empty = np.zeros(SHAPE, bool)
    assert math.isnan(db_eval_t(m, empty))
    assert math.isnan(db_eval_t(empty, empty))
    dot = np.zeros(SHAPE, bool)
    dot[5, 5] = True
    assert math.isnan(db_eval_t(dot, m))


def test_metrics_re_exports_temporal_stability():
    """``eponet.evaluation.metrics`` keeps every measure's name: T's functions are the temporal module's."""
    assert metrics.db_eval_t is db_eval_t and metrics.mask_contours is mask_contours
    assert set(metrics.__all__) >= {"db_eval_t", "T_SCALE", "shape_context", "match_contours"}
