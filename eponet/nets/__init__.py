"""Neural networks (torch modules), kept free of pipeline concerns."""

from .unet import INPUT_CHANNELS, EpoUNet, InferenceUNet

__all__ = ["EpoUNet", "INPUT_CHANNELS", "InferenceUNet"]
