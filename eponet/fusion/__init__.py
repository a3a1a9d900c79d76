"""The EpO+ fusion network (bidirectional ConvGRU over appearance features and the motion map) and its
windowed whole-video inference."""

from .convgru import ConvGRUCell, ConvGRUFusion, resize_saliency
from .windows import BLENDS, video_logits, window_starts, window_weights

__all__ = ["ConvGRUCell", "ConvGRUFusion", "resize_saliency", "BLENDS", "video_logits", "window_starts",
           "window_weights"]
