"""Known-answer tests of the trifocal tensor functions on exact synthetic correspondences."""

from __future__ import annotations

import numpy as np
import pytest

from eponet.geometry import (
    cameras_from_trifocal,
    epipoles_from_trifocal,
    fundamentals_from_trifocal,
    hartley_normalisation,
    normalise_cameras,
    transform_trifocal,
    trifocal_from_cameras,
    trifocal_linear,
    trifocal_residual,
    trifocal_six_point,
    trifocal_transfer,
    triplet_epipolar_distance,
    triplet_sampson_error,
)
from tests.geometry.scenes import project, random_points, three_cameras


def _views(rng, n=60, kind="general"):
    cams = three_cameras(kind)
    x = random_points(rng, n)
    return [project(p, x) for p in cams], cams


def _unit(t):
    t = t / np.linalg.norm(t)
    return t * np.sign(t.ravel()[np.argmax(np.abs(t.ravel()))])


def test_tensor_from_cameras_satisfies_incidence():
    rng = np.random.default_rng(0)
    (x1, x2, x3), cams = _views(rng)
    t = trifocal_from_cameras(*normalise_cameras(*cams))
    t = t / np.linalg.norm(t)
    assert np.abs(trifocal_residual(t, x1, x2, x3)).max() < 1e-9


def test_six_point_transfers_other_points_exactly():
    rng = np.random.default_rng(1)
    (x1, x2, x3), _ = _views(rng)
    norm = [hartley_normalisation(x) for x in (x1, x2, x3)]
    tensors, valid = trifocal_six_point(*(n[0][:6] for n in norm))
    assert valid.any()
    errors = []
    for t in tensors[valid]:
        t_pix = transform_trifocal(t, *(np.linalg.inv(n[1]) for n in norm))
        errors.append(np.abs(trifocal_transfer(t_pix, x1[6:], x2[6:]) - x3[6:]).max())
    # exactly one of the (up to three) solutions is the true geometry; it transfers every other point
    assert min(errors) < 1e-6


def test_six_point_solution_matches_true_tensor_up_to_scale():
    rng = np.random.default_rng(2)
    (x1, x2, x3), cams = _views(rng)
    truth = _unit(trifocal_from_cameras(*normalise_cameras(*cams)))
    tensors, valid = trifocal_six_point(x1[:6], x2[:6], x3[:6])  # pixel coordinates work too
    assert min(np.abs(_unit(t) - truth).max() for t in tensors[valid]) < 1e-6


def test_six_point_batch_equals_single_samples():
    rng = np.random.default_rng(3)
    (x1, x2, x3), _ = _views(rng)
    idx = np.stack([rng.choice(len(x1), 6, replace=False) for _ in range(20)])
    batch, valid = trifocal_six_point(x1[idx], x2[idx], x3[idx])
    assert batch.shape == (20, 3, 3, 3, 3) and valid.shape == (20, 3)
    for b in range(20):
        single, ok = trifocal_six_point(x1[idx[b]], x2[idx[b]], x3[idx[b]])
        np.testing.assert_array_equal(ok, valid[b])
        for a, c in zip(single[ok], batch[b][valid[b]]):  # equal up to the sign SVD leaves free
            np.testing.assert_allclose(_unit(a), _unit(c), atol=1e-9)


def test_six_point_rejects_collinear_basis():
    rng = np.random.default_rng(4)
    (x1, x2, x3), _ = _views(rng)
    x1 = x1.copy()
    x1[:3] = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]  # three basis points collinear in view 1
    _, valid = trifocal_six_point(x1[:6], x2[:6], x3[:6])
    assert not valid.any()


def test_fundamentals_from_tensor_vanish_on_all_rigid_points():
    rng = np.random.default_rng(5)
    (x1, x2, x3), _ = _views(rng, n=200)
    tensors, valid = trifocal_six_point(x1[:6], x2[:6], x3[:6])
    best = None
    for t in tensors[valid]:
        f21, f31, f32 = fundamentals_from_trifocal(t)
        d = triplet_epipolar_distance(f21, f31, f32, x1, x2, x3)
        best = d if best is None or d.max() < best.max() else best
    # the six point-to-epipolar-line distances of all 200 rigid points, in pixels
    assert best.max() < 1e-6
    h = [np.c_[x, np.ones(len(x))] for x in (x1, x2, x3)]
    f21, f31, f32 = fundamentals_from_trifocal(_unit(trifocal_from_cameras(*normalise_cameras(*three_cameras()))))
    for f, a, b in ((f21, 0, 1), (f31, 0, 2), (f32, 1, 2)):
        alg = np.abs(np.einsum("ni,ij,nj->n", h[b], f, h[a]))
        assert alg.max() < 1e-9


def test_epipoles_and_cameras_from_tensor():
    cams = three_cameras()
    p2, p3 = normalise_cameras(*cams)
    t = trifocal_from_cameras(p2, p3)
    e2, e3 = epipoles_from_trifocal(t)
    centre1 = np.linalg.svd(cams[0])[2][-1]
    for e, p in ((e2, cams[1]), (e3, cams[2])):
        true = p @ centre1
        assert np.linalg.norm(np.cross(e, true / np.linalg.norm(true))) < 1e-9
    # the retrieved cameras reproduce the tensor (up to scale)
    q2, q3 = cameras_from_trifocal(t)
    assert np.abs(_unit(trifocal_from_cameras(q2, q3)) - _unit(t)).max() < 1e-9


def test_linear_fit_exact_and_noisy():
    rng = np.random.default_rng(6)
    (x1, x2, x3), _ = _views(rng, n=300)
    t = trifocal_linear(x1[:7], x2[:7], x3[:7])  # the minimum of seven triplets
    assert np.abs(trifocal_transfer(t, x1, x2) - x3).max() < 1e-6
    noisy = [x + rng.normal(0, 0.3, x.shape) for x in (x1, x2, x3)]
    t = trifocal_linear(*noisy)
    f = fundamentals_from_trifocal(t)
    err = np.sqrt(triplet_sampson_error(*f, x1, x2, x3))
    assert np.median(err) < 0.3  # fitted to noisy data, checked against the exact points
    with pytest.raises(ValueError, match="at least 7"):
        trifocal_linear(x1[:6], x2[:6], x3[:6])


def test_linear_fit_weights_select_points():
    rng = np.random.default_rng(7)
    (x1, x2, x3), _ = _views(rng, n=100)
    bad = x3.copy()
    bad[:30] += rng.normal(0, 20, (30, 2))
    w = np.r_[np.zeros(30), np.ones(70)]
    t = trifocal_linear(x1, x2, bad, w)
    assert np.abs(trifocal_transfer(t, x1[30:], x2[30:]) - x3[30:]).max() < 1e-6


def test_linear_fit_normal_matrix_is_the_incidence_rows_gram():
    # the linear fit's normal matrix is formed from per-point Kronecker factors, not from the 4N x 27 rows: the
    # same matrix (weighted), and the same tensor as the rows' smallest right singular vector
    from eponet.geometry.trifocal import _incidence_normal, _incidence_rows

    rng = np.random.default_rng(8)
    (x1, x2, x3), _ = _views(rng, n=200)
    x1, x2, x3 = (x + rng.normal(0, 0.5, x.shape) for x in (x1, x2, x3))
    w = rng.uniform(0, 2, len(x1))
    rows = (_incidence_rows(x1, x2, x3) * np.sqrt(w)[:, None, None]).reshape(-1, 27)
    expected = rows.T @ rows
    assert np.abs(_incidence_normal(x1, x2, x3, w) - expected).max() < 1e-9 * np.abs(expected).max()
    t = trifocal_linear(x1, x2, x3, enforce=False)
    (n1, s1), (n2, s2), (n3, s3) = (hartley_normalisation(x) for x in (x1, x2, x3))
    v = np.linalg.svd(_incidence_rows(n1, n2, n3).reshape(-1, 27))[2][-1].reshape(3, 3, 3)
    v = transform_trifocal(v, np.linalg.inv(s1), np.linalg.inv(s2), np.linalg.inv(s3))
    v /= np.linalg.norm(v)
    assert min(np.abs(t - v).max(), np.abs(t + v).max()) < 1e-9


def test_transform_roundtrip():
    rng = np.random.default_rng(8)
    t = rng.normal(size=(3, 3, 3))
    hs = [rng.normal(size=(3, 3)) for _ in range(3)]
    back = transform_trifocal(transform_trifocal(t, *hs), *(np.linalg.inv(h) for h in hs))
    np.testing.assert_allclose(back, t, atol=1e-9)
