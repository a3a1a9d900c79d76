"""Epipolar geometry in pixel coordinates: skew matrices, fundamental matrices, point-to-epipolar-line distances.

Conventions (see :mod:`eponet.core.types`): points are ``(x, y)`` pixels, pixel centres at integers. ``F21``
maps a point of view 1 to its epipolar line in view 2, so a correspondence satisfies ``x2^T F21 x1 = 0``
(Hartley & Zisserman, 2nd ed., eq. 9.2). All functions broadcast over leading batch axes.

References
----------
.. [HZ] R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2003.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "homogeneous",
    "skew",
    "null_vector",
    "rank2_null_vector",
    "camera_centre",
    "fundamental_from_cameras",
    "point_line_distance",
    "epipolar_line_distances",
    "symmetric_epipolar_distance",
    "sampson_error",
    "static_fundamentals",
]


def homogeneous(points: np.ndarray) -> np.ndarray:
    """Append a 1 to ``(..., 2)`` points, giving float64 ``(..., 3)``."""
    points = np.asarray(points, dtype=np.float64)
    return np.concatenate([points, np.ones(points.shape[:-1] + (1,))], axis=-1)


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix ``[v]x`` with ``[v]x @ u == np.cross(v, u)`` ([HZ] A4.5).

    Parameters
    ----------
    v : array (..., 3)

    Returns
    -------
    array (..., 3, 3)
    """
    v = np.asarray(v, dtype=np.float64)
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def null_vector(a: np.ndarray) -> np.ndarray:
    """Unit right null vector (smallest right singular vector) of each matrix in ``a`` ``(..., m, n)``."""
    _, _, vt = np.linalg.svd(a)
    return vt[..., -1, :]


def rank2_null_vector(a: np.ndarray) -> np.ndarray:
    """Unit right null vector of rank-2 matrices ``a`` (..., 3, 3): the longest cross product of two rows.

    Exact for rank-2 matrices and much faster than a batched SVD; for a full-rank (noisy) matrix use
    :func:`null_vector`, the least-squares answer.
    """
    a = np.asarray(a, dtype=np.float64)
    c = np.stack([np.cross(a[..., 0, :], a[..., 1, :]), np.cross(a[..., 0, :], a[..., 2, :]),
                  np.cross(a[..., 1, :], a[..., 2, :])], -2)
    n = np.linalg.norm(c, axis=-1)
    best = np.argmax(n, axis=-1)
    v = np.take_along_axis(c, best[..., None, None], -2)[..., 0, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.take_along_axis(n, best[..., None], -1)


def camera_centre(p: np.ndarray) -> np.ndarray:
    """Homogeneous centre ``C`` (..., 4) of cameras ``p`` (..., 3, 4), ``P C = 0``, by cofactors ([HZ] Sec. 6.2.4)."""
    p = np.asarray(p, dtype=np.float64)
    cols = [p[..., :, i] for i in range(4)]

    def det3(a, b, c):
        return np.einsum("...i,...i->...", a, np.cross(b, c))

    c = np.stack([det3(cols[1], cols[2], cols[3]), -det3(cols[0], cols[2], cols[3]),
                  det3(cols[0], cols[1], cols[3]), -det3(cols[0], cols[1], cols[2])], -1)
    return c / np.linalg.norm(c, axis=-1, keepdims=True)


def fundamental_from_cameras(p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Fundamental matrix ``F21 = [e2]x P2 P1^+`` of two cameras, with ``e2 = P2 C1`` ([HZ] Result 9.9).

    Parameters
    ----------
    p1, p2 : array (..., 3, 4)
        Camera matrices of views 1 and 2.

    Returns
    -------
    array (..., 3, 3)
        ``F21`` with ``x2^T F21 x1 = 0``, scaled to unit Frobenius norm.
    """
    p1 = np.asarray(p1, dtype=np.float64)
    p2 = np.asarray(p2, dtype=np.float64)
    c1 = camera_centre(p1)
    e2 = np.einsum("...ij,...j->...i", p2, c1)
    p1_pinv = np.swapaxes(p1, -1, -2) @ np.linalg.inv(p1 @ np.swapaxes(p1, -1, -2))
    f = skew(e2) @ p2 @ p1_pinv
    return f / np.linalg.norm(f, axis=(-2, -1), keepdims=True)


def point_line_distance(points: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """Distance ``|l . x| / sqrt(l1^2 + l2^2)`` of pixel points from lines.

    Parameters
    ----------
    points : array (..., N, 2)
        Pixel coordinates.
    lines : array (..., N, 3)
        Homogeneous lines ``l1 x + l2 y + l3 = 0``.

    Returns
    -------
    array (..., N)
        Distances in pixels; ``inf`` for a degenerate line ``l1 = l2 = 0``.
    """
    num = np.abs(lines[..., 0] * points[..., 0] + lines[..., 1] * points[..., 1] + lines[..., 2])
    den = np.sqrt(lines[..., 0] ** 2 + lines[..., 1] ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = num / den
    return np.where(den > 0, out, np.inf)


def _lines(f: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Epipolar lines ``F x`` for points ``x`` (N, 2) and matrices ``f`` (..., 3, 3), as (..., 3, N): one
    (batched) matrix product, so that ``out[..., k, :]`` is a contiguous component."""
    f = np.asarray(f, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    xh = np.empty((3, len(x)))
    xh[:2] = x.T
    xh[2] = 1.0
    return f @ xh


def epipolar_line_distances(x1: np.ndarray, x2: np.ndarray, f21: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both point-to-epipolar-line distances of correspondences ``x1 <-> x2`` (the paper's eq. 1-2).

    Parameters
    ----------
    x1, x2 : array (N, 2)
        Pixel coordinates in views 1 and 2.
    f21 : array (..., 3, 3)
        Fundamental matrix (or a batch of them) with ``x2^T F21 x1 = 0``.

    Returns
    -------
    d2, d1 : arrays (..., N)
        ``d2 = d(x2, F21 x1)`` in view 2 and ``d1 = d(x1, F21^T x2)`` in view 1, in pixels.

    Examples
    --------
    >>> f = skew([1.0, 0.0, 0.0])  # epipole at infinity along x: horizontal epipolar lines
    >>> d2, d1 = epipolar_line_distances(np.array([[3.0, 4.0]]), np.array([[5.0, 6.0]]), f)
    >>> float(d2[0]), float(d1[0])
    (2.0, 2.0)
    """
    x1 = np.asarray(x1, dtype=np.float64)
    x2 = np.asarray(x2, dtype=np.float64)
    la = _lines(f21, x1)
    lb = _lines(np.swapaxes(f21, -1, -2), x2)
    a0, a1, a2 = la[..., 0, :], la[..., 1, :], la[..., 2, :]
    b0, b1, b2 = lb[..., 0, :], lb[..., 1, :], lb[..., 2, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        d2 = np.abs(a0 * x2[:, 0] + a1 * x2[:, 1] + a2) / np.sqrt(a0 * a0 + a1 * a1)
        d1 = np.abs(b0 * x1[:, 0] + b1 * x1[:, 1] + b2) / np.sqrt(b0 * b0 + b1 * b1)
    return np.where(np.isnan(d2), np.inf, d2), np.where(np.isnan(d1), np.inf, d1)


def symmetric_epipolar_distance(x1: np.ndarray, x2: np.ndarray, f21: np.ndarray) -> np.ndarray:
    """``d(x2, F21 x1) + d(x1, F21^T x2)`` in pixels, shape (..., N)."""
    d2, d1 = epipolar_line_distances(x1, x2, f21)
    return d2 + d1


def sampson_error(x1: np.ndarray, x2: np.ndarray, f21: np.ndarray) -> np.ndarray:
    """Squared Sampson distance (first-order geometric error) of correspondences, in pixels^2 ([HZ] eq. 11.9).

    Parameters
    ----------
    x1, x2 : array (N, 2)
    f21 : array (..., 3, 3)

    Returns
    -------
    array (..., N)
        ``(x2^T F x1)^2 / ((F x1)_1^2 + (F x1)_2^2 + (F^T x2)_1^2 + (F^T x2)_2^2)``; under isotropic Gaussian
        noise of standard deviation sigma on every coordinate it is distributed as ``sigma^2 chi^2_1``.
    """
    la = _lines(f21, x1)
    lb = _lines(np.swapaxes(f21, -1, -2), x2)
    a0, a1, a2 = la[..., 0, :], la[..., 1, :], la[..., 2, :]
    b0, b1 = lb[..., 0, :], lb[..., 1, :]
    x2 = np.asarray(x2, dtype=np.float64)
    alg = a0 * x2[:, 0] + a1 * x2[:, 1] + a2
    den = a0 * a0 + a1 * a1 + b0 * b0 + b1 * b1
    with np.errstate(divide="ignore", invalid="ignore"):
        out = alg * alg / den
    return np.where(den > 0, out, np.inf)


def static_fundamentals() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fixed skew-symmetric ``F21, F31, F32`` for a static camera (the paper's Sec. 3).

    With a static camera every skew-symmetric matrix ``[a]x`` is a valid fundamental matrix: its epipolar
    line of ``x`` is the line through ``x`` and ``a``, so a point that did not move has distance exactly 0.
    The original code puts ``a`` at finite normalised points; here the three ``a`` are points at infinity in
    three directions (0, 90 and 45 degrees) so that the distance is a plain displacement component in pixels:
    ``d(x2, F21 x1) = |dy|`` between views 1 and 2, ``|dx|`` between views 1 and 3, and the displacement
    across the diagonal between views 2 and 3. Any motion is seen by at least two of the three.

    Returns
    -------
    F21, F31, F32 : arrays (3, 3)
    """
    return skew([1.0, 0.0, 0.0]), skew([0.0, 1.0, 0.0]), skew([np.sqrt(0.5), np.sqrt(0.5), 0.0])
