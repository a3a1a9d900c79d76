"""Synthetic scenes with exact ground truth for the geometry tests: random 3-D points seen by known cameras,
a small ray-cast renderer of textured planes with an independently moving patch, DIS flow and ROC AUC."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from eponet.geometry import sample_bilinear

K_DEFAULT = np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]])


def camera(rotvec, centre, k=K_DEFAULT) -> np.ndarray:
    """``P = K R [I | -C]`` (3, 4) for a rotation vector and a camera centre in world coordinates."""
    r = Rotation.from_rotvec(np.asarray(rotvec, float)).as_matrix()
    return k @ r @ np.c_[np.eye(3), -np.asarray(centre, float)]


def project(p: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Pixel projections (N, 2) of homogeneous or Euclidean world points (N, 3|4)."""
    if x.shape[1] == 3:
        x = np.c_[x, np.ones(len(x))]
    h = x @ p.T
    return h[:, :2] / h[:, 2:]


def three_cameras(kind: str = "general") -> list[np.ndarray]:
    """Three cameras: ``general`` (translation and rotation), ``static`` (all equal), ``rotation`` (a common
    centre)."""
    if kind == "general":
        return [camera([0, 0, 0], [0, 0, 0]), camera([0.02, -0.04, 0.01], [0.6, 0.1, 0.1]),
                camera([-0.03, 0.05, 0.02], [1.1, -0.3, 0.25])]
    if kind == "static":
        return [camera([0, 0, 0], [0, 0, 0])] * 3
    if kind == "rotation":
        return [camera([0, 0, 0], [0, 0, 0]), camera([0.01, -0.03, 0.0], [0, 0, 0]),
                camera([0.02, -0.06, 0.01], [0, 0, 0])]
    raise ValueError(kind)


def random_points(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` world points in front of the cameras, depths 4-12."""
    return np.c_[rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(4, 12, n)]


def roc_auc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``score`` for the boolean labels ``positive`` (ties count one half)."""
    from scipy.stats import rankdata

    pos = np.asarray(positive, bool).ravel()
    s = np.asarray(score, np.float64).ravel()
    n_pos = int(pos.sum())
    n_neg = pos.size - n_pos
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    ranks = rankdata(s)
    return float((ranks[pos].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def dis_flow(frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward/backward DIS (preset medium) flow (F-1, H, W, 2) of RGB or grey frames (project convention)."""
    gray = [f if f.ndim == 2 else cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    fw = np.stack([dis.calc(gray[t], gray[t + 1], None) for t in range(len(gray) - 1)])
    bw = np.stack([dis.calc(gray[t + 1], gray[t], None) for t in range(len(gray) - 1)])
    return fw.astype(np.float32), bw.astype(np.float32)


def _texture(rng: np.random.Generator, size: int = 512) -> np.ndarray:
    """A multi-scale random texture, float32 (size, size) in [0, 255]."""
    tex = np.zeros((size, size), np.float32)
    for sigma, weight in ((1.0, 0.5), (3.0, 1.0), (8.0, 1.0)):
        layer = cv2.GaussianBlur(rng.normal(0, 1, (size, size)).astype(np.float32), (0, 0), sigma)
        tex += weight * layer / (layer.std() + 1e-6)
    tex = (tex - tex.min()) / (tex.max() - tex.min())
    return (tex * 235 + 10).astype(np.float32)


@dataclass
class Plane:
    """A textured rectangle: origin, two in-plane unit axes, extents (metres) along them, texture scale."""

    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    extent: tuple[float, float]
    texture: np.ndarray
    pixels_per_unit: float = 60.0
    moving: bool = False


@dataclass
class RenderedVideo:
    frames: np.ndarray  # uint8 (F, H, W, 3)
    masks: np.ndarray  # bool (F, H, W): the independently moving patch is the nearest surface
    cameras: list  # (3, 4) per frame


def render_scene(num_frames: int = 10, size: tuple[int, int] = (240, 320), seed: int = 0,
                 object_velocity=(0.0, -0.06, 0.0), camera_step=(0.08, 0.0, 0.03), yaw_step=0.004,
                 object_origin=(0.5, 0.2, 3.5), object_size=(0.9, 0.7)) -> RenderedVideo:
    """Ray-cast a scene of several textured planes at different depths (ground, back wall, a box, a side
    wall) seen by a translating and rotating camera, with a textured patch that moves independently by
    ``object_velocity`` world units per frame (default: upwards, across the epipolar lines of the mostly
    sideways camera motion)."""
    rng = np.random.default_rng(seed)
    h, w = size
    k = np.array([[0.9 * w, 0, w / 2], [0, 0.9 * w, h / 2], [0, 0, 1.0]])
    ex, ey, ez = np.eye(3)
    planes = [
        Plane(np.array([-8.0, 1.2, 0.5]), ex, ez, (16.0, 14.0), _texture(rng), 40),  # ground (y = 1.2)
        Plane(np.array([-8.0, -6.0, 12.0]), ex, ey, (16.0, 7.2), _texture(rng), 30),  # back wall (z = 12)
        Plane(np.array([-1.6, -0.4, 5.0]), ex, ey, (1.4, 1.6), _texture(rng), 80),  # box front (z = 5)
        Plane(np.array([-0.2, -0.4, 5.0]), ez, ey, (1.5, 1.6), _texture(rng), 80),  # box side (x = -0.2)
        Plane(np.array([2.6, -6.0, 1.0]), ez, ey, (11.0, 7.2), _texture(rng), 40),  # right wall (x = 2.6)
    ]
    boxes = ((-2.8, 3.0, 0.8, 1.0), (1.2, 7.5, 1.0, 2.2), (-1.0, 9.5, 1.4, 3.0), (-3.5, 6.0, 0.9, 2.5))
    for x0, z0, width, height in boxes:
        # more boxes at other depths: no two planes explain the background (real 3-D parallax)
        planes.append(Plane(np.array([x0, 1.2 - height, z0]), ex, ey, (width, height), _texture(rng), 80))
        planes.append(Plane(np.array([x0 + width, 1.2 - height, z0]), ez, ey, (width, height), _texture(rng), 80))
    patch = Plane(np.array(object_origin, float), ex, ey, tuple(object_size), _texture(rng), 120, moving=True)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    rays_cam = np.stack([xs.ravel(), ys.ravel(), np.ones(h * w)], 0)
    kinv = np.linalg.inv(k)
    frames, masks, cams = [], [], []
    for t in range(num_frames):
        centre = np.array(camera_step, float) * t + np.array([-0.4, 0.0, 0.0])
        rotvec = np.array([0.0, yaw_step * t, 0.0])
        r = Rotation.from_rotvec(rotvec).as_matrix()
        cams.append(k @ r @ np.c_[np.eye(3), -centre])
        dirs = r.T @ (kinv @ rays_cam)  # world-frame ray directions (3, N)
        best = np.full(h * w, np.inf)
        image = np.zeros(h * w, np.float32)
        is_obj = np.zeros(h * w, bool)
        moved = Plane(patch.origin + np.asarray(object_velocity) * t, patch.u, patch.v, patch.extent,
                      patch.texture, patch.pixels_per_unit, True)
        for plane in planes + [moved]:
            normal = np.cross(plane.u, plane.v)
            denom = normal @ dirs
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                lam = (normal @ (plane.origin - centre)) / denom
                lam = np.where(np.isfinite(lam), lam, -1.0)
                rel = centre[:, None] + lam * dirs - plane.origin[:, None]
                a, b = plane.u @ rel, plane.v @ rel
            hit = (lam > 0) & (a >= 0) & (a <= plane.extent[0]) & (b >= 0) & (b <= plane.extent[1]) & (lam < best)
            if not hit.any():
                continue
            tex = plane.texture
            tx = (a[hit] * plane.pixels_per_unit) % (tex.shape[1] - 1)
            ty = (b[hit] * plane.pixels_per_unit) % (tex.shape[0] - 1)
            vals = sample_bilinear(tex[..., None], np.stack([tx, ty], 1).astype(np.float32))[:, 0]
            image[hit] = vals
            best[hit] = lam[hit]
            is_obj[hit] = plane.moving
        gray = np.clip(image.reshape(h, w), 0, 255).astype(np.uint8)
        frames.append(np.repeat(gray[..., None], 3, axis=2))
        masks.append(is_obj.reshape(h, w))
    return RenderedVideo(np.stack(frames), np.stack(masks), cams)
