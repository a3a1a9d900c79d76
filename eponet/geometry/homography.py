"""Plane projective transformations: minimal and DLT fits, point transfer and transfer residuals in pixels.

A homography explains the image motion of a rigid scene exactly when the camera only rotates (or zooms) or
the scene is a plane, and approximately when the scene is far away compared with the baseline: the degenerate
cases of the epipolar model ([HZ] Sec. 13 and Result 9.5 / 13.6).

References
----------
.. [HZ] R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2003.
"""

from __future__ import annotations

import numpy as np

from .epipolar import homogeneous
from .normalise import hartley_normalisation

__all__ = [
    "homography_four_point",
    "homography_dlt",
    "transfer",
    "transfer_error_sq",
    "homography_triplet_error_sq",
    "homography_triplet_distance",
]


def _basis(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projective map sending e1, e2, e3, (1,1,1) to the four points (..., 4, 2); and |det| of the basis."""
    ph = homogeneous(points)  # (..., 4, 3)
    b = np.swapaxes(ph[..., :3, :], -1, -2)  # columns p0 p1 p2
    det = np.linalg.det(b)
    safe = np.where(np.abs(det)[..., None, None] > 1e-12, b, np.eye(3))
    lam = np.linalg.solve(safe, ph[..., 3, :, None])[..., 0]
    return b * lam[..., None, :], np.abs(det) * np.abs(np.prod(lam, axis=-1))


def homography_four_point(x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact homographies from batches of four correspondences ([HZ] Sec. 4.1, via canonical bases).

    Parameters
    ----------
    x1, x2 : array (B, 4, 2)
        Pixel (or normalised) coordinates in views 1 and 2.

    Returns
    -------
    H : array (B, 3, 3)
        ``x2 ~ H x1``, unit Frobenius norm.
    valid : bool array (B,)
        False where three of the four points are (nearly) collinear in either view.
    """
    a1, s1 = _basis(x1)
    a2, s2 = _basis(x2)
    ok = (s1 > 1e-9) & (s2 > 1e-9)
    a1 = np.where(ok[:, None, None], a1, np.eye(3))
    h = a2 @ np.linalg.inv(a1)
    h = h / np.linalg.norm(h, axis=(-2, -1), keepdims=True)
    return h, ok & np.isfinite(h).all(axis=(-2, -1))


def homography_dlt(x1: np.ndarray, x2: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """Normalised DLT homography from N >= 4 correspondences ([HZ] Algorithm 4.2).

    Parameters
    ----------
    x1, x2 : array (N, 2)
        Pixel coordinates.
    weights : array (N,), optional
        Non-negative weights of the correspondences (e.g. 0/1 inlier flags).

    Returns
    -------
    array (3, 3)
        ``H`` in pixel coordinates with ``x2 ~ H x1``, unit Frobenius norm.
    """
    n1, t1 = hartley_normalisation(x1)
    n2, t2 = hartley_normalisation(x2)
    x, y = n1[:, 0], n1[:, 1]
    u, v = n2[:, 0], n2[:, 1]
    one, zero = np.ones_like(x), np.zeros_like(x)
    r1 = np.stack([zero, zero, zero, -x, -y, -one, v * x, v * y, v], 1)
    r2 = np.stack([x, y, one, zero, zero, zero, -u * x, -u * y, -u], 1)
    a = np.concatenate([r1, r2], 0)
    if weights is not None:
        w = np.sqrt(np.concatenate([weights, weights]).astype(np.float64))
        a = a * w[:, None]
    _, vec = np.linalg.eigh(a.T @ a)
    hn = vec[:, 0].reshape(3, 3)
    h = np.linalg.inv(t2) @ hn @ t1
    return h / np.linalg.norm(h)


def _transfer_xy(h: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Components (..., N) of ``h x`` for points (N, 2), written out: much faster than stacking a last axis."""
    h = np.asarray(h, dtype=np.float64)
    x = np.asarray(x, dtype=np.float64)
    px, py = x[:, 0], x[:, 1]
    hh = [[h[..., i, j, None] for j in range(3)] for i in range(3)]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = 1.0 / (hh[2][0] * px + hh[2][1] * py + hh[2][2])
        return (hh[0][0] * px + hh[0][1] * py + hh[0][2]) * w, (hh[1][0] * px + hh[1][1] * py + hh[1][2]) * w


def transfer(h: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Points ``x`` (N, 2) mapped by homographies ``h`` (..., 3, 3): (..., N, 2); inf where mapped to infinity."""
    tx, ty = _transfer_xy(h, x)
    out = np.stack([tx, ty], -1)
    return np.where(np.isfinite(out), out, np.inf)


def transfer_error_sq(h: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Squared one-way transfer error ``|x2 - H x1|^2`` in pixels^2, shape (..., N) ([HZ] eq. 4.6)."""
    tx, ty = _transfer_xy(h, x1)
    x2 = np.asarray(x2, dtype=np.float64)
    dx = tx - x2[:, 0]
    dy = ty - x2[:, 1]
    out = dx * dx + dy * dy
    return np.where(np.isnan(out), np.inf, out)


def homography_triplet_error_sq(
    h21: np.ndarray, h31: np.ndarray, x1: np.ndarray, x2: np.ndarray, x3: np.ndarray
) -> np.ndarray:
    """First-order squared distance of a triplet of points from the homography model (pixels^2).

    ``(|x2 - H21 x1|^2 + |x3 - H31 x1|^2 + |x3 - H32 x2|^2) / 3`` with ``H32 = H31 H21^-1``. For transfers
    close to a rigid motion this is the squared distance of the 6-vector (x1, x2, x3) from the model's
    2-dimensional manifold (for identities exactly ``sum_i |x_i - mean|^2``), so under isotropic noise sigma it
    is distributed about as ``sigma^2 chi^2_4`` and is commensurate with the trifocal model's Sampson error
    (``sigma^2 chi^2_3``) in GRIC (Torr 1998).

    Parameters
    ----------
    h21, h31 : array (..., 3, 3)
    x1, x2, x3 : array (N, 2)

    Returns
    -------
    array (..., N)
    """
    h32 = h31 @ np.linalg.inv(h21)
    return (transfer_error_sq(h21, x1, x2) + transfer_error_sq(h31, x1, x3) + transfer_error_sq(h32, x2, x3)) / 3.0


#: Points per block of the per-point distance kernels (:func:`homography_triplet_distance`,
#: :func:`~eponet.geometry.trifocal.triplet_epipolar_distance`): their dozen temporaries of this many float32
#: stay in a core's cache, where at a 854x480 triplet's 430 000 points every pass went to memory (about twice
#: the time; the values are the same, element by element).
BLOCK = 1 << 15


def _columns(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contiguous (x, y) columns, float32 for float32 input (half the memory traffic), else float64."""
    x = np.asarray(x)
    dtype = np.float32 if x.dtype == np.float32 else np.float64
    return np.ascontiguousarray(x[:, 0], dtype=dtype), np.ascontiguousarray(x[:, 1], dtype=dtype)


def _in_blocks(xs, buffers: int):
    """What the per-point distance kernels loop over: their output ``total`` (zeros (N,), float32 for float32
    points, else float64) and an iterator over blocks of :data:`BLOCK` points, each yielding the point sets' (x, y)
    columns (:func:`_columns`), the block's slice of ``total`` and ``buffers`` scratch arrays of its length
    (preallocated once: fresh temporaries cost a page fault per 4 kB)."""
    points = [np.asarray(x) for x in xs]
    dtype = np.float32 if points[0].dtype == np.float32 else np.float64
    n = len(points[0])
    total = np.zeros(n, dtype)
    scratch = [np.empty(min(n, BLOCK), dtype) for _ in range(buffers)]

    def blocks():
        for start in range(0, n, BLOCK):
            part = total[start : start + BLOCK]
            yield [_columns(x[start : start + BLOCK]) for x in points], part, [b[: len(part)] for b in scratch]

    return total, blocks()


def _transfer_distance(h: np.ndarray, a: tuple, b: tuple, total: np.ndarray, buf: list) -> None:
    """``total += |b - H a|`` for one homography and points given as contiguous (x, y) columns, in place with
    the preallocated buffers ``buf`` (fresh temporaries of this size cost a page fault per 4 kB)."""
    (h00, h01, h02), (h10, h11, h12), (h20, h21, h22) = (map(float, row) for row in np.asarray(h, np.float64))
    ax, ay = a
    w, dx, dy, tmp = buf
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for out, (p, q, r) in ((w, (h20, h21, h22)), (dx, (h00, h01, h02)), (dy, (h10, h11, h12))):
            np.multiply(ax, p, out=out)
            np.multiply(ay, q, out=tmp)
            out += tmp
            out += r
        np.divide(1.0, w, out=w)
        dx *= w
        dx -= b[0]
        dy *= w
        dy -= b[1]
        dx *= dx
        dy *= dy
        dx += dy
        np.sqrt(dx, out=dx)
        total += dx


def homography_triplet_distance(
    h21: np.ndarray, h31: np.ndarray, x1: np.ndarray, x2: np.ndarray, x3: np.ndarray
) -> np.ndarray:
    """Sum of the six transfer distances of a point triplet (pixels), the homography analogue of the
    paper's six epipolar distances: ``d(x2, H21 x1) + d(x1, H21^-1 x2) + d(x3, H31 x1) + d(x1, H31^-1 x3)
    + d(x3, H32 x2) + d(x2, H32^-1 x3)`` with ``H32 = H31 H21^-1``.

    Parameters
    ----------
    h21, h31 : array (3, 3)
    x1, x2, x3 : array (N, 2)
        Computed in float32 when the points are float32 (as stored in trajectories), else in float64.

    Returns
    -------
    array (N,)
    """
    h32 = h31 @ np.linalg.inv(h21)
    transfers = [(h, a, b) for h0, a, b in ((h21, 0, 1), (h31, 0, 2), (h32, 1, 2))
                 for h, a, b in ((h0, a, b), (np.linalg.inv(h0), b, a))]
    total, blocks = _in_blocks((x1, x2, x3), 4)
    for cols, part, buf in blocks:
        for h, a, b in transfers:
            _transfer_distance(h, cols[a], cols[b], part, buf)
    total[np.isnan(total)] = np.inf  # a point mapped to infinity
    return total
