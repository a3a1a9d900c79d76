"""Whole-video inference of the fusion network in overlapping windows, so memory does not grow with length."""

from __future__ import annotations

import numpy as np
import torch

from .convgru import ConvGRUFusion

__all__ = ["BLENDS", "window_starts", "window_weights", "video_logits"]

#: How overlapping windows are stitched: ``centre`` takes each frame from the window in which it lies farthest
#: from an inner window edge; ``linear`` cross-fades the logits over each overlap. ``centre`` is the more
#: accurate: a window's first and last frames see states started from zero, and linear blending still gives
#: them some weight (on the tests' fading-memory GRU, overlap 8: max probability error 2e-4 against 8e-3).
BLENDS = ("linear", "centre")


def window_starts(num_frames: int, window: int | None, overlap: int) -> list[int]:
    """First frames of the windows covering ``num_frames`` frames: windows of ``window`` frames advancing by
    ``window - overlap``; the last window ends at the last frame (so it may overlap its neighbour by more).
    ``window=None`` or ``window >= num_frames``: one window, the whole video.

    >>> window_starts(10, 4, 1)
    [0, 3, 6]
    >>> window_starts(11, 4, 1)
    [0, 3, 6, 7]
    """
    if window is None or window >= num_frames:
        return [0]
    if not 0 <= overlap < window:
        raise ValueError(f"overlap: expected 0 <= overlap < window ({window}), got {overlap}")
    starts = list(range(0, num_frames - window + 1, window - overlap))
    if starts[-1] + window < num_frames:
        starts.append(num_frames - window)
    return starts


def window_weights(starts: list[int], length: int, num_frames: int, blend: str = "linear") -> np.ndarray:
    """Stitching weights float64 ``(len(starts), length)``: for each window, how much each of its frames counts.

    ``linear``: a frame's weight is its distance (in frames, counting from 1) to the nearest *inner* edge of
    its window (an edge shared with a neighbour; the video's own ends are not inner edges), so that over an
    overlap the earlier window fades out linearly while the later one fades in. ``centre``: weight 1 in the
    window where that distance is largest (the earlier window on ties), 0 elsewhere. For every frame the
    weights of the windows covering it are then normalised to sum to 1 by :func:`video_logits`.
    """
    if blend not in BLENDS:
        raise ValueError(f"blend: expected one of {', '.join(BLENDS)}, got {blend!r}")
    index = np.arange(length, dtype=np.float64)
    far = float(length + 1)  # more than any distance to an inner edge
    weights = np.empty((len(starts), length))
    for k in range(len(starts)):
        left = index + 1 if k > 0 else np.full(length, far)
        right = length - index if k < len(starts) - 1 else np.full(length, far)
        weights[k] = np.minimum(left, right)
    if blend == "centre":
        frames = np.asarray(starts)[:, None] + index.astype(int)[None]
        best = np.full(num_frames, -1.0)
        owner = np.zeros(num_frames, int)
        for k in range(len(starts)):  # strict '>' keeps the earlier window on ties
            better = weights[k] > best[frames[k]]
            owner[frames[k][better]] = k
            best[frames[k][better]] = weights[k][better]
        weights = (owner[frames] == np.arange(len(starts))[:, None]).astype(np.float64)
    return weights


def video_logits(model: ConvGRUFusion, features: np.ndarray, saliency: np.ndarray, *, window: int | None = 32,
                 overlap: int = 8, blend: str = "centre", device: torch.device | str = "cpu") -> torch.Tensor:
    """Logits float32 ``(F, h, w)`` at the feature size for a whole video, run in overlapping windows.

    ``features`` float32 ``(F, C, h, w)``, ``saliency`` float32 ``(F, H, W)`` in [0, 1]. With ``window=None``
    (or a video no longer than ``window``) the bidirectional ConvGRU runs over the whole video in one pass, as
    the authors' code does; otherwise each window runs on its own (states start at zero at each window's
    ends) and the windows' logits are stitched as :func:`window_weights` says.

    Memory: the network's working set depends on ``window``, not on the video length ``F``. For one window of
    ``L = min(window, F)`` frames it is about ``4 * L * h * w * (max(2 * bottleneck, bottleneck + 6 * hidden) + 2)``
    bytes (float32: the GRU input, i.e. the bottleneck output with the motion map; the three gate
    pre-activations of the direction running; the states of both directions, one of them while being stacked),
    plus some tens of MB of library workspace. E.g. ``window=32`` with bottleneck 128 and hidden 64: about
    105 MB at 240p (h x w = 30 x 54), 420 MB at 480p (60 x 107). Measured (peak RSS growth, 60 x 107 grid,
    bottleneck 32, hidden 16, window 16): 85 MB for a 32-frame and 87 MB for a 96-frame video, against 160
    and 342 MB with ``window=None``. What grows with ``F`` is only what the caller holds anyway (the inputs,
    ``F * C * h * w`` floats of features, and the saliency maps) and the stitched logits with their weights,
    ``8 * F * h * w`` bytes (float64 sums). ``window=None`` gives up the bound: the working set is then that of
    one window of ``F`` frames.
    """
    num_frames = len(features)
    if len(saliency) != num_frames:
        raise ValueError(f"saliency: expected {num_frames} frames like the features, got {len(saliency)}")
    starts = window_starts(num_frames, window, overlap)
    length = num_frames if len(starts) == 1 else int(window)
    weights = window_weights(starts, length, num_frames, blend)
    total = torch.zeros((num_frames,) + tuple(features.shape[-2:]), dtype=torch.float64)
    norm = torch.zeros(num_frames, dtype=torch.float64)
    model.eval()
    with torch.inference_mode():
        for k, start in enumerate(starts):
            f = torch.from_numpy(np.ascontiguousarray(features[start : start + length], np.float32)).to(device)
            s = torch.from_numpy(np.ascontiguousarray(saliency[start : start + length], np.float32)).to(device)
            logits = model(f[None], s[None])[0].double().cpu()
            w = torch.from_numpy(weights[k])
            total[start : start + length] += w[:, None, None] * logits
            norm[start : start + length] += w
    return (total / norm[:, None, None]).float()
