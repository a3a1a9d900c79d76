"""Per-video self-training: an appearance classifier fitted on the motion network's confident pixels.

The motion network sees only motion; where something else moves too (swaying flowers, spray, a screen) or the
object pauses, motion alone cannot tell. Test-time adaptation fits a classifier of *appearance* for each video
(or window of frames) on the pixels the motion map is sure about, and mixes its probability back in, as
unsupervised video segmentation methods have done since Papazoglou & Ferrari's FST (ICCV 2013, colour models
seeded by motion boundaries) and the self-training of test-time adaptation methods:

1. the saliency is averaged onto the appearance features' grid (``(h, w)``, stride 8);
2. pixels above ``foreground`` are positives, below ``background`` negatives (at most ``samples`` of them,
   half of each class, drawn with a seeded generator); with ``foreground_share > 0``, a window where fewer than
   that share of the cells are above ``foreground`` (a small object, or a map that is nowhere sure) takes its
   top ``foreground_share`` of cells as positives instead, as long as they are above ``foreground_floor``; given a
   second map (``motion``, e.g. the motion network's map under a fusion's output), a negative must also be below
   ``background_motion`` there: both cues agree that it is background;
3. an L2-regularised logistic regression on the standardised features (class-balanced loss, L-BFGS);
4. its probability on every grid cell, bilinearly upsampled, is mixed with the saliency:
   ``(1 - weight) * saliency + weight * appearance``.

A window with too few confident pixels of either class (fewer than :data:`MIN_SAMPLES`) keeps its saliency.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MIN_SAMPLES", "self_trained_probability", "fit_appearance", "foreground_threshold"]

#: The fewest confident grid cells of each class a window needs to be self-trained.
MIN_SAMPLES = 20


def fit_appearance(features: np.ndarray, labels: np.ndarray, *, l2: float = 1e-3, iterations: int = 60,
                   samples: int = 60000, seed: int = 0) -> np.ndarray | None:
    """P(foreground) float32 ``(F, h, w)`` of every grid cell of ``features`` float ``(F, C, h, w)``, from a
    logistic regression fitted on the cells whose ``labels`` int8 ``(F, h, w)`` are 1 (foreground) or 0
    (background); -1 is unlabelled. ``None`` when either class has fewer than :data:`MIN_SAMPLES` cells."""
    import torch

    frames, channels, h, w = features.shape
    x = np.asarray(features, np.float32).reshape(frames, channels, h * w)  # a view: no per-cell copy
    y = labels.reshape(-1)
    positive, negative = np.flatnonzero(y == 1), np.flatnonzero(y == 0)
    if min(len(positive), len(negative)) < MIN_SAMPLES:
        return None
    rng = np.random.default_rng(seed)
    half = max(1, samples // 2)
    positive = np.sort(rng.choice(positive, min(half, len(positive)), replace=False))
    negative = np.sort(rng.choice(negative, min(half, len(negative)), replace=False))
    # per-channel mean and std over every cell of the window (any values would do: training and prediction fold
    # the same ones, so they only condition the fit); einsum sums the squares without a copy of the window
    mean = x.mean(axis=(0, 2))
    std = np.sqrt(np.maximum(np.einsum("fcp,fcp->c", x, x) / (frames * h * w) - mean * mean, 0.0)) + 1e-6
    cells = np.concatenate([positive, negative])
    rows = x[cells // (h * w), :, cells % (h * w)]  # (n, C): only the training cells are gathered
    train = torch.from_numpy(((rows - mean) / std).astype(np.float32))
    target = torch.from_numpy(np.r_[np.ones(len(positive)), np.zeros(len(negative))].astype(np.float32))
    balance = torch.from_numpy(np.r_[np.full(len(positive), 0.5 / len(positive)),
                                     np.full(len(negative), 0.5 / len(negative))].astype(np.float32))
    weights = torch.zeros(channels, requires_grad=True)
    bias = torch.zeros(1, requires_grad=True)
    optimiser = torch.optim.LBFGS([weights, bias], max_iter=iterations, line_search_fn="strong_wolfe")

    def closure():
        optimiser.zero_grad()
        logits = train @ weights + bias
        loss = torch.nn.functional.binary_cross_entropy_with_logits(logits, target, reduction="none")
        loss = (loss * balance).sum() + l2 * (weights * weights).sum()
        loss.backward()
        return loss

    optimiser.step(closure)
    # the standardisation folded into the weights: w . (x - mean) / std + b = (w / std) . x + b - w . mean / std
    w_raw = weights.detach().numpy() / std
    b_raw = float(bias.detach()[0]) - float(w_raw @ mean)
    logits = np.matmul(w_raw.astype(np.float32)[None, None, :], x)[:, 0] + np.float32(b_raw)  # (F, h * w)
    return torch.sigmoid(torch.from_numpy(logits)).numpy().reshape(frames, h, w)


def _on_grid(maps: np.ndarray, h: int, w: int) -> np.ndarray:
    """float32 ``(F, h, w)``: each of ``maps`` ``(F, H, W)`` averaged onto the features' grid."""
    import cv2

    return np.stack([cv2.resize(np.asarray(m, np.float32), (w, h), interpolation=cv2.INTER_AREA) for m in maps])


def foreground_threshold(grid: np.ndarray, foreground: float, share: float = 0.0, floor: float = 0.0) -> float:
    """The probability above which a cell of ``grid`` float ``(F, h, w)`` is a foreground example: ``foreground``,
    lowered to the ``1 - share`` quantile of the grid when fewer than ``share`` of its cells are above it, but
    never below ``floor``.

    >>> grid = np.zeros((1, 10, 10)); grid[0, 0, :5] = 0.6      # 5% of the cells, none above 0.8
    >>> foreground_threshold(grid, 0.8), foreground_threshold(grid, 0.8, 0.04, 0.3)
    (0.8, 0.6)
    >>> foreground_threshold(grid, 0.8, 0.04, 0.7)              # not below the floor
    0.7
    """
    if share <= 0:
        return float(foreground)
    return float(min(foreground, max(floor, np.quantile(grid, 1.0 - share))))


def self_trained_probability(features: np.ndarray, saliency: np.ndarray, *, foreground: float = 0.9,
                             background: float = 0.05, weight: float = 0.5, l2: float = 1e-3,
                             iterations: int = 60, samples: int = 60000, seed: int = 0,
                             foreground_share: float = 0.0, foreground_floor: float = 0.5,
                             motion: np.ndarray | None = None, background_motion: float | None = None) -> np.ndarray:
    """Foreground probability float32 ``(F, H, W)`` in [0, 1] from appearance ``features`` float
    ``(F, C, h, w)`` and the motion network's ``saliency`` float ``(F, H, W)`` in [0, 1] (see the module
    docstring); the saliency itself when the window has too few confident pixels.

    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> features = rng.normal(size=(2, 4, 8, 8)).astype(np.float32)
    >>> features[:, 0, 2:6, 2:6] += 4.0                      # the object's appearance: channel 0 is high
    >>> saliency = np.zeros((2, 16, 16), np.float32)
    >>> saliency[:, 4:12, 4:12] = 1.0                        # the motion map found it
    >>> saliency[:, 0:2, 0:2] = 1.0                          # ... and a distractor of background appearance
    >>> p = self_trained_probability(features, saliency, weight=1.0)
    >>> bool(p[:, 6:10, 6:10].mean() > 0.8), bool(p[:, 0, 0].max() < 0.2)   # object kept, distractor dropped
    (True, True)
    """
    import cv2

    frames, height, width = saliency.shape
    h, w = features.shape[2:]
    grid = _on_grid(saliency, h, w)
    labels = np.full(grid.shape, -1, np.int8)
    labels[grid > foreground_threshold(grid, foreground, foreground_share, foreground_floor)] = 1
    background_cells = grid < background
    if motion is not None and background_motion is not None:
        background_cells &= _on_grid(motion, h, w) < background_motion
    labels[background_cells] = 0
    appearance = fit_appearance(features, labels, l2=l2, iterations=iterations, samples=samples, seed=seed)
    if appearance is None:
        return np.asarray(saliency, np.float32)
    upsampled = np.stack([cv2.resize(a, (width, height), interpolation=cv2.INTER_LINEAR) for a in appearance])
    return np.clip((1.0 - weight) * saliency + weight * upsampled, 0.0, 1.0).astype(np.float32)
