"""Motion-net stage ``epo_unet``: the EpO U-Net on (dx, dy, ED) motion images."""

from __future__ import annotations

import logging

import numpy as np

from eponet.core.devices import DEVICES, PRECISIONS, resolve_precision, torch_device
from eponet.core.errors import MissingWeights, SpecError
from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.motion import mirror_motion_images
from eponet.core.params import Param
from eponet.core.progress import track
from eponet.weights import load_each, resolve_weights, weights_list

__all__ = ["EpoUNetStage", "load_unet"]

log = logging.getLogger(__name__)


def load_unet(weights: str, sha256: str | None = None):
    """Build an :class:`~eponet.nets.EpoUNet` from a verified weights file (built-in name or path)."""
    import torch

    from eponet.nets import EpoUNet

    path, digest = resolve_weights(weights, sha256=sha256, kind="motion_net")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
        model = EpoUNet(**checkpoint["config"])
        model.load_state_dict(checkpoint["state_dict"])
    except Exception as exc:
        raise MissingWeights(f"{path}: not EpO U-Net weights ({exc.__class__.__name__}: {str(exc).splitlines()[0]})") from None
    return model.eval(), digest


class EpoUNetStage:
    """Per-frame inference of the U-Net, in batches, on CPU or GPU.

    ``weights`` may list several networks (an ensemble, e.g. one recipe trained with two seeds): the foreground
    probability is the mean of theirs, for the cost of one network each. With ``flip``, each network's
    probability is the mean of its predictions on the motion images and on their mirror images (test-time
    augmentation, twice the cost). Each network runs as its :class:`~eponet.nets.InferenceUNet` (BatchNorm
    folded into the convolutions: the same probabilities to float32 rounding, in less time); ``precision:
    bfloat16`` runs it under bfloat16 autocast (about twice as fast on CPUs with AMX or AVX-512 BF16 and on
    GPUs; far slower on CPUs without them; probabilities within a few hundredths of float32's); ``auto`` chooses
    bfloat16 on a CPU that has them (:func:`~eponet.core.devices.native_bfloat16`) and float32 otherwise
    (:attr:`resolved` holds the choice, which ``run.json`` records).
    """

    def __init__(self, *, weights: str | list[str] = "epo-davis", sha256: str | list[str] | None = None,
                 batch_size: int = 8, device: str = "auto", flip: bool = False, precision: str = "float32"):
        from eponet.nets import InferenceUNet

        models, self.sha256 = load_each(load_unet, weights, sha256)
        self.models = [InferenceUNet(model) for model in models]
        self.batch_size = batch_size
        self.device = torch_device(device)
        self.flip = flip
        self.precision = resolve_precision(precision, self.device)

    @property
    def resolved(self) -> dict:
        """What ``device`` and ``precision`` became on this machine (``run.json`` records it)."""
        return {"device": str(self.device), "precision": self.precision}

    def predict(self, motion_images: np.ndarray) -> np.ndarray:
        import torch

        models = [model.to(self.device).to(memory_format=torch.channels_last) for model in self.models]
        out = np.empty((motion_images.shape[0],) + motion_images.shape[2:], np.float32)
        with torch.inference_mode():
            starts = range(0, len(motion_images), self.batch_size)
            for start in track(starts, desc="motion net", total=len(starts)):
                images = motion_images[start : start + self.batch_size]
                mirrored = mirror_motion_images(images) if self.flip else None
                prob = 0
                for model in models:
                    prob = prob + self._probability(model, images)
                    if mirrored is not None:
                        prob = prob + self._probability(model, mirrored).flip(-1)
                prob = prob / (len(models) * (2 if self.flip else 1))
                out[start : start + len(images)] = prob.float().cpu().numpy()
        return out

    def _probability(self, model, images: np.ndarray):
        """Foreground probability ``(B, H, W)`` (a tensor on the stage's device) of motion images ``(B, 3, H, W)``."""
        import torch

        batch = model.select_inputs(torch.from_numpy(images).to(self.device))
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.precision == "bfloat16"):
            logits = model(batch.contiguous(memory_format=torch.channels_last))
        return torch.sigmoid(logits.float())[:, 0]


def _check(params: dict) -> list[str]:
    try:
        for name, digest in weights_list(params["weights"], params.get("sha256")):
            resolve_weights(name, sha256=digest, kind="motion_net")
    except SpecError as exc:
        return exc.problems
    except MissingWeights as exc:
        return [exc.problem]
    return []


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="motion_net",
            name="epo_unet",
            factory=EpoUNetStage,
            params=(
                Param("weights", "weights", "epo-davis", "built-in weights name or a weights file (.pt from eponet "
                      "train); a list of them averages the networks' probabilities", many=True),
                Param("sha256", "str", None, "expected sha256 of the weights file (checked before loading); one per "
                      "file for a list", nullable=True, many=True),
                Param("batch_size", "int", 8, "frames per inference batch", minimum=1),
                Param("device", "choice", "auto", "where to run: auto = GPU when available", choices=DEVICES),
                Param("flip", "bool", False, "test-time augmentation: average with the prediction on the mirrored "
                      "motion images (dx negated); twice the cost"),
                Param("precision", "choice", "float32", "arithmetic of the networks: bfloat16 is about 2x faster "
                      "on CPUs with AMX / AVX-512 BF16 and on GPUs (probabilities within a few hundredths), "
                      "far slower on other CPUs; auto = bfloat16 on CPUs that have it, else float32",
                      choices=PRECISIONS),
            ),
            doc="EpO U-Net motion network on (dx, dy, ED) motion images",
            check=_check,
        )
    ]
