"""Fusion stage ``convgru``: EpO+'s bidirectional ConvGRU over appearance features and the motion map."""

from __future__ import annotations

import logging

import numpy as np

from eponet.core.devices import DEVICES, torch_device
from eponet.core.errors import MissingWeights, SpecError, StageError
from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.plugins.fusion import example_params, threshold_problems, window_problems
from eponet.weights import load_each, resolve_weights, weights_list, weights_path

__all__ = ["ConvGRUStage", "load_fusion"]

log = logging.getLogger(__name__)

#: the built-in weights the stage loads by default: the epo+ preset's fusion
DEFAULT_WEIGHTS = "epo-plus-davis-lite2-pair"


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
    test-time adaptation, seeded by the fusion instead of the motion map.

    ``weights`` may list several fusions trained on the same appearance stage (an ensemble, e.g. one recipe
    trained with two seeds): the fused probability is the mean of theirs, before the self-training, for the cost
    of one ConvGRU pass each.

    ``motion_support`` (off by default) then lowers each foreground region of the result that holds no motion
    probability of at least that value to the motion map (:func:`eponet.fusion.support.motion_supported`): the
    appearance shapes an object but does not add a look-alike that does not move. ``motion_fill`` (off by default)
    then gives back, inside the convex hull of each region with motion support (``motion_support``, or 0.5 when
    that is off), the pixels whose motion probability reaches ``motion_fill``, where they are at least
    ``motion_fill_share`` of the region's size (:func:`eponet.fusion.support.motion_filled`): nor does the
    appearance cut the middle out of an object that moves."""

    def __init__(self, *, weights: str | list[str] = DEFAULT_WEIGHTS, sha256: str | list[str] | None = None,
                 window: int | None = 32,
                 overlap: int = 8, blend: str = "centre", device: str = "auto", selftrain: float = 0.0,
                 selftrain_foreground: float = 0.9, selftrain_background: float = 0.05, selftrain_samples: int = 60000,
                 selftrain_l2: float = 1e-3, selftrain_foreground_share: float = 0.0,
                 selftrain_foreground_floor: float = 0.5, selftrain_background_motion: float | None = None,
                 motion_support: float | None = None, motion_fill: float | None = None,
                 motion_fill_share: float = 0.1):
        self.models, self.sha256 = load_each(load_fusion, weights, sha256)
        channels = {model.appearance_channels for model in self.models}
        if len(channels) > 1:
            raise StageError(f"fusion convgru: the weights expect different appearance channels ({sorted(channels)}); "
                             "an ensemble's fusions must be trained on one appearance stage")
        self.window, self.overlap, self.blend = window, overlap, blend
        self.device = torch_device(device)
        self.selftrain = dict(weight=selftrain, foreground=selftrain_foreground, background=selftrain_background,
                              samples=selftrain_samples, l2=selftrain_l2, foreground_share=selftrain_foreground_share,
                              foreground_floor=selftrain_foreground_floor,
                              background_motion=selftrain_background_motion)
        self.motion_support, self.motion_fill, self.motion_fill_share = motion_support, motion_fill, motion_fill_share

    def fuse(self, features: np.ndarray, saliency: np.ndarray) -> np.ndarray:
        """Foreground probability float32 ``(F, H, W)`` from features ``(F, C, h, w)`` and saliency ``(F, H, W)``."""
        import torch

        from eponet.fusion import video_logits

        expected = self.models[0].appearance_channels
        if features.ndim != 4 or features.shape[1] != expected:
            raise StageError(f"fusion convgru: the weights expect {expected} appearance channels, got features of "
                             f"shape {features.shape}; use the appearance stage the fusion was trained with")
        out = np.zeros(saliency.shape, np.float32)
        maps = torch.from_numpy(np.ascontiguousarray(saliency, np.float32))  # (no copy of a float32 map)
        for model in self.models:
            model = model.to(self.device)
            logits = video_logits(model, features, saliency, window=self.window, overlap=self.overlap,
                                  blend=self.blend, device=self.device)
            with torch.inference_mode():
                for start in range(0, len(out), 16):  # upsample a few frames at a time: bounded temporaries
                    chunk = model.frame_logits(logits[start : start + 16].to(self.device),
                                               maps[start : start + 16].to(self.device))
                    out[start : start + len(chunk)] += torch.sigmoid(chunk).cpu().numpy()
        if len(self.models) > 1:
            out /= len(self.models)
        if self.selftrain["weight"] > 0:
            from eponet.fusion.selftrain import self_trained_probability

            out = self_trained_probability(features, out, motion=saliency, **self.selftrain)
        if self.motion_support is not None:
            from eponet.fusion.support import motion_supported

            out = motion_supported(out, saliency, self.motion_support)
        if self.motion_fill is not None:
            from eponet.fusion.support import motion_filled

            support = 0.5 if self.motion_support is None else self.motion_support
            out = motion_filled(out, saliency, support, self.motion_fill, self.motion_fill_share)
        return out


def _check(params: dict) -> list[str]:
    problems = []
    try:
        for name, digest in weights_list(params["weights"], params.get("sha256")):
            resolve_weights(name, sha256=digest, kind="fusion")
    except SpecError as exc:
        problems += exc.problems
    except MissingWeights as exc:
        problems.append(exc.problem)
    return problems + window_problems(params) + threshold_problems(params, "selftrain_")


def _check_stages(params: dict, stages: dict) -> list[str]:
    """The weights' appearance stage (recorded by ``eponet train``) must be the spec's: a fusion reads the
    features it was trained on (another backbone's have other channels, or the same count meaning other things)."""
    import torch

    if "appearance" not in stages:
        return []
    used, problems = stages["appearance"][0], []
    for name, _ in weights_list(params["weights"], None):
        try:  # (``_check`` has verified the files' checksums already: their paths suffice, not a second sha256)
            checkpoint = torch.load(weights_path(name, kind="fusion"), map_location="cpu", weights_only=True)
        except Exception:  # (load_fusion reports an unreadable file when the stage is built)
            continue
        trained = (checkpoint.get("meta") or {}).get("appearance") or {}
        if trained.get("plugin") and trained["plugin"] != used:
            channels = checkpoint.get("config", {}).get("appearance_channels")
            problems.append(f"weights: {name!r} was trained on {trained['plugin']} features ({channels} channels), "
                            f"not on stages.appearance's {used}: set stages.appearance.plugin to {trained['plugin']} "
                            f"or train a fusion on {used}")
    return problems


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="fusion",
            name="convgru",
            factory=ConvGRUStage,
            params=(
                Param("weights", "weights", DEFAULT_WEIGHTS, "built-in weights name or a weights file (.pt "
                      "from eponet train with task: fusion), with the appearance stage it was trained on "
                      "(epo-plus-davis-lite2-pair, epo-plus-davis-lite2: efficientnet_lite2; "
                      "epo-plus-davis-lite2-pair-fine: efficientnet_lite2 at scale 1.5; epo-plus-davis: "
                      "efficientnet_lite0); a list of them averages the fusions' "
                      "probabilities", many=True),
                Param("sha256", "str", None, "expected sha256 of a weights file (checked before loading); one per file "
                      "for a list", nullable=True, many=True),
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
                Param("motion_support", "float", None, "a fused foreground region whose motion probability never "
                      "reaches this falls to the motion map (null = off; a frame without any supported region "
                      "keeps its fused map)", minimum=0.0, maximum=1.0, nullable=True),
                Param("motion_fill", "float", None, "inside the convex hull of each fused region with motion "
                      "support, a pixel whose motion probability reaches this is raised to it (null = off)",
                      minimum=0.0, maximum=1.0, nullable=True),
                Param("motion_fill_share", "float", 0.1, "motion_fill gives back an object's pixels only where they "
                      "are at least this share of the region's size (a lost part, not the motion map's blur)",
                      minimum=0.0),
            ),
            doc="EpO+ fusion: bottleneck appearance features + motion map through a bidirectional ConvGRU",
            check=_check,
            check_stages=_check_stages,
        )
    ]
