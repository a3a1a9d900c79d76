"""The trifocal tensor: six-point and linear estimation, fundamental matrices and cameras from it, transfer.

Tensor convention ([HZ] Ch. 15): an array ``T`` of shape ``(3, 3, 3)`` with ``T[i]`` the matrix ``T_i`` and
``T[i, j, k] = T_i^{jk}``; ``j`` indexes view 2 and ``k`` view 3. For cameras ``P1 = [I | 0]``,
``P2 = [a_1 a_2 a_3 | a_4]`` and ``P3 = [b_1 b_2 b_3 | b_4]``, ``T_i = a_i b_4^T - a_4 b_i^T`` ([HZ] eq. 15.1).
A point triplet satisfies ``[x2]x (sum_i x1^i T_i) [x3]x = 0_3x3`` ([HZ] Table 15.1). Every function takes
and returns float64 and broadcasts over leading batch axes unless stated otherwise.

References
----------
.. [HZ] R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2003.
.. [Q] L. Quan, "Invariants of six points and projective reconstruction from three uncalibrated images",
   IEEE PAMI 17(1), 1995 (the six-point problem; [HZ] Sec. 20.2.4 solves it through Carlsson-Weinshall duality).
"""

from __future__ import annotations

import numpy as np

from .epipolar import (
    fundamental_from_cameras,
    homogeneous,
    null_vector,
    rank2_null_vector,
    sampson_error,
    skew,
)
from .homography import _basis, _in_blocks
from .normalise import hartley_normalisation

__all__ = [
    "trifocal_from_cameras",
    "normalise_cameras",
    "trifocal_six_point",
    "trifocal_linear",
    "transform_trifocal",
    "epipoles_from_trifocal",
    "fundamentals_from_trifocal",
    "cameras_from_trifocal",
    "trifocal_transfer",
    "trifocal_residual",
    "triplet_epipolar_distance",
    "triplet_sampson_error",
]

# Reduced camera of the dual "view" of the 3-D point (1, 1, 1, 1): x = (a + d, b + d, c + d).
_M5 = np.array([[1.0, 0, 0, 1], [0, 1.0, 0, 1], [0, 0, 1.0, 1]])


def trifocal_from_cameras(p2: np.ndarray, p3: np.ndarray) -> np.ndarray:
    """Trifocal tensor of cameras ``P1 = [I | 0]``, ``P2``, ``P3`` ([HZ] eq. 15.1).

    Parameters
    ----------
    p2, p3 : array (..., 3, 4)

    Returns
    -------
    array (..., 3, 3, 3)
        ``T_i = a_i b_4^T - a_4 b_i^T``, not rescaled.
    """
    p2 = np.asarray(p2, dtype=np.float64)
    p3 = np.asarray(p3, dtype=np.float64)
    a, a4 = p2[..., :3], p2[..., 3]
    b, b4 = p3[..., :3], p3[..., 3]
    # T[i, j, k] = a[j, i] b4[k] - a4[j] b[k, i]
    return np.einsum("...ji,...k->...ijk", a, b4) - np.einsum("...j,...ki->...ijk", a4, b)


def normalise_cameras(p1: np.ndarray, p2: np.ndarray, p3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Apply the 3-D projective map that takes ``P1`` to ``[I | 0]``; returns the new ``(P2, P3)``.

    Requires the left 3x3 block of ``P1`` to be invertible (a finite camera in the working frame).
    """
    m, c = p1[..., :3], p1[..., 3:]
    minv = np.linalg.inv(m)
    h = np.zeros(p1.shape[:-2] + (4, 4))
    h[..., :3, :3] = minv
    h[..., :3, 3:] = -minv @ c
    h[..., 3, 3] = 1.0
    return p2 @ h, p3 @ h


def _real_cubic_roots(coef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Roots of cubics ``coef[..., 0] r^3 + ... + coef[..., 3]`` (leading coefficient not 0): (..., 3) real
    parts and a mask of the (numerically) real ones."""
    lead = coef[..., :1]
    c = -coef[..., 1:] / lead
    comp = np.zeros(coef.shape[:-1] + (3, 3))
    comp[..., 0, :] = c
    comp[..., 1, 0] = comp[..., 2, 1] = 1.0
    comp = np.where(np.isfinite(comp), comp, 0.0)
    roots = np.linalg.eigvals(comp)
    real = np.abs(roots.imag) <= 1e-7 * np.maximum(1.0, np.abs(roots.real))
    return roots.real, real & np.isfinite(lead)


def trifocal_six_point(x1: np.ndarray, x2: np.ndarray, x3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Trifocal tensors through six point triplets: the six-point algorithm ([HZ] Algorithm 20.1, p. 511).

    The first four points of each sample are the projective basis: in every view they are mapped to
    ``e1, e2, e3, (1, 1, 1)`` and in space they are ``E1 .. E4``; the fifth point is ``(1, 1, 1, 1)``. By
    Carlsson-Weinshall duality the two remaining points become two dual "views" whose reduced fundamental
    matrix (zero diagonal, entries summing to zero) has six unknowns and one constraint per camera; its
    two-dimensional solution family and ``det F = 0`` give a cubic, so up to three solutions ([HZ] Sec. 20.2).
    From each dual fundamental matrix the sixth 3-D point follows from its two epipoles, the three reduced
    cameras from the images of the fifth and sixth points, and the tensor from the cameras ([HZ] eq. 15.1).

    Batched over samples; pass Hartley-normalised coordinates for good conditioning.

    Parameters
    ----------
    x1, x2, x3 : array (B, 6, 2) or (6, 2)
        The six correspondences in views 1, 2, 3.

    Returns
    -------
    T : array (B, 3, 3, 3, 3) (or (3, 3, 3, 3) for one sample)
        Up to three tensors per sample (axis 1), in the input coordinates, unit Frobenius norm.
    valid : bool array (B, 3) (or (3,))
        Which of the three are real solutions; all False when the sample is degenerate (three basis points
        collinear in a view, a repeated point, a sixth point at infinity in the projective basis ...).

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> X = np.c_[rng.normal(size=(6, 3)) + [0, 0, 6], np.ones(6)]
    >>> P = [np.eye(3, 4), np.c_[np.eye(3), [-1.0, 0, 0]], np.c_[np.eye(3), [0, -1.0, 0]]]
    >>> x = [(X @ p.T)[:, :2] / (X @ p.T)[:, 2:] for p in P]
    >>> T, valid = trifocal_six_point(*x)
    >>> bool(valid.any())
    True
    """
    single = np.ndim(x1) == 2
    xs = [np.asarray(x, dtype=np.float64).reshape(-1, 6, 2) for x in (x1, x2, x3)]
    nb = xs[0].shape[0]
    valid = np.ones(nb, bool)
    bases, p4, p5 = [], [], []
    for x in xs:
        # every triple of the four basis points must be non-collinear: check all four determinants
        h = homogeneous(x)
        for tri in ((0, 1, 2), (0, 1, 3), (0, 2, 3), (1, 2, 3)):
            valid &= np.abs(np.linalg.det(h[:, tri, :])) > 1e-8
        a, _ = _basis(x[:, :4])
        a = np.where(valid[:, None, None], a, np.eye(3))
        ainv = np.linalg.inv(a)
        bases.append(a)
        p4.append(np.einsum("bij,bj->bi", ainv, h[:, 4]))
        p5.append(np.einsum("bij,bj->bi", ainv, h[:, 5]))
    # Dual reduced fundamental matrix: q^T F p = 0 for (p, q) = images of points 5 and 6 in each view, plus
    # sum(F) = 0 (the point (1,1,1) <-> (1,1,1)); unknowns are the off-diagonal entries in row-major order.
    off = [(0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1)]
    rows = [np.stack([q[:, r] * p[:, c] for r, c in off], 1) for p, q in zip(p4, p5)]
    rows.append(np.ones((nb, 6)))
    a_mat = np.stack(rows, 1)  # (B, 4, 6)
    a_mat = a_mat / np.linalg.norm(a_mat, axis=-1, keepdims=True)
    _, _, vt = np.linalg.svd(a_mat)
    f1 = np.zeros((nb, 3, 3))
    f2 = np.zeros((nb, 3, 3))
    for n, (r, c) in enumerate(off):
        f1[:, r, c] = vt[:, 4, n]
        f2[:, r, c] = vt[:, 5, n]
    # det(mu f1 + lam f2) is a homogeneous cubic; fit its coefficients from 4 samples and solve it in the
    # better conditioned of lam/mu.
    lam = np.array([0.0, 1.0, -1.0, 2.0])
    dets = np.linalg.det(f1[:, None] + lam[None, :, None, None] * f2[:, None])  # (B, 4)
    coef = np.linalg.solve(np.vander(lam, 4), dets.T).T  # c3, c2, c1, c0 (highest power first)
    use_lam = np.abs(coef[:, 0]) >= np.abs(coef[:, 3])
    poly = np.where(use_lam[:, None], coef, coef[:, ::-1])
    roots, real = _real_cubic_roots(poly)
    fd = np.where(
        use_lam[:, None, None, None],
        f1[:, None] + roots[..., None, None] * f2[:, None],
        roots[..., None, None] * f1[:, None] + f2[:, None],
    )  # (B, 3, 3, 3)
    e = rank2_null_vector(fd)  # right null vector: epipole in the dual view of point 5
    ep = rank2_null_vector(np.swapaxes(fd, -1, -2))  # left null vector: epipole in the dual view of point 6
    # Sixth point (X, Y, Z, 1): X_i = 1 + s e'_i and 1/X_i - 1 = t e_i, i.e. s e'_i + t e_i + st e_i e'_i = 0.
    m = np.stack([ep, e, e * ep], -1)
    v = rank2_null_vector(m)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = v[..., 2] / v[..., 1]
    x6 = np.concatenate([1.0 + s[..., None] * ep, np.ones(s.shape + (1,))], -1)  # (B, 3, 4)
    x6 = np.where(np.isfinite(x6), x6, 1.0)
    m6 = np.zeros(x6.shape[:-1] + (3, 4))
    for i in range(3):
        m6[..., i, i] = x6[..., i]
        m6[..., i, 3] = x6[..., 3]
    cams = []
    for view in range(3):
        sp = skew(p4[view])[:, None]  # (B, 1, 3, 3)
        sq = skew(p5[view])[:, None]
        sys_ = np.concatenate([np.broadcast_to(sp @ _M5, m6.shape), sq @ m6], -2)  # (B, 3, 6, 4)
        abcd = null_vector(sys_)  # (B, 3, 4)
        reduced = np.zeros(abcd.shape[:-1] + (3, 4))
        for i in range(3):
            reduced[..., i, i] = abcd[..., i]
            reduced[..., i, 3] = abcd[..., 3]
        cams.append(bases[view][:, None] @ reduced)
    ok = valid[:, None] & real & np.isfinite(s) & (np.abs(np.linalg.det(cams[0][..., :3])) > 1e-12)
    safe = [np.where(ok[..., None, None], c, np.eye(3, 4)) for c in cams]
    p2n, p3n = normalise_cameras(*safe)
    t = trifocal_from_cameras(p2n, p3n)
    norm = np.linalg.norm(t.reshape(t.shape[:-3] + (27,)), axis=-1)
    ok &= np.isfinite(norm) & (norm > 0)
    t = np.where(ok[..., None, None, None], t / np.where(ok, norm, 1.0)[..., None, None, None], 0.0)
    if single:
        return t[0], ok[0]
    return t, ok


def transform_trifocal(t: np.ndarray, h1: np.ndarray, h2: np.ndarray, h3: np.ndarray) -> np.ndarray:
    """The tensor in new image coordinates ``x1' = h1 x1``, ``x2' = h2 x2``, ``x3' = h3 x3`` ([HZ] Sec. 15.1.3).

    ``T'_i^{jk} = (h1^-1)^r_i h2^j_s h3^k_t T_r^{st}``: covariant in the first index, contravariant in the
    other two. To denormalise a tensor estimated in Hartley coordinates ``x_hat = N x`` pass
    ``inv(N1), inv(N2), inv(N3)`` ([HZ] Algorithm 16.1 step (iii)).
    """
    return np.einsum("...ri,...js,...kt,...rst->...ijk", np.linalg.inv(h1), h2, h3, t)


def epipoles_from_trifocal(t: np.ndarray, *, exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Epipoles ``e2`` (of camera 1 in view 2) and ``e3`` (in view 3) of a tensor ([HZ] Algorithm 15.1 (i)).

    ``e2`` is the common perpendicular of the left null vectors of the ``T_i``, ``e3`` that of the right null
    vectors. Returns unit vectors, each (..., 3). Least squares (SVD) by default; ``exact=True`` uses cross
    products, exact and faster for geometrically valid tensors (e.g. from the six-point solver).
    """
    if exact:
        left = rank2_null_vector(np.swapaxes(t, -1, -2))
        right = rank2_null_vector(t)
        return rank2_null_vector(left), rank2_null_vector(right)
    u, _, vt = np.linalg.svd(t)  # per T_i
    left = u[..., :, 2]  # (..., 3 (i), 3)
    right = vt[..., 2, :]
    return null_vector(left), null_vector(right)


def fundamentals_from_trifocal(t: np.ndarray, *, exact: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``F21, F31, F32`` from a trifocal tensor ([HZ] Algorithm 15.1).

    ``F21 = [e2]x [T1, T2, T3] e3``, ``F31 = [e3]x [T1^T, T2^T, T3^T] e2``, and ``F32`` from the cameras of
    :func:`cameras_from_trifocal`. The paper's other three are the transposes (``F12 = F21^T`` ...).
    Each has unit Frobenius norm and satisfies ``x_b^T F_ba x_a = 0``.

    Parameters
    ----------
    t : array (..., 3, 3, 3)
    exact : bool
        See :func:`epipoles_from_trifocal`.

    Returns
    -------
    F21, F31, F32 : arrays (..., 3, 3)
    """
    e2, e3 = epipoles_from_trifocal(t, exact=exact)
    f21 = skew(e2) @ np.swapaxes(_t_times_e3(t, e3), -1, -2)
    f31 = skew(e3) @ np.swapaxes(_tt_times_e2(t, e2), -1, -2)
    p2, p3 = _cameras(t, e2, e3)
    f32 = fundamental_from_cameras(p2, p3)
    f21 = f21 / np.linalg.norm(f21, axis=(-2, -1), keepdims=True)
    f31 = f31 / np.linalg.norm(f31, axis=(-2, -1), keepdims=True)
    return f21, f31, f32


def _t_times_e3(t: np.ndarray, e3: np.ndarray) -> np.ndarray:
    """Rows i: T_i e3, shape (..., 3, 3)."""
    return (t @ e3[..., None, :, None])[..., 0]


def _tt_times_e2(t: np.ndarray, e2: np.ndarray) -> np.ndarray:
    """Rows i: T_i^T e2, shape (..., 3, 3)."""
    return (np.swapaxes(t, -1, -2) @ e2[..., None, :, None])[..., 0]


def _cameras(t: np.ndarray, e2: np.ndarray, e3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.swapaxes(_t_times_e3(t, e3), -1, -2)  # columns T_i e3
    b = np.swapaxes(_tt_times_e2(t, e2), -1, -2)  # columns T_i^T e2
    b = (e3[..., :, None] * e3[..., None, :] - np.eye(3)) @ b
    return np.concatenate([a, e2[..., None]], -1), np.concatenate([b, e3[..., None]], -1)


def cameras_from_trifocal(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cameras ``P2 = [[T1, T2, T3] e3 | e2]`` and ``P3 = [(e3 e3^T - I)[T1^T, T2^T, T3^T] e2 | e3]`` with
    ``P1 = [I | 0]`` ([HZ] Algorithm 15.1 (iii)); each (..., 3, 4)."""
    e2, e3 = epipoles_from_trifocal(t)
    return _cameras(t, e2, e3)


def _incidence_rows(x1: np.ndarray, x2: np.ndarray, x3: np.ndarray) -> np.ndarray:
    """The four independent point-point-point equations per triplet as rows (N, 4, 27) acting on T.ravel()."""
    h1, h2, h3 = homogeneous(x1), homogeneous(x2), homogeneous(x3)
    s2 = skew(h2)[:, :2]  # rows s = 0, 1 of [x2]x: (N, s, q)
    s3 = skew(h3)[:, :, :2]  # columns t = 0, 1 of [x3]x: (N, r, t)
    # rows[n, s, t, i, q, r] = x1[n, i] s2[n, s, q] s3[n, r, t], by broadcasting (einsum is slow here)
    rows = (
        h1[:, None, None, :, None, None]
        * s2[:, :, None, None, :, None]
        * np.swapaxes(s3, 1, 2)[:, None, :, None, None, :]
    )
    return rows.reshape(len(h1), 4, 27)


def _skew_gram(x: np.ndarray) -> np.ndarray:
    """``sum_s r_s r_s^T`` over the two rows ``r_s`` of ``[x]x`` (equally its first two columns) for points
    ``x`` (N, 2) with ``w = 1``: ``[[1, 0, -u], [0, 1, -v], [-u, -v, u^2 + v^2]]`` per point, (N, 3, 3)."""
    m = np.zeros((len(x), 3, 3))
    m[:, 0, 0] = m[:, 1, 1] = 1.0
    m[:, 0, 2] = m[:, 2, 0] = -x[:, 0]
    m[:, 1, 2] = m[:, 2, 1] = -x[:, 1]
    m[:, 2, 2] = x[:, 0] ** 2 + x[:, 1] ** 2
    return m


def _incidence_normal(x1: np.ndarray, x2: np.ndarray, x3: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """``A^T W A`` (27, 27) of the stacked incidence rows ``A`` of :func:`_incidence_rows`, without forming ``A``.

    A point's four rows are ``x1 (x) r_s (x) c_t`` (Kronecker products; ``r_s`` rows of ``[x2]x``, ``c_t``
    columns of ``[x3]x``, s, t in {0, 1}), so their Gram sum factorises into ``x1 x1^T (x) G(x2) (x) G(x3)``
    with :func:`_skew_gram`: about 4x faster than the rows for a few thousand points, the same to rounding.
    """
    n = len(x1)
    h1 = homogeneous(x1)
    a = (h1 if weights is None else h1 * weights[:, None])[:, :, None] * h1[:, None, :]  # (N, i, j)
    b, c = _skew_gram(x2), _skew_gram(x3)  # (N, q, p), (N, r, u)
    ab = (a[:, :, None, :, None] * b[:, None, :, None, :]).reshape(n, 81)  # (N, (i, q, j, p))
    m = (ab.T @ c.reshape(n, 9)).reshape(3, 3, 3, 3, 3, 3)  # (i, q, j, p, r, u)
    return m.transpose(0, 1, 4, 2, 3, 5).reshape(27, 27)


def trifocal_residual(t: np.ndarray, x1: np.ndarray, x2: np.ndarray, x3: np.ndarray) -> np.ndarray:
    """Algebraic residual ``[x2]x (sum_i x1^i T_i) [x3]x`` (the 4 independent entries) per triplet: (N, 4)."""
    return _incidence_rows(x1, x2, x3) @ np.asarray(t, dtype=np.float64).reshape(27)


def trifocal_linear(
    x1: np.ndarray,
    x2: np.ndarray,
    x3: np.ndarray,
    weights: np.ndarray | None = None,
    *,
    enforce: bool = True,
) -> np.ndarray:
    """Trifocal tensor from N >= 7 point triplets: the normalised linear algorithm ([HZ] Algorithm 16.1).

    Each view is Hartley-normalised, the 4N x 27 system of point-point-point incidences is solved in the
    least-squares sense (the smallest eigenvector of its 27 x 27 normal matrix, :func:`_incidence_normal`), and
    with ``enforce`` the result is made geometrically valid by algebraic minimisation with the epipoles
    of the linear solution held fixed ([HZ] Algorithm 16.2 without the final Levenberg-Marquardt over the
    epipoles; [HZ] Algorithm A5.6). The tensor is denormalised to pixel coordinates.

    Parameters
    ----------
    x1, x2, x3 : array (N, 2)
        Pixel coordinates in the three views.
    weights : array (N,), optional
        Non-negative weights (e.g. inlier flags).

    Returns
    -------
    array (3, 3, 3)
        The tensor in pixel coordinates, unit Frobenius norm.
    """
    if weights is not None:
        keep = np.asarray(weights) > 0
        x1, x2, x3, weights = x1[keep], x2[keep], x3[keep], np.asarray(weights, dtype=np.float64)[keep]
    if len(x1) < 7:
        raise ValueError(f"trifocal_linear: need at least 7 point triplets, got {len(x1)}")
    (n1, t1), (n2, t2), (n3, t3) = (hartley_normalisation(x) for x in (x1, x2, x3))
    ata = _incidence_normal(n1, n2, n3, weights)
    _, vec = np.linalg.eigh(ata)
    t = vec[:, 0].reshape(3, 3, 3)
    if enforce:
        e2, e3 = epipoles_from_trifocal(t)
        # t = E p with p = (A (3x3, entries a[j, i]), B (3x3, entries b[k, i])): T_ijk = A_ji e3_k - e2_j B_ki
        e = np.zeros((3, 3, 3, 18))
        for i in range(3):
            for j in range(3):
                for k in range(3):
                    e[i, j, k, j * 3 + i] += e3[k]
                    e[i, j, k, 9 + k * 3 + i] -= e2[j]
        e = e.reshape(27, 18)
        u, s, _ = np.linalg.svd(e, full_matrices=False)
        u = u[:, s > 1e-9 * s[0]]
        _, vec = np.linalg.eigh(u.T @ ata @ u)
        t = (u @ vec[:, 0]).reshape(3, 3, 3)
    t = transform_trifocal(t, np.linalg.inv(t1), np.linalg.inv(t2), np.linalg.inv(t3))
    return t / np.linalg.norm(t)


def trifocal_transfer(t: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Transfer ``x1 <-> x2`` into view 3 through the tensor ([HZ] Sec. 15.1.4, "point transfer").

    The line through ``x2`` perpendicular to the epipolar line ``F21 x1`` is used, which avoids the degenerate
    choice of the epipolar line itself: ``x3^k = x1^i l2_j T_i^{jk}``.

    Parameters
    ----------
    t : array (3, 3, 3)
    x1, x2 : array (N, 2)

    Returns
    -------
    array (N, 2)
    """
    f21, _, _ = fundamentals_from_trifocal(t)
    h1, h2 = homogeneous(x1), homogeneous(x2)
    le = h1 @ f21.T  # epipolar lines in view 2
    l2 = np.stack([le[:, 1], -le[:, 0], -h2[:, 0] * le[:, 1] + h2[:, 1] * le[:, 0]], 1)
    x3 = np.einsum("ni,nj,ijk->nk", h1, l2, t)
    return x3[:, :2] / x3[:, 2:]


def triplet_epipolar_distance(
    f21: np.ndarray, f31: np.ndarray, f32: np.ndarray, x1: np.ndarray, x2: np.ndarray, x3: np.ndarray
) -> np.ndarray:
    """The paper's triplet epipolar distance (its eq. 3): the sum of the six point-to-epipolar-line distances
    ``d12 + d21 + d13 + d31 + d23 + d32`` in pixels.

    Parameters
    ----------
    f21, f31, f32 : array (3, 3)
    x1, x2, x3 : array (N, 2)
        Computed in float32 when the points are float32 (as stored in trajectories), else in float64.

    Returns
    -------
    array (N,)
    """
    mats = [([float(v) for v in np.asarray(f, np.float64).ravel()], a, b)
            for f, a, b in ((f21, 0, 1), (f31, 0, 2), (f32, 1, 2))]
    # in blocks of BLOCK points with preallocated buffers: this runs on every trajectory of every triplet, and a
    # block's temporaries stay in the cache
    total, blocks = _in_blocks((x1, x2, x3), 5)
    for cols, part, (l0, l1, alg, tmp, acc) in blocks:
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            for f, a, b in mats:
                (ax, ay), (bx, by) = cols[a], cols[b]
                f00, f01, f02, f10, f11, f12, f20, f21_, f22 = f
                # the line l = F x_a (in view b) and the algebraic residual x_b^T F x_a = (l0 bx + l1 by) + l2,
                # summed in this order so that it is exactly 0 for [a]x F's and static points
                _affine(ax, ay, f00, f01, f02, l0, tmp)
                _affine(ax, ay, f10, f11, f12, l1, tmp)
                _affine(ax, ay, f20, f21_, f22, alg, tmp)
                np.multiply(l0, bx, out=acc)
                np.multiply(l1, by, out=tmp)
                acc += tmp
                np.add(acc, alg, out=alg)
                np.abs(alg, out=alg)
                # d(x_b, F x_a) = |alg| / |(l0, l1)|
                _add_ratio(part, alg, l0, l1)
                # d(x_a, F^T x_b) = |alg| / |(m0, m1)| with m = F^T x_b
                _affine(bx, by, f00, f10, f20, l0, tmp)
                _affine(bx, by, f01, f11, f21_, l1, tmp)
                _add_ratio(part, alg, l0, l1)
    total[np.isnan(total)] = np.inf  # a point at an epipole: its epipolar line is undefined
    return total


def _affine(x: np.ndarray, y: np.ndarray, a: float, b: float, c: float, out: np.ndarray, tmp: np.ndarray) -> None:
    """``out = (a x + b y) + c`` in place (the order numpy uses for the same expression)."""
    np.multiply(x, a, out=out)
    np.multiply(y, b, out=tmp)
    out += tmp
    out += c


def _add_ratio(total: np.ndarray, num: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    """``total += num / sqrt(a^2 + b^2)``, overwriting ``a`` and ``b``."""
    a *= a
    b *= b
    a += b
    np.sqrt(a, out=a)
    np.divide(num, a, out=a)
    total += a


def triplet_sampson_error(
    f21: np.ndarray, f31: np.ndarray, f32: np.ndarray, x1: np.ndarray, x2: np.ndarray, x3: np.ndarray
) -> np.ndarray:
    """First-order squared distance of a point triplet from the three-view epipolar model (pixels^2).

    The sum of the three pairwise Sampson errors ([HZ] eq. 11.9); under isotropic noise sigma it is about
    ``sigma^2 chi^2_3`` (3 = 6 measured coordinates minus the 3 of a space point), the error term of GRIC.
    Broadcasts over a leading batch of F's: ``f21`` (..., 3, 3) gives (..., N).
    """
    return sampson_error(x1, x2, f21) + sampson_error(x1, x3, f31) + sampson_error(x2, x3, f32)
