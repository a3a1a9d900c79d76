"""Refiner ``densecrf``: fully connected CRF (Kraehenbuehl & Koltun, NIPS 2011) as in the EpO-Net code."""

from __future__ import annotations

import numpy as np

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.core.progress import track

__all__ = ["DenseCrfRefiner", "densecrf_mask"]


def densecrf_mask(
    frame: np.ndarray,
    probability: np.ndarray,
    *,
    iterations: int = 5,
    gaussian_sxy: float = 3.0,
    gaussian_compat: float = 3.0,
    bilateral_sxy: float = 50.0,
    bilateral_srgb: float = 10.0,
    bilateral_compat: float = 5.0,
    normalise: bool = True,
    scale: float = 1.0,
    max_size: int | None = None,
    crop_margin: float | None = None,
) -> np.ndarray:
    """Binary mask uint8 ``(H, W)`` from an RGB ``frame`` uint8 ``(H, W, 3)`` and P(fg) float ``(H, W)``.

    As in the authors' ``crf_motion.py``: the probability is min-max normalised per frame (``normalise``),
    unary = -log(p) with p clipped at 1e-5, a Gaussian kernel (sxy 3, compat 3) and a bilateral kernel
    (sxy 50, srgb 10, compat 5), both DIAG_KERNEL / NORMALIZE_SYMMETRIC, 5 mean-field iterations, argmax.
    A constant probability map (max = min, where the original divides by zero) is used as it is.

    With ``scale < 1`` the CRF runs on a downscaled frame (spatial standard deviations scaled alike) and the
    marginals are upsampled bilinearly before the argmax: about 1/scale^2 times faster, slightly softer
    boundaries. ``max_size`` (px) caps the longer side the CRF runs at, so its cost per frame stays bounded
    whatever the input size: the effective scale is ``min(scale, max_size / max(H, W))``.

    ``crop_margin`` (in bilateral widths ``bilateral_sxy``): run the CRF only on the bounding box of the pixels
    whose (normalised) probability is above 0.5, grown by that margin on every side, and call every pixel outside
    it background; no pixel above 0.5: all background, as the CRF itself answers then (its Potts terms only pull
    labels together, so no pixel can leave the label its unary prefers when all prefer one). The bilateral
    kernel's weight at 3 widths is exp(-4.5) = 0.011, so a margin of 3 changes few pixels, and the cost falls
    with the box's area. ``None``: the whole frame, as the original code.
    """
    p = probability.astype(np.float32)
    if normalise:
        lo, hi = float(p.min()), float(p.max())
        if hi > lo:
            p = (p - lo) / (hi - lo)
    p = np.clip(p, 0.0, 1.0)
    full_size = p.shape
    if max_size is not None:
        scale = min(scale, max_size / max(full_size))
    if scale < 1.0:
        import cv2

        small = (max(8, int(round(full_size[1] * scale))), max(8, int(round(full_size[0] * scale))))
        frame = cv2.resize(frame, small, interpolation=cv2.INTER_AREA)
        p = cv2.resize(p, small, interpolation=cv2.INTER_LINEAR)
        gaussian_sxy, bilateral_sxy = gaussian_sxy * scale, bilateral_sxy * scale
    box = (slice(None), slice(None))
    if crop_margin is not None:
        rows, cols = np.flatnonzero((p > 0.5).any(axis=1)), np.flatnonzero((p > 0.5).any(axis=0))
        if not len(rows):
            return np.zeros(full_size, np.uint8)
        grow = int(np.ceil(crop_margin * bilateral_sxy))
        box = (slice(max(0, rows[0] - grow), rows[-1] + 1 + grow), slice(max(0, cols[0] - grow), cols[-1] + 1 + grow))
    margin = np.full(p.shape, -1.0, np.float32)
    margin[box] = _crf_margin(frame[box], p[box], iterations, gaussian_sxy, gaussian_compat, bilateral_sxy,
                              bilateral_srgb, bilateral_compat)
    if margin.shape != full_size:
        import cv2

        margin = cv2.resize(margin, (full_size[1], full_size[0]), interpolation=cv2.INTER_LINEAR)
    return (margin > 0).astype(np.uint8)


def _crf_margin(frame: np.ndarray, p: np.ndarray, iterations: int, gaussian_sxy: float, gaussian_compat: float,
                bilateral_sxy: float, bilateral_srgb: float, bilateral_compat: float) -> np.ndarray:
    """Q(fg) - Q(bg) float32 ``(H, W)`` after the mean-field iterations of pydensecrf on ``frame`` and P(fg) ``p``."""
    import pydensecrf.densecrf as dcrf
    from pydensecrf.utils import unary_from_softmax

    height, width = p.shape
    crf = dcrf.DenseCRF2D(width, height, 2)
    crf.setUnaryEnergy(np.ascontiguousarray(unary_from_softmax(np.stack([1.0 - p, p]))))
    crf.addPairwiseGaussian(sxy=gaussian_sxy, compat=gaussian_compat, kernel=dcrf.DIAG_KERNEL,
                            normalization=dcrf.NORMALIZE_SYMMETRIC)
    crf.addPairwiseBilateral(sxy=bilateral_sxy, srgb=bilateral_srgb, rgbim=np.ascontiguousarray(frame, dtype=np.uint8),
                             compat=bilateral_compat, kernel=dcrf.DIAG_KERNEL, normalization=dcrf.NORMALIZE_SYMMETRIC)
    q = np.asarray(crf.inference(iterations)).reshape(2, height, width)
    return q[1] - q[0]


class DenseCrfRefiner:
    """Dense CRF per frame on the min-max normalised probability (defaults from the original code)."""

    def __init__(self, **params):
        self.params = params

    def refine(self, frames: np.ndarray, probability: np.ndarray) -> np.ndarray:
        masks = np.empty(probability.shape, np.uint8)
        for t in track(range(len(frames)), desc="refiner (densecrf)", total=len(frames)):
            masks[t] = densecrf_mask(frames[t], probability[t], **self.params)
        return masks


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="refiner",
            name="densecrf",
            factory=DenseCrfRefiner,
            params=(
                Param("iterations", "int", 5, "mean-field iterations", minimum=1),
                Param("gaussian_sxy", "float", 3.0, "spatial std of the Gaussian kernel (px)", minimum=0.0, exclusive_min=True),
                Param("gaussian_compat", "float", 3.0, "weight of the Gaussian kernel", minimum=0.0),
                Param("bilateral_sxy", "float", 50.0, "spatial std of the bilateral kernel (px)", minimum=0.0, exclusive_min=True),
                Param("bilateral_srgb", "float", 10.0, "colour std of the bilateral kernel (0-255)", minimum=0.0, exclusive_min=True),
                Param("bilateral_compat", "float", 5.0, "weight of the bilateral kernel", minimum=0.0),
                Param("normalise", "bool", True, "min-max normalise the probability per frame first (original code)"),
                Param("scale", "float", 1.0, "run at this fraction of the frame size (1 = as the original code)",
                      minimum=0.1, maximum=1.0),
                Param("max_size", "int", None, "run at most at this longer side in px (null = no cap)",
                      minimum=16, nullable=True),
                Param("crop_margin", "float", None, "run only on the box around the pixels above 0.5, grown by this "
                      "many bilateral widths (background outside; null = the whole frame)", minimum=0.0, nullable=True),
            ),
            doc="dense CRF (pydensecrf) with the EpO-Net defaults",
        )
    ]
