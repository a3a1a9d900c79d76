"""Augmentation: random crops, horizontal flips and input-dropout, of motion-image batches (ED channel) and of
fusion clips (the motion map)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from eponet.core.motion import mirror_motion_images

__all__ = ["InputDropout", "random_crop_flip", "shift_flow", "random_clip_crop_flip", "drop_motion_maps"]

ED_CHANNEL = 2


@dataclass(frozen=True)
class InputDropout:
    """Input-dropout of the paper (sections 4.2 and 6.1): for a fraction ``probability`` of the training samples
    the ED channel is replaced, so the network learns to fall back on flow where ED is wrong.

    During the first ``zero_epochs`` epochs the replaced ED is all zeros; afterwards it is ``then``:
    ``zero`` (zeros), ``noise`` (zeros plus Gaussian noise of std ``noise_std``, clipped at 0) or ``random``
    (uniform values in [0, 1], the range of normalised ED). Flow channels are never touched.
    """

    probability: float = 0.2
    zero_epochs: int = 10
    then: str = "noise"
    noise_std: float = 0.05

    def apply(self, batch: np.ndarray, epoch: int, rng: np.random.Generator) -> np.ndarray:
        """Return a copy of motion images ``(B, 3, H, W)`` with the ED channel replaced in the chosen samples,
        and the boolean ``(B,)`` selection as a second value."""
        batch = batch.copy()
        chosen = rng.random(len(batch)) < self.probability
        count = int(chosen.sum())
        if count:
            shape = (count,) + batch.shape[2:]
            mode = "zero" if epoch < self.zero_epochs else self.then
            if mode == "zero":
                replacement = np.zeros(shape, batch.dtype)
            elif mode == "noise":
                replacement = np.clip(rng.normal(0.0, self.noise_std, shape), 0, None).astype(batch.dtype)
            else:
                replacement = rng.random(shape).astype(batch.dtype)
            batch[chosen, ED_CHANNEL] = replacement
        return batch, chosen


def random_crop_flip(images: np.ndarray, masks: np.ndarray, crop: tuple[int, int] | None, flip: bool,
                     rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Crop motion images ``(3, H, W)`` and the mask ``(H, W)`` to ``crop`` ``(h, w)`` at a random place and flip
    both left-right with probability 1/2 (negating dx, the horizontal flow)."""
    height, width = masks.shape
    if crop is not None:
        ch, cw = min(crop[0], height), min(crop[1], width)
        y = int(rng.integers(0, height - ch + 1))
        x = int(rng.integers(0, width - cw + 1))
        images, masks = images[:, y : y + ch, x : x + cw], masks[y : y + ch, x : x + cw]
    if flip and rng.random() < 0.5:
        images = mirror_motion_images(images)
        masks = masks[:, ::-1]
    return np.ascontiguousarray(images), np.ascontiguousarray(masks)


def shift_flow(batch: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """Motion images ``(B, 3, H, W)`` with a random constant, normal with standard deviation ``std`` (normalised
    flow units), added to each sample's dx and to its dy: the same scene seen by a camera panning at another
    speed, whose rigid background ED does not change. ED is untouched; ``std == 0`` returns ``batch`` itself."""
    if std <= 0:
        return batch
    batch = batch.copy()
    batch[:, :ED_CHANNEL] += rng.normal(0.0, std, (len(batch), ED_CHANNEL, 1, 1)).astype(batch.dtype)
    return batch


def random_clip_crop_flip(features: np.ndarray, saliency: np.ndarray, masks: np.ndarray, crop: tuple[int, int] | None,
                          flip: bool, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Crop and flip a fusion clip, the same way on every frame: features ``(T, C, h, w)`` on the feature grid,
    motion saliency ``(T, H, W)`` and masks ``(T, H, W)`` at the frame size.

    ``crop`` ``(height, width)`` is in frame pixels; the crop is chosen on the feature grid (the nearest whole
    number of cells) and the frame-size maps are cut at the matching pixels, cell ``i`` covering pixels
    ``[i * H / h, (i + 1) * H / h)`` as in the fusion network's resizing. Flips mirror all three left-right
    (the cached features are mirrored, not recomputed on mirrored frames).
    """
    cells, pixels = features.shape[-2:], masks.shape[-2:]
    if crop is not None:
        box = []
        for c, size, full in zip(crop, cells, pixels):
            n = min(size, max(1, round(c * size / full)))
            first = int(rng.integers(0, size - n + 1))
            box.append((first, first + n, round(first * full / size), min(full, round((first + n) * full / size))))
        (y0, y1, py0, py1), (x0, x1, px0, px1) = box
        features = features[..., y0:y1, x0:x1]
        saliency, masks = saliency[..., py0:py1, px0:px1], masks[..., py0:py1, px0:px1]
    if flip and rng.random() < 0.5:
        features, saliency, masks = features[..., ::-1], saliency[..., ::-1], masks[..., ::-1]
    return tuple(np.ascontiguousarray(a) for a in (features, saliency, masks))


def drop_motion_maps(saliency: np.ndarray, probability: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Input-dropout of the fusion (paper section 5.2): a copy of motion saliency maps ``(..., H, W)`` with each
    map replaced by zeros with ``probability``, and the boolean selection ``saliency.shape[:-2]``."""
    chosen = rng.random(saliency.shape[:-2]) < probability
    saliency = saliency.copy()
    saliency[chosen] = 0
    return saliency, chosen
