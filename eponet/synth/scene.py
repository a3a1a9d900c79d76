"""Random RBSF-style scenes: a textured 3D room with boxes, a smoothly moving camera, and moving sprites.

Everything is drawn from one seeded ``numpy.random.Generator``, so a seed fixes the whole clip. World
coordinates: x right, y down, z forward, in arbitrary units (about metres); the first camera sits near the
origin looking down +z. Cameras are world-to-camera, ``x_cam = R X + t``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..core.errors import SpecError
from ..core.registry import nearest
from .render import render_frame, scaled_intrinsics
from .textures import TextureBank, WaterTexture, sprite_alpha, sprite_texture, surface_texture

__all__ = ["SceneConfig", "Surface", "Scene", "sample_scene"]


def _range(name: str, value: Any, lo: float, hi: float, integer: bool = False) -> list[str]:
    kind = "integers" if integer else "numbers"
    if not (isinstance(value, (tuple, list)) and len(value) == 2):
        return [f"{name}: expected a pair [min, max] of {kind}, got {value!r}"]
    ok_type = (lambda x: isinstance(x, (int, np.integer)) and not isinstance(x, bool)) if integer else (
        lambda x: isinstance(x, (int, float, np.number)) and not isinstance(x, bool))
    if not all(ok_type(x) for x in value):
        return [f"{name}: expected a pair [min, max] of {kind}, got {value!r}"]
    a, b = value
    if not (lo <= a <= b <= hi):
        return [f"{name}: expected {lo} <= min <= max <= {hi}, got {list(value)!r}"]
    return []


def _scalar(name: str, value: Any, lo: float, hi: float) -> list[str]:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) or not (lo <= value <= hi):
        return [f"{name}: expected a number in [{lo}, {hi}], got {value!r}"]
    return []


@dataclass(frozen=True)
class SceneConfig:
    """What the scene sampler may draw; ranges are ``(min, max)``, drawn uniformly.

    Speeds are in image units so that they mean the same at every frame size: a fraction of the frame
    width per frame (0.01 is about 4 px/frame at 427x240).
    """

    #: Number of foreground objects.
    num_objects: tuple[int, int] = (1, 3)
    #: Fraction of the frame the objects cover together in the first frame (the paper: 30-50%).
    fg_fraction: tuple[float, float] = (0.30, 0.50)
    #: Object speed in the image, fraction of the frame width per frame ("fairly fast").
    object_speed: tuple[float, float] = (0.008, 0.03)
    #: Largest in-plane rotation speed of an object, degrees per frame.
    object_rotation: float = 1.5
    #: Probability that an object pauses once during the clip, and the pause length in frames.
    pause_probability: float = 0.3
    pause_frames: tuple[int, int] = (3, 10)
    #: Fraction of clips with a static camera.
    static_camera_probability: float = 0.15
    #: Camera speed: parallax of a point at the objects' depth, fraction of the frame width per frame.
    camera_speed: tuple[float, float] = (0.004, 0.015)
    #: Largest camera rotation speed, degrees per frame (free-looking cameras).
    camera_rotation: float = 0.4
    #: Probability that the camera keeps looking at a fixed point (a tracking shot) while it translates.
    look_at_probability: float = 0.5
    #: Horizontal field of view, degrees.
    fov: tuple[float, float] = (50.0, 70.0)
    #: Boxes standing on the floor.
    num_boxes: tuple[int, int] = (1, 4)
    #: Probability of a water-like dynamic-texture region on the floor.
    dynamic_texture_probability: float = 0.25
    #: Global brightness drift: largest relative change per frame (0 = constant brightness).
    brightness_drift: float = 0.0
    #: Folder of photographs for the background surfaces (None: scikit-image's bundled photographs).
    backgrounds: str | None = None

    def __post_init__(self) -> None:
        problems = self.problems()
        if problems:
            raise SpecError(problems)

    def problems(self) -> list[str]:
        """Every invalid field, each as ``name: expected ..., got ...``."""
        p: list[str] = []
        p += _range("num_objects", self.num_objects, 1, 8, integer=True)
        p += _range("fg_fraction", self.fg_fraction, 0.01, 0.9)
        p += _range("object_speed", self.object_speed, 0.0, 0.2)
        p += _scalar("object_rotation", self.object_rotation, 0.0, 20.0)
        p += _scalar("pause_probability", self.pause_probability, 0.0, 1.0)
        p += _range("pause_frames", self.pause_frames, 1, 10000, integer=True)
        p += _scalar("static_camera_probability", self.static_camera_probability, 0.0, 1.0)
        p += _range("camera_speed", self.camera_speed, 0.0, 0.1)
        p += _scalar("camera_rotation", self.camera_rotation, 0.0, 5.0)
        p += _scalar("look_at_probability", self.look_at_probability, 0.0, 1.0)
        p += _range("fov", self.fov, 20.0, 100.0)
        p += _range("num_boxes", self.num_boxes, 0, 12, integer=True)
        p += _scalar("dynamic_texture_probability", self.dynamic_texture_probability, 0.0, 1.0)
        p += _scalar("brightness_drift", self.brightness_drift, 0.0, 0.2)
        if self.backgrounds is not None and not isinstance(self.backgrounds, str):
            p.append(f"backgrounds: expected a folder path or null, got {self.backgrounds!r}")
        return p

    @classmethod
    def from_dict(cls, data: dict, *, file: str | None = None) -> "SceneConfig":
        """Build from a mapping (e.g. parsed YAML); unknown keys and bad values are all reported at once."""
        if not isinstance(data, dict):
            raise SpecError(f"expected a mapping of scene settings, got {type(data).__name__}", file=file)
        names = {f.name for f in dataclasses.fields(cls)}
        problems = []
        for key in data:
            if key not in names:
                hint = nearest(key, sorted(names))
                problems.append(f"{key}: unknown setting{f' (did you mean {hint!r}?)' if hint else ''} "
                                f"(known: {', '.join(sorted(names))})")
        values = {k: (tuple(v) if isinstance(v, list) else v) for k, v in data.items() if k in names}
        try:
            config = cls(**values)
        except SpecError as exc:
            problems += exc.problems
            config = None
        if problems:
            raise SpecError(problems, file=file)
        return config


@dataclass(eq=False)
class Surface:
    """A textured planar quad ``corner + a * edge_u + b * edge_v``, ``(a, b)`` in the unit square.

    Coordinates are world coordinates for the background (``object_id`` 0) and the object's local frame for
    a sprite (``object_id`` k >= 1, placed by ``Scene.object_poses[k-1]``). ``texture`` is RGBA uint8; for a
    sprite, ``alpha`` float32 in [0, 1] on the same texel grid gives the shape (support: alpha > 0.5).
    ``cull_back``: drawn only from the side ``edge_u x edge_v`` points to (faces of closed boxes).
    """

    name: str
    corner: np.ndarray
    edge_u: np.ndarray
    edge_v: np.ndarray
    object_id: int = 0
    #: Texture size in texels ``(W_t, H_t)`` the quad spans; ``texture`` may be smaller (tiled by mirroring).
    texels: tuple[int, int] = (1, 1)
    texture: np.ndarray | None = None
    alpha: np.ndarray | None = None
    cull_back: bool = False
    dynamic: WaterTexture | None = field(default=None, repr=False)
    _dyn_cache: tuple[int, np.ndarray] | None = field(default=None, repr=False)

    @property
    def alpha_padded(self) -> np.ndarray | None:
        """``alpha`` with a one-texel zero border (for exact bilinear sampling), cached."""
        if self.alpha is None:
            return None
        cached = self.__dict__.get("_alpha_padded")
        if cached is None or cached[0] is not self.alpha:
            cached = (self.alpha, np.pad(self.alpha.astype(np.float64), 1))
            self.__dict__["_alpha_padded"] = cached
        return cached[1]

    @property
    def alpha8(self) -> np.ndarray | None:
        """``alpha`` as uint8 (x255, rounded), the sprite texture's alpha channel, cached."""
        if self.alpha is None:
            return None
        cached = self.__dict__.get("_alpha8")
        if cached is None or cached[0] is not self.alpha:
            cached = (self.alpha, np.round(self.alpha * 255).astype(np.uint8))
            self.__dict__["_alpha8"] = cached
        return cached[1]

    def texture_at(self, t: int) -> np.ndarray:
        """The RGBA texture at frame ``t`` (changes every frame for a dynamic texture)."""
        if self.dynamic is None:
            return self.texture
        if self._dyn_cache is None or self._dyn_cache[0] != t:
            self._dyn_cache = (t, self.dynamic.frame(t))
        return self._dyn_cache[1]


@dataclass(eq=False)
class Scene:
    """A sampled scene: intrinsics ``K`` (3, 3), cameras ``R`` (F, 3, 3) and ``t`` (F, 3) (world-to-camera),
    surfaces, per-object poses ``object_poses`` (N, F, 4, 4) (local -> world), per-frame brightness gain."""

    size: tuple[int, int]
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    surfaces: list[Surface]
    object_poses: np.ndarray
    brightness: np.ndarray | None
    static_camera: bool
    info: dict = field(default_factory=dict)

    @property
    def num_frames(self) -> int:
        return int(self.R.shape[0])

    @property
    def num_objects(self) -> int:
        return int(self.object_poses.shape[0])

    def object_of_surface(self) -> np.ndarray:
        """uint8 lookup table: surface index (and ``NO_SURFACE``) -> object id (0 = background)."""
        lut = np.zeros(256, np.uint8)
        for i, s in enumerate(self.surfaces):
            lut[i] = s.object_id
        return lut

    def surface_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Corners, u edges and v edges of all surfaces, each (S, 3)."""
        return (
            np.array([s.corner for s in self.surfaces], np.float64),
            np.array([s.edge_u for s in self.surfaces], np.float64),
            np.array([s.edge_v for s in self.surfaces], np.float64),
        )

    def surface_object_ids(self) -> np.ndarray:
        return np.array([s.object_id for s in self.surfaces], np.int64)

    def draw_order(self) -> list[int]:
        """Surface indices roughly front to back: objects (nearest first), boxes, the room."""
        def key(i: int):
            s = self.surfaces[i]
            if s.object_id:
                return (0, float(np.linalg.norm(self.object_poses[s.object_id - 1, 0, :3, 3])))
            return (1 if s.cull_back else 2, i)

        return sorted(range(len(self.surfaces)), key=key)

    def dynamic_surfaces(self) -> np.ndarray:
        """bool lookup table: surface index -> has a dynamic texture."""
        lut = np.zeros(256, bool)
        for i, s in enumerate(self.surfaces):
            lut[i] = s.dynamic is not None
        return lut


#: Background textures get one texel per pixel at this percentile of the surface's visible pixels' footprints:
#: beyond it they are minified, which bilinear sampling aliases (measured: the warping error grows with
#: minification).
_TEXEL_FOOTPRINT_PERCENTILE = 60

# --- rotations ---------------------------------------------------------------------------------------------

def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _look_at(position: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """Camera-to-world rotation (columns: camera x, y, z axes) looking from ``position`` at ``target``."""
    z = target - position
    z = z / np.linalg.norm(z)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z]) @ _rot_z(roll)


def _oscillation(rng: np.random.Generator, amplitude: float, rate: float, steps: np.ndarray) -> np.ndarray:
    """Smooth bounded motion ``A (sin(w s + phi) - sin phi)`` starting at 0 with speed about ``rate`` at
    ``s = 0`` (``w = rate / A``); ``steps`` may stand still (pauses)."""
    if amplitude <= 0 or rate <= 0:
        return np.zeros_like(steps, dtype=np.float64)
    phase = rng.uniform(-math.pi / 3, math.pi / 3)  # start moving, not at a turning point
    omega = rate / (amplitude * math.cos(phase))
    return amplitude * (np.sin(omega * steps + phase) - math.sin(phase))


def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)


# --- sampling ----------------------------------------------------------------------------------------------

def _sample_cameras(rng, frames, f, width, config, z_ref):
    """World-to-camera R (F, 3, 3), t (F, 3), and whether the camera is static."""
    static = bool(rng.random() < config.static_camera_probability)
    yaw0, pitch0, roll0 = np.radians([rng.uniform(-10, 10), rng.uniform(-10, 3), rng.uniform(-3, 3)])
    c0 = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.2), rng.uniform(-0.3, 0.3)])
    C0 = _rot_y(yaw0) @ _rot_x(pitch0) @ _rot_z(roll0)
    steps = np.arange(frames, dtype=np.float64)
    if static:
        C = np.repeat(C0[None], frames, axis=0)
        centres = np.repeat(c0[None], frames, axis=0)
    else:
        speed = rng.uniform(*config.camera_speed) * width * z_ref / f  # world units per frame
        angle = rng.uniform(-math.pi / 3, math.pi / 3) + (math.pi if rng.random() < 0.5 else 0.0)
        # mostly sideways; forward motion only a little, so the camera never reaches the objects
        main = _unit([math.cos(angle), rng.uniform(-0.25, 0.25), min(0.3, 0.6 * math.sin(angle))])
        side = _unit(np.cross(main, _unit(rng.normal(size=3))))
        amp = rng.uniform(0.4, 0.6)
        centres = (
            c0
            + _oscillation(rng, amp, speed, steps)[:, None] * main
            + _oscillation(rng, 0.3 * amp, 0.3 * speed, steps)[:, None] * side
        )
        if rng.random() < config.look_at_probability:
            target = c0 + C0 @ np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.2, 0.2), z_ref])
            roll = roll0 + _oscillation(rng, math.radians(2), math.radians(config.camera_rotation) / 4, steps)
            C = np.stack([_look_at(c, target, r) for c, r in zip(centres, roll)])
        else:
            rate = math.radians(rng.uniform(0, config.camera_rotation))
            yaw = yaw0 + _oscillation(rng, math.radians(rng.uniform(3, 8)), rate, steps)
            pitch = pitch0 + _oscillation(rng, math.radians(rng.uniform(2, 4)), rate / 2, steps)
            roll = roll0 + _oscillation(rng, math.radians(2), rate / 4, steps)
            C = np.stack([_rot_y(a) @ _rot_x(b) @ _rot_z(c) for a, b, c in zip(yaw, pitch, roll)])
    R = np.ascontiguousarray(np.transpose(C, (0, 2, 1)))
    t = -np.einsum("fij,fj->fi", R, centres)
    return R, t, static


def _quad(name, corner, edge_u, edge_v, **kw) -> Surface:
    return Surface(name, np.asarray(corner, float), np.asarray(edge_u, float), np.asarray(edge_v, float), **kw)


def _room(rng):
    """Floor, ceiling, back wall and two side walls (oversized: the depth test trims them at the corners)."""
    floor_y = rng.uniform(1.2, 1.8)
    ceil_y = -rng.uniform(2.5, 4.0)
    back_z = rng.uniform(8.0, 16.0)
    left_x, right_x = -rng.uniform(3.0, 7.0), rng.uniform(3.0, 7.0)
    z_near, margin = -4.0, 3.0
    x_lo, x_hi = left_x - 6.0, right_x + 6.0
    surfaces = [
        _quad("floor", [x_lo, floor_y, back_z + margin], [x_hi - x_lo, 0, 0], [0, 0, z_near - back_z - margin]),
        _quad("ceiling", [x_lo, ceil_y, z_near], [x_hi - x_lo, 0, 0], [0, 0, back_z + margin - z_near]),
        _quad("back wall", [x_lo, ceil_y - 1, back_z], [x_hi - x_lo, 0, 0], [0, floor_y - ceil_y + 2, 0]),
    ]
    height = floor_y - ceil_y + 2
    for name, x in (("left wall", left_x), ("right wall", right_x)):
        yaw = math.radians(rng.uniform(-10, 10))  # walls need not be parallel
        along = _rot_y(yaw) @ np.array([0.0, 0.0, 1.0])
        length = (back_z + margin - z_near) / max(abs(along[2]), 0.5)
        start = np.array([x, ceil_y - 1, 0.0]) + along * z_near / along[2]
        surfaces.append(_quad(name, start, along * length, [0, height, 0]))
    return surfaces, dict(floor_y=floor_y, ceil_y=ceil_y, back_z=back_z, left_x=left_x, right_x=right_x)


def _box(rng, index, room, cx: float, cz: float) -> list[Surface]:
    """A closed box standing on the floor at (cx, cz) (its four sides and top; outward normals for culling)."""
    w, d, h = rng.uniform(0.6, 2.5), rng.uniform(0.6, 2.5), rng.uniform(0.5, 2.5)
    centre = np.array([cx, room["floor_y"] - h / 2, cz])
    Rb = _rot_y(rng.uniform(0, math.pi))
    ex, ey, ez = Rb[:, 0], Rb[:, 1], Rb[:, 2]
    half = {0: w / 2, 1: h / 2, 2: d / 2}
    axes = {0: ex, 1: ey, 2: ez}
    # (normal axis, sign, tangent a, tangent b) with a x b = sign * normal
    faces = [(0, 1, 1, 2), (0, -1, 2, 1), (2, 1, 0, 1), (2, -1, 1, 0), (1, -1, 0, 2)]
    out = []
    for k, (n, sign, a, b) in enumerate(faces):
        corner = centre + sign * half[n] * axes[n] - half[a] * axes[a] - half[b] * axes[b]
        out.append(_quad(f"box {index} face {k}", corner, 2 * half[a] * axes[a], 2 * half[b] * axes[b], cull_back=True))
    return out


def _object_track(rng, frames, config, f, width, depth, R_obj0, X0):
    """Local-to-world poses (F, 4, 4) of one object: a smooth 3D path with in-plane rotation and tilt,
    optionally pausing once (its pose is then bit-identical over the pause)."""
    moving = np.ones(frames, np.float64)
    pause = None
    if frames >= 4 and rng.random() < config.pause_probability:
        length = int(min(rng.integers(config.pause_frames[0], config.pause_frames[1] + 1), frames - 2))
        start = int(rng.integers(1, frames - length))
        moving[start : start + length] = 0.0
        pause = (start, start + length)
    # internal time: stands still during the pause, so poses repeat exactly
    tau = np.concatenate([[0.0], np.cumsum(moving[:-1])])
    speed = rng.uniform(*config.object_speed) * width * depth / f  # world units per frame
    half_width = depth * (width / 2) / f
    angle = rng.uniform(0, 2 * math.pi)
    main = _unit(R_obj0 @ _unit([math.cos(angle), 0.6 * math.sin(angle), rng.uniform(-0.3, 0.3)]))
    side = _unit(np.cross(main, R_obj0[:, 2]))
    amp = rng.uniform(0.25, 0.45) * half_width
    path = (
        _oscillation(rng, amp, speed, tau)[:, None] * main
        + _oscillation(rng, 0.35 * amp, 0.5 * speed, tau)[:, None] * side
    )
    rate = math.radians(rng.uniform(0.2, 1.0) * config.object_rotation)
    roll = _oscillation(rng, math.radians(rng.uniform(5, 25)), rate, tau)
    yaw = _oscillation(rng, math.radians(rng.uniform(0, 20)), rate, tau)
    poses = np.zeros((frames, 4, 4))
    for i in range(frames):
        poses[i, :3, :3] = R_obj0 @ _rot_z(roll[i]) @ _rot_y(yaw[i])
        poses[i, :3, 3] = X0 + path[i]
        poses[i, 3, 3] = 1.0
    return poses, pause


def _project_rect(K, R, t, points: np.ndarray):
    """Image bounding rectangle (x0, y0, x1, y1) and nearest depth of world points (N, 3) seen by (R, t)."""
    cam = points @ R.T + t
    z = cam[:, 2]
    if z.min() <= 0.05:
        return None, float(z.min())
    px = cam @ K.T
    px = px[:, :2] / px[:, 2:3]
    return (px[:, 0].min(), px[:, 1].min(), px[:, 0].max(), px[:, 1].max()), float(z.min())


def _object_rects(scene: "Scene", k: int, t: int):
    """Frame ``t``, image rectangle and depth of object ``k``'s sprite."""
    s = scene.surfaces[k]
    pose = scene.object_poses[k, t]
    local = np.stack([s.corner, s.corner + s.edge_u, s.corner + s.edge_u + s.edge_v, s.corner + s.edge_v])
    world = local @ pose[:3, :3].T + pose[:3, 3]
    rect, depth = _project_rect(scene.K, scene.R[t], scene.t[t], world)
    return t, rect, depth


def _hides(scene: "Scene", faces: list[Surface], view) -> bool:
    """Whether a box (its faces) in front of an object covers more than a quarter of the object's rectangle."""
    t, obj_rect, obj_depth = view
    if obj_rect is None:
        return False
    corners = np.concatenate([[f.corner, f.corner + f.edge_u, f.corner + f.edge_v, f.corner + f.edge_u + f.edge_v] for f in faces])
    rect, depth = _project_rect(scene.K, scene.R[t], scene.t[t], corners)
    if depth > obj_depth:
        return False
    if rect is None:
        return True
    ix = max(0.0, min(rect[2], obj_rect[2]) - max(rect[0], obj_rect[0]))
    iy = max(0.0, min(rect[3], obj_rect[3]) - max(rect[1], obj_rect[1]))
    area = (obj_rect[2] - obj_rect[0]) * (obj_rect[3] - obj_rect[1])
    return ix * iy > 0.25 * area


def _coverage(scene: Scene, indices: list[int], t: int) -> float:
    render = render_frame(scene, t, surfaces=indices, color=False)
    return float(np.count_nonzero(render.sid != 255)) / render.sid.size


def _size_textures(scene: Scene, rng, bank: TextureBank, background: list[int], water: int | None):
    """Give every background surface a texture whose texels are about one pixel where the surface is seen.

    Texel sizes are set per texture axis: a floor seen at a grazing angle is compressed along the viewing
    direction, and an isotropic texel would be minified (and alias) along it. For each visible pixel of a
    quarter-resolution geometry pass of the first and last frame, the footprint of one full-resolution pixel
    along each texture axis is the norm of that texture coordinate's image gradient (from the plane's
    pixel -> texture homography), in world units; the texel size along the axis is a percentile of it.
    """
    W, H = scene.size
    f = scene.K[0, 0]
    scale = 0.25
    small = (max(8, round(W * scale)), max(8, round(H * scale)))
    Ks = scaled_intrinsics(scene.K, small[0] / W)
    ys, xs = np.mgrid[0 : small[1], 0 : small[0]].astype(np.float64)
    pixels = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    spans: dict[int, list[np.ndarray]] = {i: [] for i in background}
    for t in sorted({0, scene.num_frames - 1}):
        g = render_frame(scene, t, K=Ks, size=small, surfaces=background, color=False)
        for i in background:
            sel = g.sid == i
            if not sel.any():
                continue
            s = scene.surfaces[i]
            A, b = scene.R[t], scene.t[t]
            to_unit = np.linalg.inv(Ks @ np.column_stack([A @ s.edge_u, A @ s.edge_v, A @ s.corner + b]))
            p = pixels[sel]  # (N, 3)
            den = p @ to_unit[2]
            per_axis = []
            for row, edge in ((0, s.edge_u), (1, s.edge_v)):
                coord = (p @ to_unit[row]) / den
                grad = (to_unit[row, :2][None, :] - coord[:, None] * to_unit[2, :2][None, :]) / den[:, None]
                # world length along this axis per full-resolution pixel
                per_axis.append(np.linalg.norm(edge) * np.hypot(grad[:, 0], grad[:, 1]) * (small[0] / W))
            spans[i].append(np.stack(per_axis, axis=1))
    # not seen in the sampled frames (or too thin to show at quarter resolution): a coarse texture, so that it
    # cannot alias if it shows up in between
    unseen = 3.0 * (scene.info["room"]["back_z"] + 4.0) / f
    for i in background:
        s = scene.surfaces[i]
        if spans[i]:
            texel_u, texel_v = np.percentile(np.concatenate(spans[i]), _TEXEL_FOOTPRINT_PERCENTILE, axis=0)
        else:
            texel_u = texel_v = unseen
        # at most 16:1 anisotropy (box tops seen almost edge-on need about that)
        texel_u, texel_v = min(texel_u, 16 * texel_v), min(texel_v, 16 * texel_u)
        tw = max(2, math.ceil(np.linalg.norm(s.edge_u) / max(texel_u, 1e-6)))
        th = max(2, math.ceil(np.linalg.norm(s.edge_v) / max(texel_v, 1e-6)))
        if i == water:
            scale_down = min(1.0, 320.0 / max(tw, th))  # regenerated every frame: keep it small
            tw, th = max(2, round(tw * scale_down)), max(2, round(th * scale_down))
            s.dynamic = WaterTexture(TextureBank.pick(rng, bank.background), tw, th, rng)
            s.texels = (tw, th)
            continue
        photos = bank.materials if (s.name in ("floor", "ceiling") and bank.materials and rng.random() < 0.7) else bank.background
        s.texture = surface_texture(TextureBank.pick(rng, photos), tw, th, rng)
        s.texels = (tw, th)


def sample_scene(
    rng: np.random.Generator,
    frames: int,
    size: tuple[int, int],
    config: SceneConfig | None = None,
    bank: TextureBank | None = None,
) -> Scene:
    """Draw a complete scene for ``frames`` frames of ``size = (W, H)`` from ``rng``.

    The background is a room (floor, ceiling, back and side walls at random depths and angles) with 0-12
    boxes; 1-8 planar sprites move in front of it; the camera translates and rotates smoothly (or is static).
    """
    config = config or SceneConfig()
    bank = bank or TextureBank(config.backgrounds)
    W, H = size
    fov = math.radians(rng.uniform(*config.fov))
    f = (W / 2) / math.tan(fov / 2)
    K = np.array([[f, 0.0, (W - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]])

    n_obj = int(rng.integers(config.num_objects[0], config.num_objects[1] + 1))
    depths = np.sort(rng.uniform(2.6, 5.5, n_obj))
    depths = depths + 0.5 * np.arange(n_obj)  # at least half a unit apart, so sprites rarely intersect
    z_ref = float(np.mean(depths))
    R, t, static = _sample_cameras(rng, frames, f, W, config, z_ref)

    room_surfaces, room = _room(rng)

    # objects: sprites facing the first camera, placed in its view
    C0 = R[0].T
    c0 = -C0 @ t[0]
    K_inv = np.linalg.inv(K)
    target = rng.uniform(*config.fg_fraction)
    shares = rng.dirichlet(np.full(n_obj, 3.0)) if n_obj > 1 else np.ones(1)
    poses, pauses, objects = [], [], []
    for k in range(n_obj):
        Z = depths[k]
        centre_px = np.array([rng.uniform(0.3, 0.7) * W, rng.uniform(0.35, 0.65) * H, 1.0])
        X0 = c0 + C0 @ (K_inv @ centre_px) * Z
        tilt = _rot_y(math.radians(rng.uniform(-20, 20))) @ _rot_x(math.radians(rng.uniform(-15, 15)))
        R_obj0 = C0 @ tilt
        pose, pause = _object_track(rng, frames, config, f, W, Z, R_obj0, X0)
        aspect = rng.uniform(0.6, 1.6)  # height / width
        area_px = target * shares[k] * W * H
        shape_seed = int(rng.integers(2**62))
        probe = sprite_alpha(96, max(8, round(96 * aspect)), np.random.default_rng(shape_seed))
        fill = max(float(np.mean(probe > 0.5)), 0.05)
        width_px = math.sqrt(area_px / (fill * aspect))
        tw = int(np.clip(round(width_px), 8, 2048))
        th = int(np.clip(round(width_px * aspect), 8, 2048))
        alpha = sprite_alpha(tw, th, np.random.default_rng(shape_seed))
        sw = width_px * Z / f
        sh = sw * aspect
        objects.append(
            _quad(f"object {k + 1}", [-sw / 2, -sh / 2, 0.0], [sw, 0, 0], [0, sh, 0], object_id=k + 1, alpha=alpha, texels=(tw, th))
        )
        poses.append(pose)
        pauses.append(pause)

    brightness = None
    if config.brightness_drift > 0:
        steps = rng.uniform(-config.brightness_drift, config.brightness_drift, frames)
        steps[0] = 0.0
        brightness = np.clip(np.cumprod(1.0 + steps), 0.6, 1.4)
    scene = Scene(
        size=(W, H),
        K=K,
        R=R,
        t=t,
        surfaces=objects,
        object_poses=np.stack(poses),
        brightness=brightness,
        static_camera=static,
        info=dict(room=room, fov_deg=math.degrees(fov), target_fg_fraction=target, pauses=pauses),
    )

    # scale the sprites about their centres until they cover the target fraction of the first frame
    object_surfaces = list(range(n_obj))
    for _ in range(3):
        covered = _coverage(scene, object_surfaces, 0)
        if covered <= 0 or abs(covered / target - 1) < 0.03:
            break
        gain = float(np.clip(math.sqrt(target / covered), 0.5, 2.0))
        for s in objects:
            s.corner, s.edge_u, s.edge_v = s.corner * gain, s.edge_u * gain, s.edge_v * gain
    scene.info["fg_fraction_frame0"] = _coverage(scene, object_surfaces, 0)

    # boxes, placed so that they do not hide much of an object (at the start, middle and end of the clip)
    object_views = [_object_rects(scene, k, t_) for k in range(n_obj) for t_ in sorted({0, frames // 2, frames - 1})]
    boxes: list[Surface] = []
    for b in range(int(rng.integers(config.num_boxes[0], config.num_boxes[1] + 1))):
        for _attempt in range(10):
            z = rng.uniform(3.5, max(3.6, room["back_z"] - 1.0))
            column = rng.uniform(-0.1, 1.1) * W
            X = c0 + C0 @ (K_inv @ np.array([column, (H - 1) / 2, 1.0])) * z
            faces = _box(rng, b, room, float(X[0]), float(X[2]))
            if not any(_hides(scene, faces, view) for view in object_views):
                boxes += faces
                break
    water = []
    if rng.random() < config.dynamic_texture_probability:
        pw, pd = rng.uniform(2.0, 5.0), rng.uniform(2.0, 5.0)
        px = rng.uniform(room["left_x"], room["right_x"] - pw)
        pz = rng.uniform(2.0, max(2.1, room["back_z"] - pd))
        # a pool slightly above the floor (no depth fighting), flow is that of the floor
        water.append(_quad("water", [px, room["floor_y"] - 0.003, pz + pd], [pw, 0, 0], [0, 0, -pd]))
    background_surfaces = room_surfaces + boxes + water
    scene.surfaces = background_surfaces + objects
    background = list(range(len(background_surfaces)))
    object_surfaces = [len(background_surfaces) + k for k in range(n_obj)]
    water_index = len(room_surfaces) + len(boxes) if water else None
    scene.info["water"] = water_index

    _size_textures(scene, rng, bank, background, water_index)
    for i in object_surfaces:
        s = scene.surfaces[i]
        s.texture = sprite_texture(TextureBank.pick(rng, bank.foreground), s.alpha, rng)
    return scene
