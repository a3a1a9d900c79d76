"""Motion images: the (dx, dy, ED) input of the motion network, and the ED scaling and encoding it reads.

This module is the one home of the ED normalisation: the pipeline, the trainers and the motion-net stage all
use :func:`normalise_ed` (scale) and :func:`encode_ed` (saturation as a network was trained).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .types import FlowPair

__all__ = [
    "FLOW_SCALE",
    "ED_ENCODINGS",
    "FLOW_CENTRINGS",
    "flow_spread_problem",
    "ED_PERCENTILE",
    "ED_TARGET",
    "ED_FLOOR_PX",
    "ED_WINDOW",
    "ED_SAMPLE",
    "shrunk_means",
    "ed_frame_sample",
    "ed_window_scale",
    "ed_scales",
    "normalise_ed",
    "encode_ed",
    "motion_images",
    "frame_flow",
    "mirror_motion_images",
]

#: Flow channels are divided by this many pixels *of the processing resolution* (at the paper's 427x240,
#: a displacement of 20 px, i.e. ~5% of the width, becomes 1.0). Values are not clipped.
FLOW_SCALE = 20.0

#: How a motion network saturates the scaled ED channel (1 = 250/255 of the 95th percentile): ``clip`` at 1,
#: as the original's uint8 images did, or ``log``: unchanged up to 1, ``1 + ln(ED)`` above, which keeps the ED
#: of small fast objects (often tens of times the percentile) apart from the background's (:func:`encode_ed`).
ED_ENCODINGS = ("clip", "log")

#: What a motion network subtracts from each frame's flow channels (``eponet.nets.unet.centre_flow``): nothing (the
#: paper), ``rigid``: the median flow of the frame's pixels whose ED is at most the frame's median ED, or ``affine``:
#: an affine flow field fitted to those pixels (``eponet.nets.unet.affine_flow_residual``).
FLOW_CENTRINGS = ("none", "rigid", "affine")

def flow_spread_problem(window) -> str | None:
    """Why ``window`` is not a valid ``flow_spread`` of a motion network (``eponet.nets.unet.flow_spread``): None
    for 0 (off) or an odd integer of at least 3 pixels, else the message."""
    if window == 0 or (isinstance(window, int) and window >= 3 and window % 2 == 1):
        return None
    return f"expected 0 (off) or an odd window of at least 3 pixels, got {window}"


#: Percentile of the ED values around a frame that sets its scale.
ED_PERCENTILE = 95.0
#: The value the percentile is mapped to (as in the original: 250 of 255).
ED_TARGET = 250.0 / 255.0
#: Lowest scale in pixels, so that a video whose ED is only flow noise is not stretched to full range.
ED_FLOOR_PX = 1.0
#: Frames of the centred window whose ED sets a frame's scale (frame t uses frames t - 30 .. t + 30): the
#: original used the whole video, which a stream cannot see and which mixes unrelated scenes in a long video.
#: A DAVIS clip (50-104 frames) sees most of itself; a stream needs ``ED_WINDOW // 2`` frames of look-ahead.
ED_WINDOW = 61
#: At most this many values of a frame enter the percentile (a systematic subsample of its finite values).
ED_SAMPLE = 4096


def shrunk_means(sums: np.ndarray, counts: np.ndarray, prior_groups: float) -> tuple[np.ndarray, float]:
    """Each trajectory's mean distance, shrunk toward the median of the means by ``prior_groups`` groups' worth.

    ``(sums + k m) / (counts + k)`` with ``m`` the median of ``sums / counts`` over the scored trajectories: the
    posterior mean of a trajectory's distance when its groups are noisy measurements and ``m`` is the prior,
    worth ``k`` groups (empirical Bayes). A trajectory scored in one or two groups (spray, motion blur, an
    occlusion edge, whose flow is least reliable) moves toward the typical distance; one scored in many keeps
    its own. ``k = 0`` is the plain mean.

    Parameters
    ----------
    sums : float (T,)
        Summed distances in pixels.
    counts : int (T,)
        Scored groups per trajectory.
    prior_groups : float
        ``k >= 0``.

    Returns
    -------
    means : float32 (T,)
        NaN where ``counts`` is 0.
    median : float
        ``m`` (pixels; 0.0 when nothing is scored).

    >>> means, m = shrunk_means(np.array([1.0, 4.0, 30.0]), np.array([1, 2, 10]), 2.0)
    >>> m, [round(float(v), 3) for v in means]
    (2.0, [1.667, 2.0, 2.833])
    """
    scored = counts > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        plain = sums / np.maximum(counts, 1)
    median = float(np.median(plain[scored])) if scored.any() else 0.0
    means = plain if prior_groups == 0 else (sums + prior_groups * median) / (counts + prior_groups)
    return np.where(scored, means, np.nan).astype(np.float32), median


def ed_frame_sample(ed_frame: np.ndarray, size: int = ED_SAMPLE) -> np.ndarray:
    """The values of one ED map ``(H, W)`` that enter the scale: its finite values, every k-th of them in
    raster order when there are more than ``size`` (deterministic, so a stream and a whole video agree).
    Returns float32 ``(n,)`` with ``n <= size``."""
    values = np.asarray(ed_frame, dtype=np.float32).ravel()
    values = values[np.isfinite(values)]
    step = -(-values.size // size) if values.size > size else 1
    return values[::step]


def ed_window_scale(samples: Sequence[np.ndarray], *, percentile: float = ED_PERCENTILE,
                    floor: float = ED_FLOOR_PX) -> float:
    """Scale in pixels from the frame samples of a window: the ``percentile`` of their union, at least
    ``floor`` (``floor`` when there is no value)."""
    values = np.concatenate([np.asarray(s, np.float32).ravel() for s in samples]) if samples else np.zeros(0)
    if values.size == 0:
        return float(floor)
    return float(max(np.percentile(values, percentile), floor))


def ed_scales(ed_maps: np.ndarray, *, window: int | None = ED_WINDOW, percentile: float = ED_PERCENTILE,
              floor: float = ED_FLOOR_PX) -> np.ndarray:
    """Per-frame ED scales float64 ``(F,)`` in pixels of ED maps ``(F, H, W)``.

    Frame t's scale is :func:`ed_window_scale` of the samples of frames ``t - window // 2 .. t + window // 2``
    (cut at the ends of the video); ``window=None`` gives every frame the whole video's scale (the original's
    per-video normalisation). A stream that holds ``window // 2`` frames of look-ahead computes exactly these
    values (the same per-frame samples, :func:`ed_frame_sample`).
    """
    samples = [ed_frame_sample(frame) for frame in np.asarray(ed_maps)]
    if window is None:
        return np.full(len(samples), ed_window_scale(samples, percentile=percentile, floor=floor))
    if window < 1:
        raise ValueError(f"window must be a positive number of frames or None, got {window}")
    half = window // 2
    return np.array([ed_window_scale(samples[max(0, t - half): t + half + 1], percentile=percentile, floor=floor)
                     for t in range(len(samples))])


def normalise_ed(
    ed_maps: np.ndarray,
    *,
    scales: np.ndarray | None = None,
    window: int | None = ED_WINDOW,
    percentile: float = ED_PERCENTILE,
    target: float = ED_TARGET,
    floor: float = ED_FLOOR_PX,
    saturate: bool = True,
) -> np.ndarray:
    """ED scaled for the motion net: ``out[t] = ed[t] * target / s[t]``.

    ``s`` are the per-frame scales of :func:`ed_scales` (``window`` frames around each frame; ``None``: the
    whole video), or the given ``scales``. With the defaults the 95th percentile around a frame maps to
    250/255. The floor (1 px) keeps a static or perfectly rigid video, whose ED is only flow noise, near 0
    instead of stretching its noise to the full range. NaN becomes 0 and +inf ``2 * target``'s worth.

    With ``saturate=True`` values are clipped at 1, as the original's uint8 images were; with ``False`` (what
    the pipeline gives the motion net) the strongest values stay above 1 (the ED of a small, fast object can
    be tens of times the percentile) and the network's :func:`encode_ed` saturates them its own way.

    Parameters
    ----------
    ed_maps : array (F, H, W)
        Epipolar distances in pixels.

    Returns
    -------
    array (F, H, W) float32 in [0, 1] (``saturate``) or [0, inf)

    Examples
    --------
    >>> ed = np.ones((2, 4, 4), np.float32) * np.array([2.0, 4.0], np.float32)[:, None, None]
    >>> normalise_ed(ed, window=None)[:, 0, 0].astype(float).round(3).tolist()  # the whole video: P95 = 4 px
    [0.49, 0.98]
    >>> normalise_ed(ed, window=1)[:, 0, 0].astype(float).round(3).tolist()  # each frame alone
    [0.98, 0.98]
    """
    ed_maps = np.asarray(ed_maps, dtype=np.float32)
    if scales is None:
        scales = ed_scales(ed_maps, window=window, percentile=percentile, floor=floor)
    scales = np.asarray(scales, np.float64).reshape(-1, *([1] * (ed_maps.ndim - 1)))
    factor = (target / scales).astype(np.float32)
    out = np.nan_to_num(ed_maps, nan=0.0, posinf=0.0, neginf=0.0) * factor
    out = np.where(np.isposinf(ed_maps), np.float32(2 * target), out).astype(np.float32, copy=False)
    return np.clip(out, 0.0, 1.0 if saturate else None, out=out)


def encode_ed(ed, encoding: str):
    """Saturate scaled ED values (>= 0) as ``encoding`` says (:data:`ED_ENCODINGS`); a torch tensor or a
    numpy array, same shape and type."""
    if encoding not in ED_ENCODINGS:
        raise ValueError(f"ed_encoding must be one of {ED_ENCODINGS}, got {encoding!r}")
    if isinstance(ed, np.ndarray):
        if encoding == "clip":
            return np.minimum(ed, 1.0)
        return np.where(ed > 1.0, 1.0 + np.log(np.maximum(ed, 1.0)), ed).astype(ed.dtype, copy=False)
    import torch

    if encoding == "clip":
        return ed.clamp(max=1.0)
    return torch.where(ed > 1.0, 1.0 + torch.log(ed.clamp(min=1.0)), ed)


def frame_flow(flow: FlowPair) -> np.ndarray:
    """Per-frame motion ``(F, H, W, 2)``: ``forward[t]`` for t < F-1 and, for the last frame (which has no
    forward flow), the negated backward flow of the last pair, which lives on the last frame's grid (the
    original code reused frame F-2's flow there, on the wrong grid)."""
    return np.concatenate([flow.forward, -flow.backward[-1:]], axis=0)


def motion_images(flow: FlowPair, ed_normalised: np.ndarray) -> np.ndarray:
    """Stack ``(dx / FLOW_SCALE, dy / FLOW_SCALE, ED_normalised)`` into float32 ``(F, 3, H, W)``.

    ``ed_normalised`` is the scaled ED ``(F, H, W)`` of :func:`normalise_ed`: the pipeline passes it
    unsaturated (the 95th percentile at 250/255, the strongest values above 1) and the motion net saturates it
    as it was trained to (:func:`encode_ed`). Channel order is (dx, dy, ED) (the original code stored
    (dy, dx, ED) as lossy JPEGs).
    """
    motion = frame_flow(flow) / FLOW_SCALE
    return np.concatenate([motion.transpose(0, 3, 1, 2), ed_normalised[:, None]], axis=1).astype(np.float32)


def mirror_motion_images(images: np.ndarray) -> np.ndarray:
    """The motion images ``(..., 3, H, W)`` of the left-right mirrored video: columns reversed and dx negated
    (dy and ED are unchanged by a mirror). A new, contiguous array."""
    mirrored = np.ascontiguousarray(images[..., ::-1])
    mirrored[..., 0, :, :] *= -1
    return mirrored
