"""The EpO motion network: a U-Net on motion images (paper section 4.2)."""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from eponet.core.motion import ED_ENCODINGS, encode_ed

__all__ = ["EpoUNet", "INPUT_CHANNELS"]

#: Which channels of a (dx, dy, ED) motion image each input modality uses.
INPUT_CHANNELS = {"ed+flow": (0, 1, 2), "flow": (0, 1), "ed": (2,)}


def _conv_bn_relu(cin: int, cout: int, kernel: int = 3) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, kernel, padding=kernel // 2, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


class EpoUNet(nn.Module):
    """U-Net of the paper: ``depth`` encoder blocks (conv, BatchNorm, ReLU, max-pool), a bottleneck block,
    ``depth`` decoder blocks (bilinear upsampling to the skip's size, concatenation, conv, BatchNorm, ReLU),
    a 1x1 layer to ``head_channels`` (128 in the paper) and a 1x1 classifier.

    Input: float ``(B, C, H, W)`` with C = ``len(INPUT_CHANNELS[inputs])``; any H, W (not only multiples of
    2**depth: the decoder resizes to each skip's size). Output: logits ``(B, 1, H, W)``; apply a sigmoid for
    the foreground probability. :meth:`select_inputs` turns the pipeline's motion images into that input,
    saturating the ED channel as ``ed_encoding`` says (``clip``, the paper's, or ``log``).
    """

    def __init__(self, *, inputs: str = "ed+flow", depth: int = 4, widths: tuple[int, ...] = (16, 32, 64, 128),
                 head_channels: int = 128, ed_encoding: str = "clip"):
        super().__init__()
        if inputs not in INPUT_CHANNELS:
            raise ValueError(f"inputs: expected one of {', '.join(INPUT_CHANNELS)}, got {inputs!r}")
        if ed_encoding not in ED_ENCODINGS:
            raise ValueError(f"ed_encoding: expected one of {', '.join(ED_ENCODINGS)}, got {ed_encoding!r}")
        if len(widths) < depth:
            raise ValueError(f"widths: need at least {depth} values for depth {depth}, got {list(widths)}")
        widths = tuple(int(w) for w in widths[:depth])
        self.config = {"inputs": inputs, "depth": depth, "widths": list(widths), "head_channels": head_channels,
                       "ed_encoding": ed_encoding}
        self.channels = INPUT_CHANNELS[inputs]
        self.ed_encoding = ed_encoding
        cin = len(self.channels)
        self.encoder = nn.ModuleList()
        for width in widths:
            self.encoder.append(_conv_bn_relu(cin, width))
            cin = width
        self.bottleneck = _conv_bn_relu(widths[-1], widths[-1])
        self.decoder = nn.ModuleList()
        cin = widths[-1]
        for width in reversed(widths):
            self.decoder.append(_conv_bn_relu(cin + width, width))
            cin = width
        self.head = _conv_bn_relu(widths[0], head_channels, kernel=1)
        self.classifier = nn.Conv2d(head_channels, 1, 1)
        self._init_weights()

    def _init_weights(self) -> None:
        for module in self.modules():
            if isinstance(module, nn.Conv2d):
                nn.init.kaiming_normal_(module.weight, nonlinearity="relu")
                if module.bias is not None:
                    nn.init.zeros_(module.bias)
        nn.init.normal_(self.classifier.weight, std=0.01)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for block in self.encoder:
            x = block(x)
            skips.append(x)
            x = F.max_pool2d(x, 2, ceil_mode=True)
        x = self.bottleneck(x)
        for block, skip in zip(self.decoder, reversed(skips)):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], dim=1))
        return self.classifier(self.head(x))

    def select_inputs(self, motion_images: torch.Tensor) -> torch.Tensor:
        """The channels of full (dx, dy, ED) motion images ``(B, 3, H, W)`` that this network reads, the ED
        channel (scaled over a window of frames, unsaturated) saturated by ``ed_encoding``. A new tensor."""
        x = motion_images[:, list(self.channels)]
        if 2 in self.channels:
            ed = self.channels.index(2)
            x[:, ed] = encode_ed(x[:, ed], self.ed_encoding)
        return x
