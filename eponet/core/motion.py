"""Motion images: the (dx, dy, ED) input of the motion network, normalised by documented constants."""

from __future__ import annotations

import numpy as np

from .types import FlowPair

__all__ = ["FLOW_SCALE", "ED_ENCODINGS", "motion_images", "frame_flow", "mirror_motion_images"]

#: Flow channels are divided by this many pixels *of the processing resolution* (at the paper's 427x240,
#: a displacement of 20 px, i.e. ~5% of the width, becomes 1.0). Values are not clipped.
FLOW_SCALE = 20.0

#: How a motion network saturates the per-video scaled ED channel (1 = 250/255 of the video's 95th
#: percentile): ``clip`` at 1, as the original's uint8 images did, or ``log``: unchanged up to 1, ``1 + ln(ED)``
#: above, which keeps the ED of small fast objects (often tens of times the percentile) apart from the
#: background's. See ``eponet.nets.encode_ed``.
ED_ENCODINGS = ("clip", "log")


def frame_flow(flow: FlowPair) -> np.ndarray:
    """Per-frame motion ``(F, H, W, 2)``: ``forward[t]`` for t < F-1 and, for the last frame (which has no
    forward flow), the negated backward flow of the last pair, which lives on the last frame's grid (the
    original code reused frame F-2's flow there, on the wrong grid)."""
    return np.concatenate([flow.forward, -flow.backward[-1:]], axis=0)


def motion_images(flow: FlowPair, ed_normalised: np.ndarray) -> np.ndarray:
    """Stack ``(dx / FLOW_SCALE, dy / FLOW_SCALE, ED_normalised)`` into float32 ``(F, 3, H, W)``.

    ``ed_normalised`` is the per-video normalised ED ``(F, H, W)`` (see ``eponet.geometry.normalise_ed``): the
    pipeline passes it unsaturated (the 95th percentile at 250/255, the strongest 5% above 1) and the motion
    net saturates it as it was trained to (``EpoUNet`` ``ed_encoding``).
    Channel order is (dx, dy, ED) (the original code stored (dy, dx, ED) as lossy JPEGs).
    """
    motion = frame_flow(flow) / FLOW_SCALE
    return np.concatenate([motion.transpose(0, 3, 1, 2), ed_normalised[:, None]], axis=1).astype(np.float32)


def mirror_motion_images(images: np.ndarray) -> np.ndarray:
    """The motion images ``(..., 3, H, W)`` of the left-right mirrored video: columns reversed and dx negated
    (dy and ED are unchanged by a mirror). A new, contiguous array."""
    mirrored = np.ascontiguousarray(images[..., ::-1])
    mirrored[..., 0, :, :] *= -1
    return mirrored
