"""Neural networks (torch modules), kept free of pipeline concerns."""

from .unet import ED_ENCODINGS, EpoUNet, INPUT_CHANNELS, encode_ed

__all__ = ["EpoUNet", "INPUT_CHANNELS", "ED_ENCODINGS", "encode_ed"]
