"""Training losses of the motion net and the fusion: binary cross-entropy (the paper), optionally plus a soft
Jaccard term that optimises the evaluation's region similarity J directly."""

from __future__ import annotations

__all__ = ["LOSSES", "segmentation_loss", "soft_jaccard_loss"]

#: ``bce``: the paper's pixel-wise binary cross-entropy; ``bce+iou``: BCE plus ``iou_weight`` times the mean
#: per-frame soft Jaccard loss.
LOSSES = ("bce", "bce+iou")


def soft_jaccard_loss(logits, target, smooth: float = 1.0):
    """Mean over frames of ``1 - (sum p y + smooth) / (sum (p + y - p y) + smooth)`` with ``p = sigmoid(logits)``.

    ``logits`` and ``target`` (in {0, 1}, or in [0, 1] when distilling) are float tensors ``(N, ...)``; one frame
    is one leading index. The smoothing term keeps frames without foreground well defined: their loss is
    ``sum p / (sum p + smooth)``, zero when nothing is predicted. Scale-free (it does not depend on the frame size) and in [0, 1].
    """
    import torch

    p = torch.sigmoid(logits).flatten(1)
    y = target.flatten(1)
    inter = (p * y).sum(1)
    union = (p + y - p * y).sum(1)
    return (1.0 - (inter + smooth) / (union + smooth)).mean()


def segmentation_loss(logits, target, name: str = "bce", iou_weight: float = 1.0):
    """The training loss ``name`` (one of :data:`LOSSES`) of logits against targets in [0, 1] of the same shape."""
    import torch.nn.functional as F

    if name not in LOSSES:
        raise ValueError(f"loss: expected one of {', '.join(LOSSES)}, got {name!r}")
    bce = F.binary_cross_entropy_with_logits(logits, target)
    if name == "bce":
        return bce
    return bce + iou_weight * soft_jaccard_loss(logits, target)
