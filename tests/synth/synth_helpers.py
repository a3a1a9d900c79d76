"""Helpers shared by the synthetic-data tests: memoised clips (they are deterministic) and epipolar geometry."""

from __future__ import annotations

import functools

import numpy as np
from eponet.synth import SceneConfig, generate_clip

SIZE = (213, 120)  # (W, H): small, so the suite stays fast


@functools.lru_cache(maxsize=None)
def cached_clip(seed: int, frames: int, size: tuple[int, int] = SIZE, **settings):
    """``generate_clip`` memoised on its arguments (settings are SceneConfig fields)."""
    return generate_clip(seed, frames, size, SceneConfig(**settings))


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def fundamental_from_cameras(K, R1, t1, R2, t2) -> np.ndarray:
    """F with ``x2^T F x1 = 0`` for world-to-camera poses ``x_cam = R X + t`` (H&Z eq. 9.2 with E = [t]x R)."""
    R = R2 @ R1.T
    t = t2 - R @ t1
    K_inv = np.linalg.inv(K)
    return K_inv.T @ skew(t) @ R @ K_inv


def epipolar_distances(F: np.ndarray, flow: np.ndarray) -> np.ndarray:
    """Distance in pixels of ``p + flow(p)`` to the epipolar line ``F p``, for every pixel p, shape (H, W)."""
    H, W = flow.shape[:2]
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    p = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    q = p.copy()
    q[..., :2] += flow
    lines = p @ F.T
    return np.abs(np.sum(q * lines, axis=-1)) / np.hypot(lines[..., 0], lines[..., 1])

