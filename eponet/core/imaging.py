"""Resizing of dense maps between the processing and input resolutions, the forward-backward flow test, and
visualisations."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["resize_flow", "resize_map", "fb_consistent", "flow_to_color", "heat_map", "overlay_mask",
           "fill_from_neighbourhood"]


def resize_flow(flow: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Resize flow ``(H, W, 2)`` to ``shape`` ``(h, w)``, scaling the vectors with the grid (bilinear)."""
    height, width = flow.shape[:2]
    if (height, width) == tuple(shape):
        return flow.astype(np.float32, copy=False)
    out = cv2.resize(flow, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)
    out[..., 0] *= shape[1] / width
    out[..., 1] *= shape[0] / height
    return out.astype(np.float32, copy=False)


def resize_map(values: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Bilinear resize of a float map ``(H, W)`` to ``shape`` ``(h, w)``."""
    if values.shape[:2] == tuple(shape):
        return values.astype(np.float32, copy=False)
    return cv2.resize(values.astype(np.float32), (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)


def fb_consistent(fx: np.ndarray, fy: np.ndarray, bx: np.ndarray, by: np.ndarray, *, relative: float = 0.01,
                  absolute: float = 0.5) -> np.ndarray:
    """The tolerance forward-backward test of Sundaram, Brox & Keutzer (ECCV 2010), elementwise: a point's flow
    ``f = (fx, fy)`` is consistent with the flow ``b = (bx, by)`` read back at its target iff
    ``|f + b|^2 < relative (|f|^2 + |b|^2) + absolute`` (pixels^2). The components come as separate arrays of one
    shape: a reduction over a last axis of 2 is several times slower.

    >>> fb_consistent(np.float32([3.0, 3.0]), np.float32([0, 0]), np.float32([-3.0, -1.0]), np.float32([0, 0])).tolist()
    [True, False]
    """
    error = (fx + bx) ** 2 + (fy + by) ** 2
    return error < relative * (fx * fx + fy * fy + bx * bx + by * by) + absolute


def flow_to_color(flow: np.ndarray, max_magnitude: float | None = None) -> np.ndarray:
    """Colour-code flow ``(H, W, 2)`` as uint8 RGB (hue = direction, saturation = magnitude)."""
    dx, dy = flow[..., 0], flow[..., 1]
    magnitude, angle = cv2.cartToPolar(dx.astype(np.float32), dy.astype(np.float32), angleInDegrees=True)
    scale = max_magnitude or max(float(np.percentile(magnitude, 99)), 1e-6)
    hsv = np.empty(flow.shape[:2] + (3,), np.uint8)
    hsv[..., 0] = (angle / 2).astype(np.uint8)
    hsv[..., 1] = np.clip(magnitude / scale * 255, 0, 255).astype(np.uint8)
    hsv[..., 2] = 255
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)


def heat_map(values: np.ndarray, vmax: float | None = None) -> np.ndarray:
    """uint8 RGB heat map (inferno-like, OpenCV's INFERNO) of a non-negative map ``(H, W)``."""
    top = vmax if vmax is not None else max(float(np.percentile(values, 99)), 1e-6)
    scaled = np.clip(np.nan_to_num(values) / top * 255, 0, 255).astype(np.uint8)
    return cv2.cvtColor(cv2.applyColorMap(scaled, cv2.COLORMAP_INFERNO), cv2.COLOR_BGR2RGB)


def overlay_mask(frame: np.ndarray, mask: np.ndarray, color=(255, 40, 40), alpha: float = 0.45) -> np.ndarray:
    """Frame ``(H, W, 3)`` RGB with the mask tinted and its contour drawn."""
    out = frame.copy()
    fg = mask.astype(bool)
    out[fg] = (out[fg] * (1 - alpha) + np.array(color) * alpha).astype(np.uint8)
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(out, contours, -1, (255, 255, 0), thickness=max(1, frame.shape[0] // 240))
    return out


def fill_from_neighbourhood(image: np.ndarray, valid: np.ndarray, fallback: float = 0.0) -> np.ndarray:
    """Replace invalid pixels by the value of the nearest valid pixel (Euclidean distance, 5x5 mask).

    Used for the pixels of trajectories too short to be scored: they take the value of the nearest longer
    trajectory in the same frame rather than 0 (a zero fill, the original's choice, hides moving objects).

    Parameters
    ----------
    image : array (H, W)
    valid : bool array (H, W)
    fallback : float
        Value used when no pixel is valid.

    Returns
    -------
    array (H, W) float32
    """
    image = np.asarray(image, dtype=np.float32)
    if valid.all():
        return image.copy()
    if not valid.any():
        return np.full(image.shape, fallback, np.float32)
    holes = (~valid).astype(np.uint8)
    _, nearest = cv2.distanceTransformWithLabels(holes, cv2.DIST_L2, 5, labelType=cv2.DIST_LABEL_PIXEL)
    # labels 1..K enumerate the valid (zero) pixels in row-major order
    lut = np.concatenate([[np.float32(fallback)], image[valid]])
    return lut[nearest]
