"""Fusion stage ``convgru``: EpO+'s bidirectional ConvGRU over appearance features and the motion map."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from eponet.core.devices import DEVICES, torch_device
from eponet.core.errors import MissingWeights, StageError
from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.plugins.fusion import example_params, threshold_problems, window_problems
from eponet.weights import resolve_weights

__all__ = ["ConvGRUStage", "load_fusion"]

log = logging.getLogger(__name__)


def load_fusion(weights: str, sha256: str | None = None):
    """Build a :class:`~eponet.fusion.ConvGRUFusion` from a verified weights file (built-in name or path, as
    written by ``eponet train`` with ``task: fusion``); returns the model in eval mode and the file's sha256."""
    import torch

    from eponet.fusion import ConvGRUFusion

    path, digest = resolve_weights(weights, sha256=sha256, kind="fusion")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
        config = dict(checkpoint["config"])
        model = ConvGRUFusion(config.pop("appearance_channels"), **config)
        model.load_state_dict(checkpoint["state_dict"])
    except Exception as exc:
        raise MissingWeights(f"{path}: not ConvGRU fusion weights ({exc.__class__.__name__}: "
                             f"{str(exc).splitlines()[0]})") from None
    return model.eval(), digest


class ConvGRUStage:
    """Whole-video fusion, in overlapping windows of ``window`` frames (see :func:`eponet.fusion.video_logits`
    for the memory bound), stitched by ``blend``; logits are bilinearly upsampled to the saliency's size.

    ``selftrain > 0`` then self-trains, per window, an appearance classifier on the fused map's confident pixels
    (above ``selftrain_foreground``, or the window's top ``selftrain_foreground_share`` of cells down to
    ``selftrain_foreground_floor`` where fewer are; below ``selftrain_background``, and below
    ``selftrain_background_motion`` in the motion map when that is set) and mixes its probability in
    with that share (:func:`eponet.fusion.selftrain.self_trained_probability`): the ``selftrain`` fusion's
    test-time adaptation, seeded by the fusion instead of the motion map."""

    def __init__(self, *, weights: str = "epo-plus-davis-lite2", sha256: str | None = None, window: int | None = 32,
                 overlap: int = 8, blend: str = "centre", device: str = "auto", selftrain: float = 0.0,
                 selftrain_foreground: float = 0.9, selftrain_background: float = 0.05, selftrain_samples: int = 60000,
                 selftrain_l2: float = 1e-3, selftrain_foreground_share: float = 0.0,
                 selftrain_foreground_floor: float = 0.5, selftrain_background_motion: float | None = None):
        self.model, self.sha256 = load_fusion(weights, sha256)
        self.window, self.overlap, self.blend = window, overlap, blend
        self.device = torch_device(device)
        self.selftrain = dict(weight=selftrain, foreground=selftrain_foreground, background=selftrain_background,
                              samples=selftrain_samples, l2=selftrain_l2, foreground_share=selftrain_foreground_share,
                              foreground_floor=selftrain_foreground_floor,
                              background_motion=selftrain_background_motion)

    def fuse(self, features: np.ndarray, saliency: np.ndarray) -> np.ndarray:
        """Foreground probability float32 ``(F, H, W)`` from features ``(F, C, h, w)`` and saliency ``(F, H, W)``."""
        import torch

        from eponet.fusion import video_logits

        expected = self.model.appearance_channels
        if features.ndim != 4 or features.shape[1] != expected:
            raise StageError(f"fusion convgru: the weights expect {expected} appearance channels, got features of "
                             f"shape {features.shape}; use the appearance stage the fusion was trained with")
        model = self.model.to(self.device)
        logits = video_logits(model, features, saliency, window=self.window, overlap=self.overlap, blend=self.blend,
                              device=self.device)
        out = np.empty(saliency.shape, np.float32)
        with torch.inference_mode():
            for start in range(0, len(out), 16):  # upsample a few frames at a time: bounded temporaries
                maps = torch.from_numpy(np.ascontiguousarray(saliency[start : start + 16], np.float32)).to(self.device)
                chunk = model.frame_logits(logits[start : start + 16].to(self.device), maps)
                out[start : start + len(chunk)] = torch.sigmoid(chunk).cpu().numpy()
        if self.selftrain["weight"] > 0:
            from eponet.fusion.selftrain import self_trained_probability

            out = self_trained_probability(features, out, motion=saliency, **self.selftrain)
        return out


def _check(params: dict) -> list[str]:
    problems = []
    try:
        resolve_weights(params["weights"], sha256=params.get("sha256"), kind="fusion")
    except MissingWeights as exc:
        problems.append(exc.problem)
    return problems + window_problems(params) + threshold_problems(params, "selftrain_")


def _check_stages(params: dict, stages: dict) -> list[str]:
    """The weights' appearance stage (recorded by ``eponet train``) must be the spec's: a fusion reads the
    features it was trained on (another backbone's have other channels, or the same count meaning other things)."""
    import torch

    if "appearance" not in stages:
        return []
    # (``_check`` has verified the file's checksum already: only its path is needed, not a second sha256)
    from eponet.weights import builtin_weights

    entry = builtin_weights().get(params["weights"])
    path = entry.file if entry is not None else Path(params["weights"]).expanduser()
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # (load_fusion reports an unreadable file when the stage is built)
        return []
    trained = (checkpoint.get("meta") or {}).get("appearance") or {}
    used = stages["appearance"][0]
    if trained.get("plugin") and trained["plugin"] != used:
        channels = checkpoint.get("config", {}).get("appearance_channels")
        return [f"weights: {params['weights']!r} was trained on {trained['plugin']} features ({channels} channels), "
                f"not on stages.appearance's {used}: set stages.appearance.plugin to {trained['plugin']} or train a "
                f"fusion on {used}"]
    return []


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="fusion",
            name="convgru",
            factory=ConvGRUStage,
            params=(
                Param("weights", "weights", "epo-plus-davis-lite2", "built-in weights name or a weights file (.pt from "
                      "eponet train with task: fusion), with the appearance stage it was trained on (epo-plus-davis-lite2: "
                      "efficientnet_lite2; epo-plus-davis: efficientnet_lite0)"),
                Param("sha256", "str", None, "expected sha256 of a weights file (checked before loading)", nullable=True),
                Param("window", "int", 32, "frames per inference window (memory grows with it, not with the video); "
                      "null: the whole video in one pass, as the authors' code", minimum=2, nullable=True),
                Param("overlap", "int", 8, "frames shared by consecutive windows", minimum=0),
                Param("blend", "choice", "centre", "stitching of overlaps: centre = each frame from the window where it "
                      "is most central (the more accurate: cold-started window edges are never used), linear = "
                      "cross-fade of the logits", choices=("centre", "linear")),
                Param("device", "choice", "auto", "where to run: auto = GPU when available", choices=DEVICES),
                Param("selftrain", "float", 0.0, "share of a per-window appearance classifier self-trained on the "
                      "fused map's confident pixels (0 = the fusion alone; see the selftrain fusion)",
                      minimum=0.0, maximum=1.0),
                *example_params("selftrain_", "fused probability"),
                Param("selftrain_background_motion", "float", None, "a background example for selftrain must also be "
                      "below this in the motion map (null = the fused map alone decides)", minimum=0.0, maximum=1.0,
                      nullable=True),
            ),
            doc="EpO+ fusion: bottleneck appearance features + motion map through a bidirectional ConvGRU",
            check=_check,
            check_stages=_check_stages,
        )
    ]
