"""One synthetic clip with exact ground truth: frames, masks, flow both ways, occlusions, cameras, depth."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..core.types import MIN_FRAMES
from .render import NO_SURFACE, exact_flow, lookup, occlusion_mask, render_frame
from .scene import Scene, SceneConfig, sample_scene
from .textures import TextureBank

__all__ = ["Clip", "generate_clip", "clip_attributes", "check_size"]

#: DAVIS "fast motion": mean per-frame displacement of the object centroid above 20 px at 854x480.
_FAST_MOTION_PX_AT_854 = 20.0


@dataclass(eq=False)
class Clip:
    """A generated clip. Conventions are those of :mod:`eponet.core.types`.

    ``frames`` uint8 ``(F, H, W, 3)`` RGB; ``masks`` uint8 ``(F, H, W)`` in {0, 1} (union of the objects);
    ``object_ids`` uint8 ``(F, H, W)`` (0 = background, k = object k); ``forward`` / ``backward`` float32
    ``(F-1, H, W, 2)``; ``occlusion_forward[t]`` is True where a pixel of frame t is hidden in (or leaves)
    frame t+1, ``occlusion_backward[t]`` where a pixel of frame t+1 is hidden in frame t; ``K`` (3, 3),
    ``R`` (F, 3, 3), ``t`` (F, 3) world-to-camera (``x_cam = R X + t``); ``depth`` float32 ``(F, H, W)``
    (camera z); ``dynamic`` bool ``(F, H, W)`` where a dynamic (water) texture is seen.
    """

    frames: np.ndarray
    masks: np.ndarray
    object_ids: np.ndarray
    forward: np.ndarray
    backward: np.ndarray
    occlusion_forward: np.ndarray
    occlusion_backward: np.ndarray
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    depth: np.ndarray
    static_camera: bool
    dynamic: np.ndarray
    attributes: list[str] = field(default_factory=list)
    seed: int | None = None
    scene: Scene | None = field(default=None, repr=False)

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def num_objects(self) -> int:
        return 0 if self.scene is None else self.scene.num_objects

    @property
    def size(self) -> tuple[int, int]:
        """``(W, H)``."""
        return int(self.frames.shape[2]), int(self.frames.shape[1])


def check_size(size) -> tuple[int, int]:
    """``(W, H)`` as ints, each at least 16 and at most 8192, else ``ValueError``."""
    try:
        w, h = (int(v) for v in size)
        ok = len(tuple(size)) == 2 and all(int(v) == v for v in size)
    except (TypeError, ValueError):
        ok = False
    if not ok or not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise ValueError(f"size: expected (W, H) with 16 <= W, H <= 8192, got {size!r}")
    return w, h


def clip_attributes(clip: Clip, supports: np.ndarray, visible: np.ndarray) -> list[str]:
    """DAVIS attributes that the ground truth decides: DB (dynamic background), FM (fast motion), OCC
    (an object more than 10% hidden), OV (an object touches the frame border). ``supports``/``visible``:
    (F, N) pixels of each object before/after the depth test."""
    import cv2

    W, H = clip.size
    out = []
    if clip.dynamic.reshape(clip.num_frames, -1).mean(axis=1).max(initial=0) > 0.01:
        out.append("DB")
    masks = clip.masks
    centroids = []
    for m in masks:
        moments = cv2.moments(m, binaryImage=True)
        area = moments["m00"]
        centroids.append((moments["m10"] / area, moments["m01"] / area) if area else (np.nan, np.nan))
    steps = np.linalg.norm(np.diff(np.array(centroids), axis=0), axis=1)
    if np.isfinite(steps).any() and np.nanmean(steps) > _FAST_MOTION_PX_AT_854 * W / 854:
        out.append("FM")
    with np.errstate(invalid="ignore", divide="ignore"):
        hidden = 1.0 - visible / supports
    if np.nanmax(np.where(supports > 0, hidden, np.nan), initial=0) > 0.1:
        out.append("OCC")
    if masks[:, 0].any() or masks[:, -1].any() or masks[:, :, 0].any() or masks[:, :, -1].any():
        out.append("OV")
    return out


def generate_clip(
    seed: int,
    frames: int,
    size: tuple[int, int],
    config: SceneConfig | None = None,
    *,
    on_frame: Callable[[], None] | None = None,
) -> Clip:
    """Generate one RBSF-style clip with exact ground truth; the same arguments give bit-identical output.

    Parameters
    ----------
    seed : int
        Seeds the ``numpy.random.Generator`` that draws the whole scene.
    frames : int
        Number of frames F (at least 3).
    size : (W, H)
        Frame size in pixels.
    config : SceneConfig, optional
        What to draw (defaults: 1-3 objects covering 30-50% of the frame, see :class:`SceneConfig`).
    on_frame : callable, optional
        Called once per finished frame (progress bars).

    Examples
    --------
    >>> clip = generate_clip(0, 5, (160, 96))
    >>> clip.frames.shape, clip.forward.shape
    ((5, 96, 160, 3), (4, 96, 160, 2))
    """
    W, H = check_size(size)
    if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < MIN_FRAMES:
        raise ValueError(f"frames: expected an integer >= {MIN_FRAMES}, got {frames!r}")
    config = config or SceneConfig()
    rng = np.random.default_rng(seed)
    scene = sample_scene(rng, int(frames), (W, H), config, TextureBank(config.backgrounds))
    F = int(frames)
    obj_lut = scene.object_of_surface()
    dyn_lut = scene.dynamic_surfaces()
    object_surfaces = [i for i, s in enumerate(scene.surfaces) if s.object_id]

    out_frames = np.empty((F, H, W, 3), np.uint8)
    object_ids = np.empty((F, H, W), np.uint8)
    depth = np.empty((F, H, W), np.float32)
    dynamic = np.empty((F, H, W), bool)
    forward = np.empty((F - 1, H, W, 2), np.float32)
    backward = np.empty((F - 1, H, W, 2), np.float32)
    occ_f = np.empty((F - 1, H, W), bool)
    occ_b = np.empty((F - 1, H, W), bool)
    supports = np.zeros((F, scene.num_objects))
    visible = np.zeros((F, scene.num_objects))

    previous = None
    for t in range(F):
        current = render_frame(scene, t)
        if (current.sid == NO_SURFACE).any():  # the room encloses every camera; a hole is a bug
            raise RuntimeError(f"seed {seed}, frame {t}: {int((current.sid == NO_SURFACE).sum())} pixels see no surface")
        out_frames[t] = current.rgb
        object_ids[t] = lookup(obj_lut, current.sid)
        np.divide(1.0, current.inv_depth, out=depth[t])
        dynamic[t] = lookup(dyn_lut, current.sid).view(bool)
        for k, i in enumerate(object_surfaces):
            supports[t, k] = current.support[i]
        visible[t] = np.bincount(object_ids[t].ravel(), minlength=scene.num_objects + 1)[1:]
        if previous is not None:
            fwd, w_fwd = exact_flow(scene, previous, t - 1, t, obj_lut)
            bwd, w_bwd = exact_flow(scene, current, t, t - 1, obj_lut)
            forward[t - 1], backward[t - 1] = fwd, bwd
            occ_f[t - 1] = occlusion_mask(fwd, w_fwd, previous, current)
            occ_b[t - 1] = occlusion_mask(bwd, w_bwd, current, previous)
        previous = current
        if on_frame is not None:
            on_frame()

    clip = Clip(
        frames=out_frames,
        masks=(object_ids > 0).astype(np.uint8),
        object_ids=object_ids,
        forward=forward,
        backward=backward,
        occlusion_forward=occ_f,
        occlusion_backward=occ_b,
        K=scene.K.copy(),
        R=scene.R.copy(),
        t=scene.t.copy(),
        depth=depth,
        static_camera=scene.static_camera,
        dynamic=dynamic,
        seed=seed,
        scene=scene,
    )
    clip.attributes = clip_attributes(clip, supports, visible)
    return clip
