"""Augmentation: random crops, horizontal flips and input-dropout, of motion-image batches (ED channel) and of
fusion clips (the motion map).

Each random step is also split into a ``draw_*`` (the random numbers, from shapes alone) and an ``apply_*``:
under DDP every process draws the whole global batch's augmentation from the epoch's generator, as one process
does, and applies it to its own samples only."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from eponet.core.motion import mirror_motion_images

__all__ = ["InputDropout", "CropFlip", "ClipCropFlip", "random_crop_flip", "draw_crop_flip", "apply_crop_flip",
           "shift_flow", "draw_flow_shift", "random_clip_crop_flip", "draw_clip_crop_flip", "apply_clip_crop_flip",
           "drop_motion_maps", "draw_motion_drops"]

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

    def draw(self, count: int, shape: tuple[int, int], epoch: int, rng: np.random.Generator,
             dtype=np.float32) -> tuple[np.ndarray, np.ndarray | None]:
        """Which of ``count`` samples of maps ``shape`` ``(H, W)`` are chosen (boolean ``(count,)``) and their
        replacement ED maps ``(chosen, H, W)`` (None when no sample is chosen), drawn as :meth:`apply` draws them."""
        chosen = rng.random(count) < self.probability
        number = int(chosen.sum())
        if not number:
            return chosen, None
        shape = (number,) + tuple(shape)
        mode = "zero" if epoch < self.zero_epochs else self.then
        if mode == "zero":
            return chosen, np.zeros(shape, dtype)
        if mode == "noise":
            return chosen, np.clip(rng.normal(0.0, self.noise_std, shape), 0, None).astype(dtype)
        return chosen, rng.random(shape).astype(dtype)

    def apply(self, batch: np.ndarray, epoch: int, rng: np.random.Generator) -> np.ndarray:
        """Return a copy of motion images ``(B, 3, H, W)`` with the ED channel replaced in the chosen samples,
        and the boolean ``(B,)`` selection as a second value."""
        batch = batch.copy()
        chosen, replacement = self.draw(len(batch), batch.shape[2:], epoch, rng, batch.dtype)
        if replacement is not None:
            batch[chosen, ED_CHANNEL] = replacement
        return batch, chosen


@dataclass(frozen=True)
class CropFlip:
    """Where a sample is cut (rows ``y : y + height``, columns ``x : x + width``) and whether it is mirrored; with
    ``source`` ``(h, w)``, a zoom: the window cut is ``h x w`` pixels at ``(y, x)``, resized to ``height x
    width``."""

    y: int
    x: int
    height: int
    width: int
    flip: bool
    source: tuple[int, int] | None = None


def draw_crop_flip(shape: tuple[int, int], crop: tuple[int, int] | None, flip: bool,
                   rng: np.random.Generator, zoom: tuple[float, float] | None = None) -> CropFlip:
    """The random crop (of ``crop`` ``(h, w)``, at most ``shape`` ``(H, W)``) and flip of one sample, drawn as
    :func:`random_crop_flip` draws them.

    With ``zoom`` ``(low, high)`` (and a crop) the sample is also magnified by a factor drawn log-uniformly from
    that range: a window of ``crop / factor`` pixels is cut and resized to ``crop``, so the network sees the
    scene's objects nearer (> 1) or farther (< 1) than the camera filmed them. The factor is raised where the
    window would not fit in the frame. Without ``zoom`` the draws are the same as before the option existed."""
    height, width = shape
    y = x = 0
    source = None
    if crop is not None:
        height, width = min(crop[0], shape[0]), min(crop[1], shape[1])
        window = (height, width)
        if zoom is not None:
            factor = float(np.exp(rng.uniform(np.log(zoom[0]), np.log(zoom[1]))))
            factor = max(factor, height / shape[0], width / shape[1])
            window = (min(shape[0], round(height / factor)), min(shape[1], round(width / factor)))
            source = window if window != (height, width) else None
        y = int(rng.integers(0, shape[0] - window[0] + 1))
        x = int(rng.integers(0, shape[1] - window[1] + 1))
    return CropFlip(y, x, height, width, bool(flip and rng.random() < 0.5), source)


def apply_crop_flip(images: np.ndarray, masks: np.ndarray, box: CropFlip) -> tuple[np.ndarray, np.ndarray]:
    """Motion images ``(3, H, W)`` and the mask ``(H, W)`` cut to ``box`` and, when it says so, flipped
    left-right (dx negated). A zoomed box's window is resized to the box's size: the images bilinearly, with the
    flow channels (dx, dy) multiplied by the magnification along their axis (the normalised ED is the video's own
    scale and stays); the mask by its nearest pixel."""
    h, w = box.source or (box.height, box.width)
    images = images[:, box.y : box.y + h, box.x : box.x + w]
    masks = masks[box.y : box.y + h, box.x : box.x + w]
    if box.source is not None:
        size = (box.width, box.height)
        images = np.moveaxis(cv2.resize(np.ascontiguousarray(np.moveaxis(images, 0, -1)), size,
                                        interpolation=cv2.INTER_LINEAR), -1, 0)
        images[0] *= box.width / w
        images[1] *= box.height / h
        masks = cv2.resize(np.ascontiguousarray(masks), size, interpolation=cv2.INTER_NEAREST)
    if box.flip:
        images = mirror_motion_images(images)
        masks = masks[:, ::-1]
    return np.ascontiguousarray(images), np.ascontiguousarray(masks)


def random_crop_flip(images: np.ndarray, masks: np.ndarray, crop: tuple[int, int] | None, flip: bool,
                     rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Crop motion images ``(3, H, W)`` and the mask ``(H, W)`` to ``crop`` ``(h, w)`` at a random place and flip
    both left-right with probability 1/2 (negating dx, the horizontal flow)."""
    return apply_crop_flip(images, masks, draw_crop_flip(masks.shape, crop, flip, rng))


def draw_flow_shift(count: int, std: float, rng: np.random.Generator) -> np.ndarray | None:
    """The random constants ``(count, 2, 1, 1)`` float32 that :func:`shift_flow` adds (None when ``std == 0``)."""
    if std <= 0:
        return None
    return rng.normal(0.0, std, (count, ED_CHANNEL, 1, 1)).astype(np.float32)


def shift_flow(batch: np.ndarray, std: float, rng: np.random.Generator) -> np.ndarray:
    """Motion images ``(B, 3, H, W)`` with a random constant, normal with standard deviation ``std`` (normalised
    flow units), added to each sample's dx and to its dy: the same scene seen by a camera panning at another
    speed, whose rigid background ED does not change. ED is untouched; ``std == 0`` returns ``batch`` itself."""
    shifts = draw_flow_shift(len(batch), std, rng)
    if shifts is None:
        return batch
    batch = batch.copy()
    batch[:, :ED_CHANNEL] += shifts.astype(batch.dtype)
    return batch


@dataclass(frozen=True)
class ClipCropFlip:
    """A fusion clip's crop: feature cells ``cells`` ``(y0, y1, x0, x1)`` and the frame pixels ``pixels`` they
    cover (``None``: the whole clip), and whether the clip is mirrored."""

    cells: tuple[int, int, int, int] | None
    pixels: tuple[int, int, int, int] | None
    flip: bool


def draw_clip_crop_flip(cells: tuple[int, int], pixels: tuple[int, int], crop: tuple[int, int] | None, flip: bool,
                        rng: np.random.Generator) -> ClipCropFlip:
    """The random crop and flip of a clip whose features have ``cells`` ``(h, w)`` and whose maps have ``pixels``
    ``(H, W)``, drawn as :func:`random_clip_crop_flip` draws them."""
    feature_box = pixel_box = None
    if crop is not None:
        box = []
        for c, size, full in zip(crop, cells, pixels):
            n = min(size, max(1, round(c * size / full)))
            first = int(rng.integers(0, size - n + 1))
            box.append((first, first + n, round(first * full / size), min(full, round((first + n) * full / size))))
        (y0, y1, py0, py1), (x0, x1, px0, px1) = box
        feature_box, pixel_box = (y0, y1, x0, x1), (py0, py1, px0, px1)
    return ClipCropFlip(feature_box, pixel_box, bool(flip and rng.random() < 0.5))


def apply_clip_crop_flip(features: np.ndarray, saliency: np.ndarray, masks: np.ndarray,
                         box: ClipCropFlip) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A fusion clip (features ``(T, C, h, w)``, saliency and masks ``(T, H, W)``) cut to ``box`` and, when it
    says so, mirrored left-right."""
    if box.cells is not None:
        (y0, y1, x0, x1), (py0, py1, px0, px1) = box.cells, box.pixels
        features = features[..., y0:y1, x0:x1]
        saliency, masks = saliency[..., py0:py1, px0:px1], masks[..., py0:py1, px0:px1]
    if box.flip:
        features, saliency, masks = features[..., ::-1], saliency[..., ::-1], masks[..., ::-1]
    return tuple(np.ascontiguousarray(a) for a in (features, saliency, masks))


def random_clip_crop_flip(features: np.ndarray, saliency: np.ndarray, masks: np.ndarray, crop: tuple[int, int] | None,
                          flip: bool, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Crop and flip a fusion clip, the same way on every frame: features ``(T, C, h, w)`` on the feature grid,
    motion saliency ``(T, H, W)`` and masks ``(T, H, W)`` at the frame size.

    ``crop`` ``(height, width)`` is in frame pixels; the crop is chosen on the feature grid (the nearest whole
    number of cells) and the frame-size maps are cut at the matching pixels, cell ``i`` covering pixels
    ``[i * H / h, (i + 1) * H / h)`` as in the fusion network's resizing. Flips mirror all three left-right
    (the cached features are mirrored, not recomputed on mirrored frames).
    """
    box = draw_clip_crop_flip(features.shape[-2:], masks.shape[-2:], crop, flip, rng)
    return apply_clip_crop_flip(features, saliency, masks, box)


def draw_motion_drops(shape, probability: float, rng: np.random.Generator) -> np.ndarray:
    """Which motion maps of ``shape`` (e.g. a clip's ``(T,)``) :func:`drop_motion_maps` zeroes: boolean."""
    return rng.random(shape) < probability


def drop_motion_maps(saliency: np.ndarray, probability: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Input-dropout of the fusion (paper section 5.2): a copy of motion saliency maps ``(..., H, W)`` with each
    map replaced by zeros with ``probability``, and the boolean selection ``saliency.shape[:-2]``."""
    chosen = draw_motion_drops(saliency.shape[:-2], probability, rng)
    saliency = saliency.copy()
    saliency[chosen] = 0
    return saliency, chosen
