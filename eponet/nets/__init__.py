"""Neural networks (torch modules), kept free of pipeline concerns."""

from .unet import EpoUNet, INPUT_CHANNELS

__all__ = ["EpoUNet", "INPUT_CHANNELS"]
