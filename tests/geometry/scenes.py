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
    """A textured rectangle: origin, two in-plane unit axes, extents (metres) along them, texture scale.

    ``velocity`` (world units per frame) translates the whole rectangle; ``scroll`` (texture pixels per
    frame along u and v) moves only its texture inside a fixed rectangle (water, a video screen).
    ``moving`` marks the independently moving object of the ground-truth masks; a scrolling or translating
    plane that is not ``moving`` is a distractor.
    """

    origin: np.ndarray
    u: np.ndarray
    v: np.ndarray
    extent: tuple[float, float]
    texture: np.ndarray
    pixels_per_unit: float = 60.0
    moving: bool = False
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scroll: tuple[float, float] = (0.0, 0.0)


@dataclass
class RenderedVideo:
    frames: np.ndarray  # uint8 (F, H, W, 3)
    masks: np.ndarray  # bool (F, H, W): the independently moving object is the nearest surface
    cameras: list  # (3, 4) per frame
    #: bool (F, H, W): the nearest surface is a distractor (a scrolling texture or another moving plane)
    distractors: np.ndarray | None = None


def render_planes(planes: list[Plane], centres: np.ndarray, rotvecs: np.ndarray,
                  size: tuple[int, int] = (240, 320)) -> RenderedVideo:
    """Ray-cast textured planes seen by cameras with centres (F, 3) and rotation vectors (F, 3) (world to
    camera), focal length 0.9 * width, principal point at the centre; the nearest surface wins."""
    h, w = size
    k = np.array([[0.9 * w, 0, w / 2], [0, 0.9 * w, h / 2], [0, 0, 1.0]])
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    rays_cam = np.stack([xs.ravel(), ys.ravel(), np.ones(h * w)], 0)
    kinv = np.linalg.inv(k)
    frames, masks, distract, cams = [], [], [], []
    for t, (centre, rotvec) in enumerate(zip(np.asarray(centres, float), np.asarray(rotvecs, float))):
        r = Rotation.from_rotvec(rotvec).as_matrix()
        cams.append(k @ r @ np.c_[np.eye(3), -centre])
        dirs = r.T @ (kinv @ rays_cam)  # world-frame ray directions (3, N)
        best = np.full(h * w, np.inf)
        image = np.zeros(h * w, np.float32)
        is_obj = np.zeros(h * w, bool)
        is_distractor = np.zeros(h * w, bool)
        for plane in planes:
            origin = plane.origin + np.asarray(plane.velocity, float) * t
            normal = np.cross(plane.u, plane.v)
            denom = normal @ dirs
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                lam = (normal @ (origin - centre)) / denom
                lam = np.where(np.isfinite(lam), lam, -1.0)
                rel = centre[:, None] + lam * dirs - origin[:, None]
                a, b = plane.u @ rel, plane.v @ rel
            hit = (lam > 0) & (a >= 0) & (a <= plane.extent[0]) & (b >= 0) & (b <= plane.extent[1]) & (lam < best)
            if not hit.any():
                continue
            tex = plane.texture
            tx = (a[hit] * plane.pixels_per_unit + plane.scroll[0] * t) % (tex.shape[1] - 1)
            ty = (b[hit] * plane.pixels_per_unit + plane.scroll[1] * t) % (tex.shape[0] - 1)
            vals = sample_bilinear(tex[..., None], np.stack([tx, ty], 1).astype(np.float32))[:, 0]
            image[hit] = vals
            best[hit] = lam[hit]
            is_obj[hit] = plane.moving
            is_distractor[hit] = not plane.moving and (any(plane.velocity) or any(plane.scroll))
        gray = np.clip(image.reshape(h, w), 0, 255).astype(np.uint8)
        frames.append(np.repeat(gray[..., None], 3, axis=2))
        masks.append(is_obj.reshape(h, w))
        distract.append(is_distractor.reshape(h, w))
    return RenderedVideo(np.stack(frames), np.stack(masks), cams, np.stack(distract))


def _box(rng, x0, z0, width, height, floor=1.2, depth=None, ppu=80) -> list[Plane]:
    """The front (z = z0) and right side (x = x0 + width) of a box standing on the ground y = floor."""
    ex, ey, ez = np.eye(3)
    top = floor - height
    return [Plane(np.array([x0, top, z0]), ex, ey, (width, height), _texture(rng), ppu),
            Plane(np.array([x0 + width, top, z0]), ez, ey, (depth or width, height), _texture(rng), ppu)]


def render_scene(num_frames: int = 10, size: tuple[int, int] = (240, 320), seed: int = 0,
                 object_velocity=(0.0, -0.06, 0.0), camera_step=(0.08, 0.0, 0.03), yaw_step=0.004,
                 object_origin=(0.5, 0.2, 3.5), object_size=(0.9, 0.7)) -> RenderedVideo:
    """Ray-cast a scene of several textured planes at different depths (ground, back wall, a box, a side
    wall) seen by a translating and rotating camera, with a textured patch that moves independently by
    ``object_velocity`` world units per frame (default: upwards, across the epipolar lines of the mostly
    sideways camera motion)."""
    rng = np.random.default_rng(seed)
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
        planes += _box(rng, x0, z0, width, height)
    planes.append(Plane(np.array(object_origin, float), ex, ey, tuple(object_size), _texture(rng), 120,
                        moving=True, velocity=tuple(object_velocity)))
    t = np.arange(num_frames)[:, None]
    centres = np.asarray(camera_step, float) * t + np.array([-0.4, 0.0, 0.0])
    rotvecs = np.c_[np.zeros(num_frames), yaw_step * t[:, 0], np.zeros(num_frames)]
    return render_planes(planes, centres, rotvecs, size)


def _ground_and_wall(rng, wall_z: float = 30.0) -> list[Plane]:
    ex, ey, ez = np.eye(3)
    return [Plane(np.array([-30.0, 1.2, 0.3]), ex, ez, (60.0, wall_z), _texture(rng), 40),  # ground (y = 1.2)
            Plane(np.array([-30.0, -20.0, wall_z]), ex, ey, (60.0, 21.2), _texture(rng), 12)]  # far wall


def _sideways(num_frames: int, step: float, start: float = -0.3) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(num_frames, dtype=float)
    return np.c_[start + step * t, np.zeros(num_frames), np.zeros(num_frames)], np.zeros((num_frames, 3))


def parallax_scene(num_frames: int = 10, size: tuple[int, int] = (180, 240), seed: int = 0,
                   object_velocity=(0.0, -0.03, 0.0)) -> RenderedVideo:
    """The paper's Fig. 1 case: a camera translating sideways (5 cm per frame) past near rigid rocks (boxes
    1.6-2.6 m away, about a quarter of the frame, 6-10 px of parallax per frame) while an object 6 m away,
    partly behind them, moves slowly (default 3 cm per frame upwards: about 1 px per frame, across the
    horizontal epipolar lines). The far background (ground and a wall 30 m away) is close to one homography;
    the rocks are not."""
    rng = np.random.default_rng(seed)
    ex, ey, _ = np.eye(3)
    planes = _ground_and_wall(rng)
    for x0, z0, width, height in ((-1.5, 1.6, 0.7, 0.9), (0.45, 2.2, 0.8, 0.7), (-0.6, 2.6, 0.5, 0.45)):
        planes += _box(rng, x0, z0, width, height, depth=0.5)
    planes.append(Plane(np.array([-0.4, 0.0, 6.0]), ex, ey, (1.0, 0.8), _texture(rng), 120, moving=True,
                        velocity=tuple(object_velocity)))
    return render_planes(planes, *_sideways(num_frames, 0.05), size)


def large_object_scene(num_frames: int = 10, size: tuple[int, int] = (180, 240), seed: int = 0,
                       object_velocity=(0.0, -0.03, 0.0)) -> RenderedVideo:
    """An object covering about half the frame (a 2.0 x 1.5 m patch 2.5 m away, the motocross case) in
    front of boxes and a far wall, camera translating sideways; the object moves upwards across the
    epipolar lines."""
    rng = np.random.default_rng(seed)
    ex, ey, _ = np.eye(3)
    planes = _ground_and_wall(rng, wall_z=12.0)
    for x0, z0, width, height in ((-3.0, 5.0, 1.0, 1.5), (1.8, 6.0, 1.0, 2.0), (-0.5, 8.0, 1.2, 2.5)):
        planes += _box(rng, x0, z0, width, height)
    planes.append(Plane(np.array([-1.0, -0.8, 2.5]), ex, ey, (2.0, 1.5), _texture(rng), 80, moving=True,
                        velocity=tuple(object_velocity)))
    return render_planes(planes, *_sideways(num_frames, 0.04), size)


def static_distractor_scene(num_frames: int = 10, size: tuple[int, int] = (180, 240), seed: int = 0,
                            object_velocity=(0.04, -0.02, 0.0), scroll=(2.5, 0.5)) -> RenderedVideo:
    """A static camera facing a wall with a 'screen' or 'water' rectangle whose texture scrolls by ``scroll``
    texture pixels per frame (a distractor: ``RenderedVideo.distractors``) and, beside it, the object moving
    by ``object_velocity``."""
    rng = np.random.default_rng(seed)
    ex, ey, _ = np.eye(3)
    planes = _ground_and_wall(rng, wall_z=8.0)
    planes.append(Plane(np.array([0.4, -1.2, 7.9]), ex, ey, (2.2, 1.6), _texture(rng), 30, scroll=tuple(scroll)))
    planes.append(Plane(np.array([-2.0, -0.5, 5.0]), ex, ey, (1.0, 1.0), _texture(rng), 100, moving=True,
                        velocity=tuple(object_velocity)))
    return render_planes(planes, np.zeros((num_frames, 3)), np.zeros((num_frames, 3)), size)


def rotation_scene(num_frames: int = 10, size: tuple[int, int] = (180, 240), seed: int = 1) -> RenderedVideo:
    """A camera that only turns (a homography per frame pair), following a large patch (17% of the frame)
    that therefore hardly moves in the image while the background moves ~3 px per frame sideways: the DAVIS
    case of a panning camera tracking the object. Any epipolar geometry with horizontal epipolar lines
    explains both, so the paper's trifocal fit absorbs the patch."""
    return render_scene(num_frames=num_frames, size=size, seed=seed, camera_step=(0.0, 0.0, 0.0), yaw_step=0.012,
                        object_velocity=(-0.03, 0.0, 0.0), object_origin=(0.0, -0.3, 2.5), object_size=(1.2, 1.0))
