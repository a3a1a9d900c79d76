"""Neural networks (torch modules), kept free of pipeline concerns."""

from .unet import EpoUNet, INPUT_CHANNELS, encode_ed

__all__ = ["EpoUNet", "INPUT_CHANNELS", "encode_ed"]
