"""Real background, pasted foreground: the EpO paper's RBSF data made from annotated videos one already has.

The paper pre-trains its motion network on RBSF (real background videos with synthetic foreground objects,
section 3.4), which it credits with +5.3% J on DAVIS-2016. Here the backgrounds are clips of annotated
DAVIS-layout sequences (their camera motion, parallax and background motion are real) and the foreground is
the annotated object of another sequence, cut out frame by frame (its articulation is real) and pasted over the
background along a path of its own: a motion independent of the camera, which is what the motion network must
find. The background's own object keeps its label, so the ground truth of a clip is the union of the two
objects (the pasted one in front).

A clip is decided by the generator ``rng`` alone (:func:`paste_clip`); :func:`write_pasted` writes clips in
the DAVIS layout, so the training data loaders read them as any other sequence.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from ..core.errors import InputError
from ..core.io import write_mask_png
from .writer import check_writable, write_jpeg, frame_name, resolution_name, sequence_seed, write_index

__all__ = ["PasteSettings", "Sprite", "object_sprites", "paste_path", "paste_clip", "write_pasted"]

log = logging.getLogger(__name__)

#: Windows of an object's sequence tried before one with the object annotated is given up.
_WINDOW_TRIES = 20


@dataclass(frozen=True)
class PasteSettings:
    """How a pasted object looks and moves. ``object_area``: the range of the pasted object's mean area as a
    fraction of the frame (drawn once per clip); ``speed``: the range of its speed in pixels per frame at the
    clip's size; ``scale_rate``: the largest relative change of its size per frame (growing or shrinking, as
    when it comes closer); ``acceleration``: the largest change of its velocity, in pixels per frame squared."""

    object_area: tuple[float, float] = (0.02, 0.25)
    speed: tuple[float, float] = (0.5, 4.0)
    scale_rate: float = 0.01
    acceleration: float = 0.1


@dataclass
class Sprite:
    """One frame's object: ``rgb`` uint8 ``(h, w, 3)`` and ``alpha`` float32 ``(h, w)`` in [0, 1] cropped to the
    mask's bounding box, ``anchor`` the mask's centroid ``(x, y)`` in the crop's pixels. Empty (``alpha`` all zero,
    1 x 1) where the frame has no object."""

    rgb: np.ndarray
    alpha: np.ndarray
    anchor: tuple[float, float]

    @property
    def area(self) -> float:
        return float(self.alpha.sum())


def object_sprites(frames: np.ndarray, masks: np.ndarray) -> list[Sprite]:
    """The annotated object of each frame of a sequence, frames uint8 ``(F, H, W, 3)``, masks ``(F, H, W)``
    (non-zero = object), as :class:`Sprite` s."""
    sprites = []
    for frame, mask in zip(frames, masks):
        ys, xs = np.nonzero(mask)
        if len(xs) == 0:
            sprites.append(Sprite(np.zeros((1, 1, 3), np.uint8), np.zeros((1, 1), np.float32), (0.0, 0.0)))
            continue
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        alpha = (mask[y0:y1, x0:x1] != 0).astype(np.float32)
        sprites.append(Sprite(np.ascontiguousarray(frame[y0:y1, x0:x1]), alpha, (xs.mean() - x0, ys.mean() - y0)))
    return sprites


def _reflect(x: np.ndarray, length: float) -> np.ndarray:
    """``x`` folded into ``[0, length]`` as a ball bouncing off both ends."""
    u = np.mod(x, 2.0 * length)
    return length - np.abs(u - length)


def paste_path(rng: np.random.Generator, frames: int, size: tuple[int, int], settings: PasteSettings):
    """The pasted object's anchor ``(F, 2)`` (x, y pixels, inside the frame: it bounces off the borders) and its
    relative scale ``(F,)`` (1 at the first frame) for ``frames`` frames of ``size = (W, H)``: constant
    acceleration from a random start, direction and speed, and a constant rate of growth or shrinking."""
    W, H = size
    t = np.arange(frames, dtype=np.float64)[:, None]
    start = rng.uniform((0.15 * W, 0.15 * H), (0.85 * W, 0.85 * H))
    angle = rng.uniform(0.0, 2.0 * np.pi)
    speed = rng.uniform(*settings.speed)
    velocity = speed * np.array([np.cos(angle), np.sin(angle)])
    acceleration = rng.uniform(-settings.acceleration, settings.acceleration, 2)
    position = start + velocity * t + 0.5 * acceleration * t**2
    anchor = np.stack([_reflect(position[:, 0], W - 1.0), _reflect(position[:, 1], H - 1.0)], axis=1)
    scale = (1.0 + rng.uniform(-settings.scale_rate, settings.scale_rate)) ** t[:, 0]
    return anchor, scale


def paste_clip(rng: np.random.Generator, frames: np.ndarray, masks: np.ndarray, sprites: list[Sprite],
               settings: PasteSettings = PasteSettings()) -> tuple[np.ndarray, np.ndarray]:
    """Paste ``sprites`` (one per frame) over background ``frames`` uint8 ``(F, H, W, 3)`` whose own object is
    ``masks`` ``(F, H, W)``; returns the composited frames uint8 ``(F, H, W, 3)`` and the ground truth uint8
    ``(F, H, W)`` in {0, 1}: the background's object or the pasted one where its alpha is at least 0.5.

    The pasted object's mean area is a fraction of the frame drawn from ``settings.object_area`` (smaller where
    its largest box would not fit in 90% of the frame), and its anchor (the mask's centroid) follows
    :func:`paste_path`. Frames and the alpha are warped bilinearly, so the pasted edge is one pixel soft."""
    F, H, W = masks.shape
    if len(sprites) != F or frames.shape[:3] != (F, H, W):
        raise ValueError(f"expected {F} frames and sprites of {W}x{H}, got frames {frames.shape}, {len(sprites)} sprites")
    present = [s for s in sprites if s.area > 0]
    if not present:
        raise ValueError("the pasted object is empty in every frame")
    anchor, relative = paste_path(rng, F, (W, H), settings)
    area = rng.uniform(*settings.object_area) * H * W
    scale = np.sqrt(area / np.mean([s.area for s in present]))
    largest = max(max(s.alpha.shape[1] / W, s.alpha.shape[0] / H) for s in present) * scale * relative.max()
    if largest > 0.9:
        scale *= 0.9 / largest
    out = frames.copy()
    truth = (masks != 0).astype(np.uint8)
    for t, sprite in enumerate(sprites):
        if sprite.area == 0:
            continue
        s = scale * relative[t]
        ax, ay = sprite.anchor
        # crop pixel (u, v) -> frame (s u + x0, s v + y0), the anchor landing on the path
        M = np.array([[s, 0.0, anchor[t, 0] - s * ax], [0.0, s, anchor[t, 1] - s * ay]])
        alpha = cv2.warpAffine(sprite.alpha, M, (W, H), flags=cv2.INTER_LINEAR, borderValue=0.0)
        rgb = cv2.warpAffine(sprite.rgb, M, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        a = alpha[..., None]
        out[t] = np.clip(out[t] * (1.0 - a) + rgb * a + 0.5, 0, 255).astype(np.uint8)
        truth[t] |= (alpha >= 0.5).astype(np.uint8)
    return out, truth


def _window(rng: np.random.Generator, length: int, frames: int) -> np.ndarray:
    """Indices of ``frames`` consecutive frames of a sequence of ``length`` (played back and forth if shorter)."""
    if length >= frames:
        start = int(rng.integers(0, length - frames + 1))
        return np.arange(start, start + frames)
    cycle = np.concatenate([np.arange(length), np.arange(length - 2, 0, -1)]) if length > 1 else np.zeros(1, int)
    return cycle[np.arange(frames) % len(cycle)]


def write_pasted(out_dir: str | Path, names: list[str], load: Callable[[str], tuple[np.ndarray, np.ndarray]],
                 clips: int, frames: int, seed: int, settings: PasteSettings = PasteSettings(), *,
                 jpeg_quality: int = 92) -> list[dict]:
    """Write ``clips`` pasted clips of ``frames`` frames (sequences ``paste-0000``, ...) in the DAVIS layout under
    ``out_dir``: for each, a background sequence and a different object sequence drawn from ``names``, and a
    window of ``frames`` frames of each. ``load(name)`` returns a sequence's frames uint8 ``(F, H, W, 3)`` and
    object masks ``(F, H, W)``, all sequences of one size. Deterministic: clip ``i`` depends on ``seed`` and ``i``
    only. Returns the ``db_info`` entries (with the ``background`` and ``object`` sequence of each clip)."""
    if len(names) < 2:
        raise ValueError(f"pasting needs at least two sequences (a background and an object), got {names}")
    out = Path(out_dir)
    check_writable(out)
    cache: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def sequence(name):
        if name not in cache:
            if len(cache) >= 4:  # a few sequences at a time: memory stays bounded on long lists
                cache.pop(next(iter(cache)))
            cache[name] = load(name)
        return cache[name]

    entries = []
    for index in range(int(clips)):
        rng = np.random.default_rng(sequence_seed(seed, index))
        background, thing = rng.choice(len(names), 2, replace=False)
        bg_frames, bg_masks = sequence(names[background])
        fg_frames, fg_masks = sequence(names[thing])
        if bg_frames.shape[1:3] != fg_frames.shape[1:3]:
            raise InputError(f"{names[background]} and {names[thing]}: pasting needs sequences of one size, got "
                             f"{bg_frames.shape[2]}x{bg_frames.shape[1]} and {fg_frames.shape[2]}x{fg_frames.shape[1]}")
        keep = _window(rng, len(bg_frames), frames)
        for _ in range(_WINDOW_TRIES):  # a window where the object is annotated in at least one frame
            take = _window(rng, len(fg_frames), frames)
            if fg_masks[take].any():
                break
        else:
            raise InputError(f"{names[thing]}: no annotated object in {_WINDOW_TRIES} windows of {frames} frames")
        sprites = object_sprites(fg_frames[take], fg_masks[take])
        composite, truth = paste_clip(rng, bg_frames[keep], bg_masks[keep], sprites, settings)
        name = f"paste-{index:04d}"
        res = resolution_name(composite.shape[1])
        for t in range(len(composite)):
            stem = frame_name(t)
            write_jpeg(out / "JPEGImages" / res / name / f"{stem}.jpg", composite[t], jpeg_quality)
            write_mask_png(out / "Annotations" / res / name / f"{stem}.png", truth[t])
        entries.append({"name": name, "attributes": [], "num_frames": int(frames), "set": "train", "eval_t": True,
                        "year": 2016, "background": names[background], "object": names[thing],
                        "background_frames": [int(keep[0]), int(keep[-1])], "object_frames": [int(take[0]), int(take[-1])]})
        log.debug("%s: %s pasted over %s", name, names[thing], names[background])
    write_index(out, entries, extra={"name": "eponet paste", "seed": int(seed), "frames": int(frames),
                                     "sequences": list(names), "object_area": list(settings.object_area),
                                     "speed": list(settings.speed), "scale_rate": settings.scale_rate,
                                     "acceleration": settings.acceleration})
    return entries
