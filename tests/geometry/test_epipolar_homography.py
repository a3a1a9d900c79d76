"""Known answers for epipolar distances, fundamental matrices from cameras, and homographies."""

from __future__ import annotations

import numpy as np

from eponet.geometry import (
    epipolar_line_distances,
    fundamental_from_cameras,
    hartley_normalisation,
    homography_dlt,
    homography_four_point,
    homography_triplet_distance,
    homography_triplet_error_sq,
    point_line_distance,
    sampson_error,
    skew,
    static_fundamentals,
    symmetric_epipolar_distance,
    transfer,
    transfer_error_sq,
    triplet_epipolar_distance,
)
from tests.geometry.scenes import project, random_points, three_cameras


def test_skew_is_cross_product():
    rng = np.random.default_rng(0)
    v, u = rng.normal(size=(2, 5, 3))
    np.testing.assert_allclose(skew(v) @ u[..., None], np.cross(v, u)[..., None], atol=1e-12)


def test_point_line_distance_known_answer():
    # line x = 2 (1, 0, -2): the point (5, 7) is 3 px away; scaling the line changes nothing
    assert point_line_distance(np.array([[5.0, 7.0]]), np.array([[2.0, 0.0, -4.0]]))[0] == 3.0
    assert np.isinf(point_line_distance(np.array([[1.0, 1.0]]), np.array([[0.0, 0.0, 1.0]]))[0])


def test_fundamental_from_cameras_and_distances():
    rng = np.random.default_rng(1)
    cams = three_cameras()
    x = random_points(rng, 100)
    x1, x2 = project(cams[0], x), project(cams[1], x)
    f = fundamental_from_cameras(cams[0], cams[1])
    d2, d1 = epipolar_line_distances(x1, x2, f)
    assert max(d1.max(), d2.max()) < 1e-8
    assert sampson_error(x1, x2, f).max() < 1e-16
    # moving x2 by 2 px along the normal of its epipolar line gives a distance of exactly 2 px
    line = np.c_[x1, np.ones(100)] @ f.T
    normal = line[:, :2] / np.linalg.norm(line[:, :2], axis=1, keepdims=True)
    d2, _ = epipolar_line_distances(x1, x2 + 2 * normal, f)
    np.testing.assert_allclose(d2, 2.0, atol=1e-8)
    # batched matrices broadcast to (K, N)
    assert symmetric_epipolar_distance(x1, x2, np.stack([f, f, f])).shape == (3, 100)


def test_static_fundamentals_zero_for_static_points_only():
    rng = np.random.default_rng(2)
    x = rng.uniform(0, 300, (50, 2))
    f21, f31, f32 = static_fundamentals()
    assert triplet_epipolar_distance(f21, f31, f32, x, x, x).max() == 0.0
    # any motion is seen: horizontal, vertical, diagonal
    for step in ([3.0, 0.0], [0.0, 3.0], [2.0, 2.0], [2.0, -2.0]):
        d = triplet_epipolar_distance(f21, f31, f32, x, x + step, x + 2 * np.array(step))
        assert d.min() > 1.0


def test_homography_four_point_and_dlt():
    rng = np.random.default_rng(3)
    h = np.array([[1.02, 0.03, 4.0], [-0.02, 0.98, -3.0], [1e-4, -5e-5, 1.0]])
    x1 = rng.uniform(0, 400, (40, 2))
    x2 = transfer(h, x1)
    hs, ok = homography_four_point(x1[None, :4], x2[None, :4])
    assert ok.all()
    assert transfer_error_sq(hs[0], x1, x2).max() < 1e-16
    hd = homography_dlt(x1, x2)
    assert transfer_error_sq(hd, x1, x2).max() < 1e-16
    # collinear samples are flagged
    col = np.array([[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [5.0, 1.0]]])
    assert not homography_four_point(col, col)[1][0]


def test_homography_triplet_residuals():
    rng = np.random.default_rng(4)
    h21 = np.array([[1.0, 0.01, 2.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
    h31 = h21 @ h21
    x1 = rng.uniform(0, 300, (30, 2))
    x2, x3 = transfer(h21, x1), transfer(h31, x1)
    assert homography_triplet_distance(h21, h31, x1, x2, x3).max() < 1e-9
    assert homography_triplet_error_sq(h21, h31, x1, x2, x3).max() < 1e-18
    # a point displaced by 1 px in view 3 only: 4 of the 6 transfers see ~1 px
    d = homography_triplet_distance(h21, h31, x1, x2, x3 + [1.0, 0.0])
    np.testing.assert_allclose(d, 4.0, atol=0.05)


def test_hartley_normalisation():
    rng = np.random.default_rng(5)
    x = rng.uniform(100, 500, (100, 2))
    xn, t = hartley_normalisation(x)
    np.testing.assert_allclose(xn.mean(0), 0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(xn, axis=1).mean(), np.sqrt(2))
    np.testing.assert_allclose((np.c_[x, np.ones(100)] @ t.T)[:, :2], xn, atol=1e-12)


def test_distances_over_many_points_are_computed_block_by_block_with_the_same_values():
    """The per-point kernels run in blocks of ``BLOCK`` points (cache-sized); every point's distance is the one it
    gets alone, whatever block it falls in, in float32 and float64, and a point at an epipole or mapped to infinity
    is inf."""
    from eponet.geometry.homography import BLOCK

    rng = np.random.default_rng(6)
    f21, f31, f32 = rng.normal(size=(3, 3, 3))
    h21, h31 = np.eye(3) + 0.05 * rng.normal(size=(2, 3, 3))
    n = 2 * BLOCK + 7
    for dtype in (np.float32, np.float64):
        x1 = rng.uniform(0, 800, (n, 2)).astype(dtype)
        x2, x3 = (x1 + rng.normal(0, 3, (2, n, 2))).astype(dtype)
        x1[BLOCK] = np.nan
        probe = [0, BLOCK - 1, BLOCK, BLOCK + 1, n - 1]
        for fn, mats in ((triplet_epipolar_distance, (f21, f31, f32)), (homography_triplet_distance, (h21, h31))):
            d = fn(*mats, x1, x2, x3)
            assert d.dtype == dtype and d.shape == (n,) and d[BLOCK] == np.inf
            alone = np.concatenate([fn(*mats, x1[i : i + 1], x2[i : i + 1], x3[i : i + 1]) for i in probe])
            np.testing.assert_array_equal(d[probe], alone)
        assert triplet_epipolar_distance(f21, f31, f32, x1[:0], x2[:0], x3[:0]).shape == (0,)
