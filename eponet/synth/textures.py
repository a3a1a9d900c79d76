"""Photographic textures, sprite alpha shapes and water-like dynamic textures for the synthetic scenes."""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.io import list_images, read_image

__all__ = [
    "BUNDLED_PHOTOS",
    "TextureBank",
    "bundled_photos",
    "folder_photos",
    "surface_texture",
    "sprite_alpha",
    "WaterTexture",
]

log = logging.getLogger(__name__)

#: Photographs that ship inside the scikit-image wheel (read from ``skimage.data.data_dir`` directly, so
#: nothing is ever fetched). Grey ones are tinted when used. Synthetic or medical images are left out.
BUNDLED_PHOTOS = (
    "astronaut.png",
    "chelsea.png",
    "coffee.png",
    "rocket.jpg",
    "motorcycle_left.png",
    "hubble_deep_field.jpg",
    "brick.png",
    "grass.png",
    "gravel.png",
    "camera.png",
    "coins.png",
    "moon.png",
)
#: Photos that look like surfaces (used preferentially for floors).
_MATERIALS = ("brick.png", "grass.png", "gravel.png")
#: Photos are downscaled to this longest side once, when loaded.
_MAX_PHOTO_SIDE = 1024


@dataclass(frozen=True)
class Photo:
    """A source photograph: bundled ones are decoded up front, a user's on first use (``path``)."""

    name: str
    pixels: np.ndarray | None  # uint8 (H, W, 3), or None until decoded from ``path``
    grey: bool
    path: str | None = None

    @property
    def rgb(self) -> np.ndarray:
        """uint8 ``(H, W, 3)``, longest side at most ``_MAX_PHOTO_SIDE``."""
        return self.pixels if self.pixels is not None else _decode_user_photo(self.path)


def _bounded(rgb: np.ndarray) -> np.ndarray:
    import cv2

    side = max(rgb.shape[:2])
    if side > _MAX_PHOTO_SIDE:
        scale = _MAX_PHOTO_SIDE / side
        rgb = cv2.resize(rgb, (round(rgb.shape[1] * scale), round(rgb.shape[0] * scale)), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(rgb)


@functools.lru_cache(maxsize=1)
def bundled_photos() -> tuple[Photo, ...]:
    """The bundled scikit-image photographs that are present, loaded once per process."""
    import skimage.data
    from PIL import Image

    photos = []
    for name in BUNDLED_PHOTOS:
        path = Path(skimage.data.data_dir) / name
        if not path.is_file():  # a different scikit-image version: skip, never download
            log.debug("bundled photo %s not found in %s", name, path.parent)
            continue
        with Image.open(path) as image:
            grey = image.mode in ("L", "I", "I;16", "1")
            rgb = np.asarray(image.convert("RGB"), dtype=np.uint8)
        photos.append(Photo(name, _bounded(rgb), grey))
    if not photos:
        raise InputError(f"{skimage.data.data_dir}: none of scikit-image's bundled photographs were found")
    return tuple(photos)


@functools.lru_cache(maxsize=32)
def _decode_user_photo(path: str) -> np.ndarray:
    return _bounded(read_image(path))


@functools.lru_cache(maxsize=4)
def _folder_photos_cached(folder: str) -> tuple[Photo, ...]:
    from PIL import Image, UnidentifiedImageError

    path = Path(folder)
    if not path.is_dir():
        raise InputError(f"{folder}: --backgrounds is not a folder")
    files = list_images(path)
    if not files:
        raise InputError(f"{folder}: --backgrounds folder holds no images (.jpg, .png, ...)")
    for f in files:  # check every header now; decode lazily (a folder may hold thousands of photos)
        try:
            with Image.open(f) as image:
                image.verify()
        except (OSError, UnidentifiedImageError, ValueError) as exc:
            raise InputError(f"{f}: cannot read image ({exc.__class__.__name__}: {exc})") from None
    return tuple(Photo(f.name, None, False, str(f)) for f in files)


def folder_photos(folder: str | Path) -> tuple[Photo, ...]:
    """All images directly inside ``folder`` in natural order (an empty or missing folder is an InputError)."""
    return _folder_photos_cached(str(Path(folder).resolve()))


class TextureBank:
    """Where textures come from: the user's background photos (if any) and the bundled photographs.

    Background surfaces use the user's folder when one is given, else the bundled photos; foreground sprites
    use the bundled photos (plus the user's).
    """

    def __init__(self, backgrounds: str | Path | None = None):
        bundled = bundled_photos()
        user = folder_photos(backgrounds) if backgrounds is not None else ()
        self.background = user or bundled
        # the moon is too flat to be a useful foreground texture
        self.foreground = tuple(p for p in bundled if p.name != "moon.png") + user
        self.materials = tuple(p for p in bundled if p.name in _MATERIALS) if not user else user

    @staticmethod
    def pick(rng: np.random.Generator, photos: tuple[Photo, ...]) -> Photo:
        return photos[int(rng.integers(len(photos)))]


def _gains(photo: Photo, rng: np.random.Generator) -> np.ndarray:
    """Per-channel gains: a random tint for grey photos, a mild colour jitter for colour ones."""
    if photo.grey:
        tint = rng.uniform(0.45, 1.0, 3)
        return tint / tint.max()
    return rng.uniform(0.85, 1.1, 3)


def _apply_gains(rgb: np.ndarray, gains: np.ndarray) -> np.ndarray:
    import cv2

    levels = np.arange(256, dtype=np.float64)[:, None] * gains[None, :]
    lut = np.clip(levels + 0.5, 0, 255).astype(np.uint8).reshape(256, 1, 3)
    return cv2.LUT(np.ascontiguousarray(rgb), lut)


def _colourise(photo: Photo, rng: np.random.Generator) -> np.ndarray:
    """Photo as float32 RGB in [0, 255] with :func:`_gains` applied."""
    return photo.rgb.astype(np.float32) * _gains(photo, rng).astype(np.float32)


def surface_texture(photo: Photo, width: int, height: int, rng: np.random.Generator, *, max_side: int = 1024) -> np.ndarray:
    """RGBA uint8 texture (alpha 255) for a surface of ``width x height`` texels, cut from ``photo``.

    The photo is flipped at random, scaled to about cover the surface (at most 2x up) and slightly blurred
    (sigma 0.5 texel); the texture is at most ``max_side`` texels a side and the renderer tiles it by
    mirroring (seamless) where the surface is larger.
    """
    import cv2

    rgb = photo.rgb[:, ::-1] if rng.random() < 0.5 else photo.rgb
    ph, pw = rgb.shape[:2]
    scale = float(np.clip(max(width / pw, height / ph) * rng.uniform(0.6, 1.0), 0.25, 2.0))
    ow, oh = max(2, round(pw * scale)), max(2, round(ph * scale))
    cw, ch = min(ow, max_side, width), min(oh, max_side, height)
    cw, ch = max(cw, 2), max(ch, 2)
    ox = rng.uniform(0, ow - cw) if ow > cw else 0.0
    oy = rng.uniform(0, oh - ch) if oh > ch else 0.0
    # the source window that becomes the (cw, ch) texture
    sx0, sy0 = int(ox / scale), int(oy / scale)
    sx1 = min(pw, max(sx0 + 1, int(np.ceil((ox + cw) / scale))))
    sy1 = min(ph, max(sy0 + 1, int(np.ceil((oy + ch) / scale))))
    crop = np.ascontiguousarray(rgb[sy0:sy1, sx0:sx1])
    interp = cv2.INTER_AREA if crop.shape[1] > cw else cv2.INTER_LINEAR
    crop = cv2.resize(crop, (cw, ch), interpolation=interp)
    # a slight blur, like a camera's optics: less aliasing where the surface is seen minified
    crop = cv2.GaussianBlur(crop, (0, 0), 0.5)
    return cv2.cvtColor(_apply_gains(crop, _gains(photo, rng)), cv2.COLOR_RGB2RGBA)


def _shape_polygon(kind: str, rng: np.random.Generator) -> np.ndarray:
    """A closed outline in the unit square (N, 2), centred, touching a 0.9-wide box."""
    theta = np.linspace(0, 2 * np.pi, 180, endpoint=False)
    if kind == "ellipse":
        r = np.ones_like(theta)
    elif kind == "blob":
        r = np.ones_like(theta)
        for k in range(2, 6):
            r += rng.uniform(0.0, 0.3 / k) * np.cos(k * theta + rng.uniform(0, 2 * np.pi))
    elif kind == "star":
        spikes = int(rng.integers(4, 7))
        r = 1.0 + rng.uniform(0.15, 0.3) * np.cos(spikes * theta + rng.uniform(0, 2 * np.pi))
    else:  # rounded box (superellipse)
        n = rng.uniform(3.0, 6.0)
        c, s = np.cos(theta), np.sin(theta)
        r = (np.abs(c) ** n + np.abs(s) ** n) ** (-1.0 / n)
    pts = np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1)
    pts -= pts.min(axis=0)
    pts /= pts.max(axis=0)
    return 0.05 + 0.9 * pts


@functools.lru_cache(maxsize=1)
def _horse_silhouette() -> np.ndarray | None:
    import skimage.data
    from PIL import Image

    path = Path(skimage.data.data_dir) / "horse.png"
    if not path.is_file():
        return None
    with Image.open(path) as image:
        grey = np.asarray(image.convert("L"))
    return (grey < 128).astype(np.float32)


SPRITE_SHAPES = ("blob", "ellipse", "star", "box", "horse")


def sprite_alpha(width: int, height: int, rng: np.random.Generator, kind: str | None = None) -> np.ndarray:
    """Anti-aliased alpha float32 ``(height, width)`` in [0, 1] of a random shape, zero on a border of at least
    two texels (so bilinear sampling never reaches the texture edge)."""
    import cv2

    kind = kind or SPRITE_SHAPES[int(rng.integers(len(SPRITE_SHAPES)))]
    margin = 2
    inner_w, inner_h = max(4, width - 2 * margin), max(4, height - 2 * margin)
    horse = _horse_silhouette() if kind == "horse" else None
    if horse is not None:
        shape = horse[:, ::-1] if rng.random() < 0.5 else horse
        ys, xs = np.nonzero(shape)
        shape = np.ascontiguousarray(shape[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1])
        inner = cv2.resize(shape, (inner_w, inner_h), interpolation=cv2.INTER_AREA)
    else:
        if kind == "horse":
            kind = "blob"
        ss = 4  # supersampling for smooth edges
        canvas = np.zeros((inner_h * ss, inner_w * ss), np.uint8)
        poly = _shape_polygon(kind, rng) * [inner_w * ss - 1, inner_h * ss - 1]
        cv2.fillPoly(canvas, [np.round(poly * 16).astype(np.int32)], 255, lineType=cv2.LINE_AA, shift=4)
        inner = cv2.resize(canvas.astype(np.float32) / 255.0, (inner_w, inner_h), interpolation=cv2.INTER_AREA)
    alpha = np.zeros((height, width), np.float32)
    alpha[margin : margin + inner_h, margin : margin + inner_w] = np.clip(inner[: height - 2 * margin, : width - 2 * margin], 0, 1)
    return alpha


def sprite_texture(photo: Photo, alpha: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """RGBA uint8 texture for a sprite: a random crop of ``photo`` with ``alpha`` (x255) in channel 3."""
    import cv2

    height, width = alpha.shape
    rgb = photo.rgb
    ph, pw = rgb.shape[:2]
    aspect = width / height
    cw = min(pw, ph * aspect) * rng.uniform(0.5, 1.0)
    ch = cw / aspect
    x0 = rng.uniform(0, pw - cw)
    y0 = rng.uniform(0, ph - ch)
    crop = np.ascontiguousarray(rgb[int(y0) : int(y0 + ch) + 1, int(x0) : int(x0 + cw) + 1])
    crop = cv2.resize(crop, (width, height), interpolation=cv2.INTER_AREA if crop.shape[1] > width else cv2.INTER_LINEAR)
    out = cv2.cvtColor(_apply_gains(crop, _gains(photo, rng)), cv2.COLOR_RGB2RGBA)
    out[..., 3] = np.round(alpha * 255).astype(np.uint8)  # the same rounding as Surface.alpha8
    return out


class WaterTexture:
    """A water-like texture that changes every frame (the "dynamic background" attribute).

    A sum of travelling waves gives a height field; its slopes shade a base colour, add glints, and distort a
    reflected photo. Deterministic: frame ``t`` depends only on the parameters drawn at construction.
    """

    def __init__(self, photo: Photo, width: int, height: int, rng: np.random.Generator):
        import cv2

        self.width, self.height = width, height
        n = 5
        wavelength = rng.uniform(0.08, 0.3, n) * max(width, height)
        angle = rng.uniform(0, 2 * np.pi, n)
        self.k = np.stack([np.cos(angle), np.sin(angle)], 1) * (2 * np.pi / wavelength)[:, None]
        self.omega = rng.uniform(0.15, 0.45, n) * rng.choice([-1, 1], n)
        self.phase = rng.uniform(0, 2 * np.pi, n)
        self.amp = rng.uniform(0.5, 1.0, n) / n
        # largest possible slope, to normalise the shading
        self.max_slope = float(np.sum(self.amp * np.hypot(self.k[:, 0], self.k[:, 1])))
        self.base = np.array(rng.uniform([20, 60, 80], [60, 120, 150]), np.float32)
        reflection = cv2.resize(_colourise(photo, rng), (width, height), interpolation=cv2.INTER_AREA)
        self.reflection = np.ascontiguousarray(reflection[::-1])
        self._x = np.arange(width, dtype=np.float32)[None, :]
        self._y = np.arange(height, dtype=np.float32)[:, None]

    def frame(self, t: int) -> np.ndarray:
        """RGBA uint8 ``(height, width, 4)`` at frame ``t``."""
        import cv2

        sx = np.zeros((self.height, self.width), np.float32)
        sy = np.zeros_like(sx)
        for (kx, ky), om, ph, a in zip(self.k, self.omega, self.phase, self.amp):
            arg = (kx * self._x) + (ky * self._y + np.float32(ph - om * t))
            c = np.cos(arg) * np.float32(a)
            sx += np.float32(kx) * c
            sy += np.float32(ky) * c
        norm = np.float32(1.0 / self.max_slope)
        sx *= norm
        sy *= norm
        gain = np.float32(0.02 * max(self.width, self.height))  # reflection distortion, texels
        mx = self._x + gain * sx
        my = self._y + gain * sy
        refl = cv2.remap(self.reflection, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        shade = np.float32(1.0) + np.float32(0.35) * (sx + sy)
        glint = np.clip(shade - 1.2, 0, None) * np.float32(600.0)
        rgb = 0.55 * refl + (0.45 * shade)[..., None] * self.base + glint[..., None]
        out = np.empty((self.height, self.width, 4), np.uint8)
        out[..., :3] = np.clip(rgb, 0, 255).astype(np.uint8)
        out[..., 3] = 255
        return out
