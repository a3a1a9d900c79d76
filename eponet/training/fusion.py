"""The training loop of the EpO+ fusion: a ConvGRU on cached appearance features and a trained motion net's maps.

Paper sections 4.3 and 5.2: clips of 12 frames back-propagated through time with binary cross-entropy,
RMSProp from lr 1e-3 decreased every epoch, gradients clipped to [-50, 50], random crops and flips of whole
clips, and input-dropout of the motion map on 20% of the frames.
"""

from __future__ import annotations

import logging
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eponet.core.errors import InputError
from eponet.core.inputs import discover_sequences
from eponet.core.progress import track
from eponet.core.types import Video
from eponet.training.augment import apply_clip_crop_flip, draw_clip_crop_flip, draw_motion_drops
from eponet.training.base import Trainer, data_line, history_table, sequence_j, trained_line
from eponet.training.config import DataSource, TrainConfig
from eponet.training.data import load_motion_sequences
from eponet.training.distributed import SINGLE, DistributedContext
from eponet.training.losses import segmentation_loss

__all__ = ["FusionSequence", "FusionTrainer", "probe_channels", "fusion_model_card"]

log = logging.getLogger(__name__)


@dataclass
class FusionSequence:
    """One fusion training sequence: appearance features float16 ``(F, C, h, w)``, the motion net's foreground
    probability float16 ``(F, H, W)`` in [0, 1] and ground-truth masks uint8 ``(F, H, W)`` in {0, 1}, at the
    processing resolution ``H x W``."""

    name: str
    features: np.ndarray
    saliency: np.ndarray
    masks: np.ndarray


def probe_channels(stage) -> int:
    """Feature channels of an appearance stage, from one small black frame."""
    video = Video("probe", np.zeros((1, 32, 32, 3), np.uint8), ["probe"], (32, 32))
    return int(stage.features(video).shape[1])


class FusionTrainer(Trainer):
    """Trains a :class:`~eponet.fusion.ConvGRUFusion` as a ``task: fusion`` :class:`TrainConfig` says.

    ``appearance_channels`` defaults to what the spec's appearance stage produces (probed on one frame).
    """

    def __init__(self, config: TrainConfig, *, appearance_channels: int | None = None,
                 context: DistributedContext = SINGLE):
        from eponet.fusion import ConvGRUFusion

        if appearance_channels is None:
            appearance_channels = probe_channels(config.stages["appearance"].build())
        super().__init__(config, context=context)
        self.model = ConvGRUFusion(appearance_channels, **config.model).to(self.device)
        self._motion_stage = None
        self._motion_stages: dict = {}  # motion_maps: stages by their weights

    # -- data ------------------------------------------------------------------------------------
    def load_data(self, source: DataSource) -> list[FusionSequence]:
        """Motion images (cached geometry), the motion net's maps and the appearance features (computed once,
        cached on disk) of each DAVIS-layout sequence, one sequence at a time to bound memory."""
        options = source.options
        root = Path(options["root"])
        names = [s.name for s in discover_sequences(root, sequences=options["sequences"], resolution=options["resolution"])
                 if s.name not in options["exclude"]]
        if not names:
            raise InputError(f"{root}: no training sequences left after exclusions")
        out: list[FusionSequence | None] = [None] * len(names)
        # under DDP each process computes its share first, filling the cache for the others
        for i in track(self.context.share_first(len(names)), desc="fusion data", total=len(names)):
            [seq] = load_motion_sequences(self.config.geometry, root, resolution=options["resolution"],
                                          sequences=[names[i]], cache=self.cache, features=True)
            saliency = self.motion_stage(names[i]).predict(seq.motion.astype(np.float32))
            out[i] = FusionSequence(seq.name, seq.features, saliency.astype(np.float16), seq.masks)
            log.info("%s: %d frames, features %s", names[i], len(seq.masks), seq.features.shape[1:])
        return out

    def motion_stage(self, sequence: str | None = None):
        """The spec's trained motion net stage, built once; for a sequence that ``motion_maps`` names, the same
        stage with the weights given there."""
        weights = self.config.motion_maps.get(sequence)
        if weights is not None:
            key = str(weights)
            if key not in self._motion_stages:
                config = self.config.stages["motion_net"]
                self._motion_stages[key] = config.spec.factory(**{**config.params, "weights": weights, "sha256": None})
            return self._motion_stages[key]
        if self._motion_stage is None:
            self._motion_stage = self.config.stages["motion_net"].build()
        return self._motion_stage

    # -- optimisation ----------------------------------------------------------------------------
    def learning_rate(self, epoch: int, epoch_in_phase: int) -> float:
        """``linear``: ``lr * (1 - epoch / epochs)`` over all phases' epochs; ``step``: ``lr * gamma **
        (epoch_in_phase // step_epochs)``; ``constant``: ``lr``."""
        o = self.config.optimizer
        if o["schedule"] == "linear":
            return o["lr"] * (1 - epoch / sum(p.epochs for p in self.config.phases))
        if o["schedule"] == "step":
            return o["lr"] * o["gamma"] ** (epoch_in_phase // o["step_epochs"])
        return o["lr"]

    def clips(self, data: list[FusionSequence], rng: np.random.Generator) -> list[tuple[int, int, int]]:
        """This epoch's clips ``(sequence, first frame, length)``: back-to-back clips of ``clips.length`` frames
        from a random offset, so every frame is used about once and clip boundaries move between epochs; a
        sequence shorter than a clip is one clip."""
        length = self.config.clips["length"]
        out = []
        for s, seq in enumerate(data):
            frames = len(seq.masks)
            if frames <= length:
                out.append((s, 0, frames))
                continue
            offset = int(rng.integers(0, min(length, frames - length + 1)))
            out += [(s, t, length) for t in range(offset, frames - length + 1, length)]
        return out

    def train_epoch(self, data: list[FusionSequence], optimizer, epoch: int, samples: int | None) -> float:
        import torch

        clips: list[tuple[int, int, int]] = []
        epoch_rng = []

        def draw(epoch: int) -> np.ndarray:
            rng = np.random.default_rng([self.config.seed, epoch])
            epoch_rng[:] = [rng]
            clips[:] = self.clips(data, rng)
            order = rng.permutation(len(clips))
            return np.resize(order, samples) if samples is not None else order

        sampler = self.epoch_sampler(draw, epoch)
        [rng] = epoch_rng
        batches = sampler.steps(self.config.optimizer["batch_size"])
        crop = tuple(self.config.augment["crop"]) if self.config.augment["crop"] else None
        dropout = self.config.input_dropout
        clip_value = self.config.optimizer["clip_gradients"]
        self.net.train()
        losses = []
        for batch in track(batches, desc=f"epoch {epoch + 1}", total=len(batches)):
            # the whole global batch's augmentation, drawn in the order one process draws it
            chosen = [clips[sampler.sample(p)] for p in batch]
            draws = []
            for s, _, length in chosen:
                seq = data[s]
                box = draw_clip_crop_flip(seq.features.shape[-2:], seq.masks.shape[-2:], crop,
                                          self.config.augment["flip"], rng)
                drops = (draw_motion_drops((length,), dropout["probability"], rng)
                         if dropout["sequences"] is None or seq.name in dropout["sequences"] else None)
                draws.append((box, drops))
            items = []
            for i in sampler.rows(batch):
                (s, t, length), (box, drops) = chosen[i], draws[i]
                seq = data[s]
                features, saliency, masks = apply_clip_crop_flip(
                    seq.features[t : t + length].astype(np.float32), seq.saliency[t : t + length].astype(np.float32),
                    seq.masks[t : t + length], box)
                if drops is not None:
                    saliency[drops] = 0
                items.append((features, saliency, masks))
            optimizer.zero_grad(set_to_none=True)
            # clips of different lengths or sizes (short sequences, no crop) go through in groups of one shape;
            # under DDP the gradients are averaged over the processes once, with the last group's
            groups: dict[tuple, list] = {}
            for item in items:
                groups.setdefault(item[0].shape[:1] + item[0].shape[2:] + item[2].shape[1:], []).append(item)
            total = 0.0
            for g, group in enumerate(groups.values()):
                last = g == len(groups) - 1
                with nullcontext() if last or not self.context.active else self.net.no_sync():
                    loss = self._clip_loss(*(np.stack(a) for a in zip(*group))) * (len(group) / len(items))
                    loss.backward()
                total += loss.item()
            if clip_value is not None:
                torch.nn.utils.clip_grad_value_(self.model.parameters(), clip_value)
            optimizer.step()
            self.after_step()
            losses.append(total)
        return float(np.mean(losses))

    def _clip_loss(self, features: np.ndarray, saliency: np.ndarray, masks: np.ndarray):
        """The training loss (``loss``: BCE, or BCE plus soft Jaccard per frame) of a batch of clips: features
        ``(B, T, C, h, w)``, saliency and masks ``(B, T, H, W)``; logits at the masks' size by
        :meth:`~eponet.fusion.ConvGRUFusion.frame_logits`."""
        import torch

        f = torch.from_numpy(features).to(self.device)
        s = torch.from_numpy(saliency).to(self.device)
        y = torch.from_numpy(masks.astype(np.float32)).to(self.device)
        logits = self.model.frame_logits(self.net(f, s).flatten(0, 1), s.flatten(0, 1))
        return segmentation_loss(logits, y.flatten(0, 1), **self.config.loss)

    def validate_sequence(self, model, seq: FusionSequence) -> tuple[float, int, float]:
        """BCE loss sum, frames and J: the whole sequence in one bidirectional pass, threshold 0.5, no CRF."""
        import torch
        import torch.nn.functional as F

        from eponet.fusion import video_logits

        saliency = seq.saliency.astype(np.float32)
        logits = video_logits(model, seq.features.astype(np.float32), saliency, window=None, device=self.device)
        with torch.inference_mode():
            logits = model.frame_logits(logits.to(self.device), torch.from_numpy(saliency).to(self.device)).cpu()
        y = torch.from_numpy(seq.masks.astype(np.float32))
        loss = float(F.binary_cross_entropy_with_logits(logits, y)) * len(y)
        return loss, len(y), sequence_j((torch.sigmoid(logits) >= 0.5).numpy(), seq.masks.astype(bool))

    # -- records ---------------------------------------------------------------------------------
    def weights_meta(self) -> dict:
        meta = {kind: {"plugin": c.plugin, "params": c.params} for kind, c in self.config.stages.items()}
        if self._motion_stage is not None and getattr(self._motion_stage, "sha256", None):
            meta["motion_net"]["sha256"] = self._motion_stage.sha256
        if self.config.motion_maps:
            meta["motion_maps"] = {name: {"weights": w, "sha256": getattr(self._motion_stages.get(str(w)), "sha256", None)}
                                   for name, w in self.config.motion_maps.items()}
        return meta

    def model_card(self, summary: dict, history: list[dict]) -> str:
        return fusion_model_card(self.config, summary, history, self.model.config)


def fusion_model_card(config: TrainConfig, summary: dict, history: list[dict], model: dict) -> str:
    """A Markdown model card of a fusion training run."""
    o, d, a = config.optimizer, config.input_dropout, config.augment
    schedule = {"linear": f"lr {o['lr']} x (1 - epoch / epochs)",
                "step": f"lr {o['lr']} x {o['gamma']} every {o['step_epochs']} epochs of a phase",
                "constant": f"constant lr {o['lr']}"}[o["schedule"]]
    stages = config.stages
    lines = [
        "# Model card: EpO+ fusion (bidirectional ConvGRU)", "",
        f"- weights: `{Path(summary['weights']).name}`, sha256 `{summary['sha256']}`",
        f"- architecture: 1x1 bottleneck {model['appearance_channels']} -> {model['bottleneck']} channels (+ ReLU), "
        f"concatenated with the motion map; bidirectional ConvGRU, {model['hidden']} state channels, "
        f"{model['kernel_size']}x{model['kernel_size']} kernels; per-frame 1x1 classifier on both directions' states"
        + ("; a correction of the motion net: plus the full-resolution motion map's logit with a learned weight "
           "(motion_residual)" if model.get("motion_residual") else "")
        + (f"; appearance channels dropped with probability {model['feature_dropout']} in training"
           if model.get("feature_dropout") else ""),
        "- appearance: " + (f"{stages['appearance'].plugin} {stages['appearance'].params}" if "appearance" in stages
                            else f"{model['appearance_channels']} channels (not recorded)")
        + " (the paper: DeepLab fc6, 1024 channels at stride 8)",
        "- motion net: " + (f"{stages['motion_net'].plugin} {stages['motion_net'].params}" if "motion_net" in stages
                            else "not recorded")
        + (f"; the maps of {len(config.motion_maps)} sequences from other weights (motion_maps): "
           + ", ".join(f"{name} {Path(str(w)).name if isinstance(w, str) else [Path(x).name for x in w]}"
                       for name, w in sorted(config.motion_maps.items())) if config.motion_maps else ""),
        trained_line(config, summary),
        f"- optimiser: {o['name']}, {schedule}, momentum {o['momentum']}, weight decay {o['weight_decay']}, "
        f"{o['batch_size']} clip(s) of {config.clips.get('length')} frames per step (BPTT, {config.loss['name']} loss), gradients clipped to "
        f"{'[-%g, %g]' % (o['clip_gradients'], o['clip_gradients']) if o['clip_gradients'] else 'no limit'}",
        f"- input-dropout: motion map zeroed on {d['probability']:.0%} of the frames of "
        + (", ".join(d["sequences"]) if d["sequences"] else "every sequence"),
        f"- augmentation: crops {a['crop']} (frame pixels, whole feature cells), flips {a['flip']} (same for a whole clip)",
        "", "## Data", "",
    ]
    lines += [f"{i + 1}. phase `{p.name}` ({p.epochs} epochs): {data_line(p.data)}" for i, p in enumerate(config.phases)]
    if config.validation:
        lines += ["", f"Validation: {data_line(config.validation)} (J mean, DAVIS-2016 protocol, whole sequences in one "
                  "bidirectional pass, threshold 0.5, no CRF, at the training resolution)."]
    lines += history_table(history)
    return "\n".join(lines) + "\n"
