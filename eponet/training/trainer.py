"""The training loop of the EpO motion network: phases (e.g. RBSF, then DAVIS), checkpoints, resume, curves."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np

from eponet.core.errors import InputError
from eponet.core.io import atomic_write_bytes
from eponet.core.progress import track
from eponet.training.augment import ED_CHANNEL, InputDropout, apply_crop_flip, draw_crop_flip, draw_flow_shift
from eponet.training.base import (HISTORY_FIELDS, Trainer, data_line, history_table, plot_history, sequence_j,
                                  trained_line)
from eponet.training.config import DataSource, TrainConfig
from eponet.training.data import SequenceData, davis_masks, load_motion_sequences
from eponet.training.distributed import SINGLE, DistributedContext, barrier
from eponet.training.losses import segmentation_loss

__all__ = ["MotionNetTrainer", "sequence_j", "model_card", "plot_history", "HISTORY_FIELDS"]

log = logging.getLogger(__name__)


class MotionNetTrainer(Trainer):
    """Trains an :class:`~eponet.nets.EpoUNet` as a :class:`TrainConfig` says."""

    def __init__(self, config: TrainConfig, *, context: DistributedContext = SINGLE):
        import torch

        from eponet.nets import EpoUNet

        super().__init__(config, context=context)
        self.model = EpoUNet(**self.model_config()).to(self.device).to(memory_format=torch.channels_last)
        self.dropout = InputDropout(**config.input_dropout)
        self.teachers = self._load_teachers(config.teacher["weights"])

    def _load_teachers(self, weights: list[str]) -> list:
        """The ``teacher`` networks, frozen, as :class:`~eponet.nets.InferenceUNet` on the training device (their
        sha256 go to the model card)."""
        import torch

        from eponet.nets import InferenceUNet
        from eponet.plugins.motion_net.epo_unet import load_unet

        teachers, self.teacher_sha256 = [], []
        for name in weights:
            model, digest = load_unet(name)
            teachers.append(InferenceUNet(model).to(self.device).to(memory_format=torch.channels_last))
            self.teacher_sha256.append(digest)
        return teachers

    def teacher_probability(self, images):
        """The teachers' mean foreground probability ``(B, 1, H, W)`` of motion images ``(B, 3, H, W)`` (a float32
        tensor on the training device), each network reading them as its own ``select_inputs`` says."""
        import torch

        with torch.inference_mode():
            total = sum(torch.sigmoid(t(t.select_inputs(images).contiguous(memory_format=torch.channels_last)))
                        for t in self.teachers)
        return (total / len(self.teachers)).clone()  # (a normal tensor: autograd cannot save inference tensors)

    def model_config(self) -> dict:
        model = dict(self.config.model)
        model["widths"] = tuple(model["widths"])
        return model

    # -- data ------------------------------------------------------------------------------------
    def load_data(self, source: DataSource) -> list[SequenceData]:
        options = source.options
        if source.kind in GENERATORS:
            root, resolution = GENERATORS[source.kind](options, self.context)
            sequences, exclude = None, []
        else:
            root, resolution = options["root"], options["resolution"]
            sequences, exclude = options["sequences"], options["exclude"]
        data = load_motion_sequences(self.config.geometry, Path(root), resolution=resolution,
                                     sequences=sequences, exclude=exclude, cache=self.cache,
                                     compute_order=self.context.share_first)
        if not data:
            raise InputError(f"{root}: no training sequences left after exclusions")
        return data

    # -- optimisation ----------------------------------------------------------------------------
    def learning_rate(self, epoch: int, epoch_in_phase: int) -> float:
        """The step schedule: ``lr * gamma ** (epoch_in_phase // step_epochs)``, restarting in each phase."""
        o = self.config.optimizer
        return o["lr"] * o["gamma"] ** (epoch_in_phase // o["step_epochs"])

    def train_epoch(self, data: list[SequenceData], optimizer, epoch: int, samples: int | None) -> float:
        import torch

        index = np.array([(s, t) for s, seq in enumerate(data) for t in range(len(seq.masks))])
        epoch_rng = []

        def draw(epoch: int) -> np.ndarray:
            rng = np.random.default_rng([self.config.seed, epoch])
            epoch_rng[:] = [rng]
            order = rng.permutation(len(index))
            return np.resize(order, samples) if samples is not None else order

        sampler = self.epoch_sampler(draw, epoch)
        [rng] = epoch_rng
        batches = sampler.steps(self.config.optimizer["batch_size"])
        crop = tuple(self.config.augment["crop"]) if self.config.augment["crop"] else None
        zoom = tuple(self.config.augment["zoom"]) if self.config.augment.get("zoom") else None
        self.net.train()
        losses = []
        for batch in track(batches, desc=f"epoch {epoch + 1}", total=len(batches)):
            # the whole global batch's augmentation, drawn in the order one process draws it
            frames = [index[sampler.sample(p)] for p in batch]
            boxes = [draw_crop_flip(data[s].masks.shape[1:], crop, self.config.augment["flip"], rng, zoom)
                     for s, _ in frames]
            # sequences of different sizes (without a crop, or smaller than it): the batch's smallest
            h, w = min(b.height for b in boxes), min(b.width for b in boxes)
            chosen, replacement = self.dropout.draw(len(batch), (h, w), epoch, rng)
            shifts = draw_flow_shift(len(batch), self.config.augment.get("flow_shift", 0.0), rng)
            images, clean, masks = [], [], []
            for i in sampler.rows(batch):
                s, t = frames[i]
                image, mask = apply_crop_flip(data[s].motion[t].astype(np.float32), data[s].masks[t], boxes[i])
                image, mask = image[:, :h, :w], mask[:h, :w]
                if shifts is not None:
                    image[:ED_CHANNEL] += shifts[i]
                if self.teachers:  # the teachers read the sample before input-dropout
                    clean.append(image.copy())
                if chosen[i]:
                    image[ED_CHANNEL] = replacement[np.count_nonzero(chosen[:i])]
                images.append(image)
                masks.append(mask)
            x = torch.from_numpy(np.stack(images)).to(self.device)
            x = self.model.select_inputs(x).contiguous(memory_format=torch.channels_last)
            y = torch.from_numpy(np.stack(masks).astype(np.float32)).to(self.device)[:, None]
            if self.teachers:
                share = self.config.teacher["share"]
                y = (1.0 - share) * y + share * self.teacher_probability(torch.from_numpy(np.stack(clean)).to(self.device))
            loss = segmentation_loss(self.net(x), y, **self.config.loss)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            self.after_step()
            losses.append(loss.item())
        return float(np.mean(losses))

    def validate_sequence(self, model, seq: SequenceData) -> tuple[float, int, float]:
        """BCE loss sum, frames and J of whole frames, threshold 0.5, no CRF."""
        import torch
        import torch.nn.functional as F

        model.eval()
        loss, probs = 0.0, []
        with torch.inference_mode():
            for start in range(0, len(seq.masks), 8):
                x = torch.from_numpy(seq.motion[start : start + 8].astype(np.float32)).to(self.device)
                x = model.select_inputs(x).contiguous(memory_format=torch.channels_last)
                logits = model(x)
                y = torch.from_numpy(seq.masks[start : start + 8].astype(np.float32)).to(self.device)[:, None]
                loss += float(F.binary_cross_entropy_with_logits(logits, y)) * len(y)
                probs.append(torch.sigmoid(logits)[:, 0].cpu().numpy())
        pred = np.concatenate(probs) >= 0.5
        return loss, len(seq.masks), sequence_j(pred, seq.masks.astype(bool))

    def weights_meta(self) -> dict:
        """The teachers (names or files, sha256, share) of a distilled network."""
        if not self.teachers:
            return {}
        return {"teacher": {**self.config.teacher, "sha256": self.teacher_sha256}}

    def model_card(self, summary: dict, history: list[dict]) -> str:
        return model_card(self.config, {**summary, "teacher_sha256": self.teacher_sha256}, history)


def model_card(config: TrainConfig, summary: dict, history: list[dict]) -> str:
    """A Markdown model card: architecture, data, recipe, per-epoch figures, training time and checksum."""
    m, o, d, a = config.model, config.optimizer, config.input_dropout, config.augment
    lines = [
        "# Model card: EpO motion network", "",
        f"- weights: `{Path(summary['weights']).name}`, sha256 `{summary['sha256']}`",
        f"- architecture: EpO U-Net, inputs {m['inputs']}, depth {m['depth']}, widths {list(m['widths'])[:m['depth']]}, "
        f"{m['head_channels']} channels before the 1x1 classifier"
        + (f", ED encoding {m.get('ed_encoding', 'clip')}" if m["inputs"] != "flow" else "")
        + (f", flow centring {m['flow_centring']}" if m.get("flow_centring", "none") != "none" else "")
        + (f", flow spread over {m['flow_spread']} px" if m.get("flow_spread", 0) else ""),
        trained_line(config, summary),
        f"- optimiser: {o['name']}, lr {o['lr']} x {o['gamma']} every {o['step_epochs']} epochs of a phase, "
        f"momentum {o['momentum']}, weight decay {o['weight_decay']}, batch {o['batch_size']}",
        f"- loss: {config.loss['name']}" + (f" (soft Jaccard weight {config.loss['iou_weight']})"
                                             if config.loss["name"] != "bce" else ""),
        f"- input-dropout: {d['probability']:.0%} of samples, ED zeroed for {d['zero_epochs']} epochs, then {d['then']}",
        f"- augmentation: crops {a['crop']}, flips {a['flip']}, flow shift std {a.get('flow_shift', 0.0)}"
        + (f", zoom {a['zoom'][0]}-{a['zoom'][1]}x" if a.get("zoom") else "")
        + (f"; weights exported as an exponential moving average (decay {o['ema']})" if o.get("ema") else ""),
        *([f"- distilled: target (1 - {config.teacher['share']}) x ground truth + {config.teacher['share']} x the mean "
           f"probability of {len(config.teacher['weights'])} teacher network(s): "
           + ", ".join(f"`{Path(w).name}`" + (f" (sha256 `{d}`)" if d else "")
                       for w, d in zip(config.teacher["weights"], summary.get("teacher_sha256") or
                                       [None] * len(config.teacher["weights"])))]
          if config.teacher["weights"] else []),
        "- geometry: " + (", ".join(f"{k} {v.plugin} {v.params}" for k, v in config.geometry.stages.items())
                          if config.geometry else "not recorded"),
        "", "## Data", "",
    ]
    lines += [f"{i + 1}. phase `{p.name}` ({p.epochs} epochs): {data_line(p.data)}" for i, p in enumerate(config.phases)]
    if config.validation:
        lines += ["", f"Validation: {data_line(config.validation)} (J mean, DAVIS-2016 protocol, threshold 0.5, no CRF, "
                  "at the training resolution)."]
    lines += history_table(history)
    return "\n".join(lines) + "\n"


#: What :func:`eponet.synth.write_dataset` and :func:`eponet.synth.paste.write_pasted` write under their folder
#: (removed before a regeneration).
GENERATED = ("JPEGImages", "Annotations", "Annotations_unsupervised", "Cameras", "ImageSets")


def _ensure_generated(root: Path, marker_name: str, recipe: dict, generate, context: DistributedContext) -> None:
    """Run ``generate()`` to write a data set under ``root`` unless its marker file ``marker_name`` records
    ``recipe`` already; what an earlier recipe wrote there is removed first. Under DDP rank 0 writes it and the
    others wait for it."""
    marker = root / marker_name

    def ready() -> bool:
        return marker.is_file() and json.loads(marker.read_text()) == recipe

    if context.is_main and not ready():
        log.info("generating training data in %s", root)
        if marker.is_file():  # data of other settings that this function wrote: no stale clip or frame may stay
            for name in GENERATED:
                shutil.rmtree(root / name, ignore_errors=True)
        generate()
        atomic_write_bytes(marker, json.dumps(recipe).encode())
    barrier(context)
    if not ready():
        raise InputError(f"{root}: rank 0 generated the training data there, but {context.label} does not "
                         "see it; put the data source's dir on storage every machine shares")


def ensure_rbsf(options: dict, context: DistributedContext = SINGLE) -> tuple[Path, str]:
    """Generate the RBSF-style data set an ``rbsf`` data source describes (``dir``, ``sequences``, ``frames``,
    ``size``, ``seed`` and optional ``scene`` settings, as the training spec validated them) unless ``dir``
    already holds it, as recorded in its ``eponet-rbsf.json``; returns its root and resolution (``240p``
    for 427x240)."""
    from eponet.synth import write_dataset
    from eponet.synth.scene import SceneConfig

    width, _, height = options["size"].partition("x")
    size = (int(width), int(height))
    root = Path(options["dir"])
    recipe = {k: options[k] for k in ("sequences", "frames", "size", "seed")}
    scene = options.get("scene")
    if scene:  # the marker of data generated without scene settings stays valid
        recipe["scene"] = scene
    config = SceneConfig.from_dict(scene) if scene else None
    _ensure_generated(root, "eponet-rbsf.json", recipe, lambda: write_dataset(
        root, options["sequences"], options["frames"], size, options["seed"], config=config, flow=False, depth=False),
        context)
    return root, f"{size[1]}p"


def ensure_pasted(options: dict, context: DistributedContext = SINGLE) -> tuple[Path, str]:
    """Write the clips a ``paste`` data source describes (:mod:`eponet.synth.paste`: objects of the DAVIS-layout
    sequences under ``root`` pasted over others of them, as the training spec validated the settings) unless
    ``dir`` already holds them, as recorded in its ``eponet-paste.json``; returns its root and resolution."""
    from eponet.core.inputs import discover_sequences, load_video
    from eponet.synth.paste import PasteSettings, write_pasted

    davis, resolution = Path(options["root"]), options["resolution"]
    sources = {s.name: s for s in discover_sequences(davis, sequences=options["sequences"], resolution=resolution)
               if s.name not in options["exclude"]}
    names = sorted(sources)
    if len(names) < 2:
        raise InputError(f"{davis}: pasting needs at least two sequences after exclusions, got {names}")
    settings = PasteSettings(object_area=tuple(options["object_area"]), speed=tuple(options["speed"]))
    root = Path(options["dir"])
    recipe = {"root": str(davis), "resolution": resolution, "sequences": names,
              **{k: options[k] for k in ("clips", "frames", "seed", "object_area", "speed")}}

    def load(name):
        video = load_video(sources[name], scale=1.0, keep_full=False)
        return video.frames, davis_masks(davis, resolution, name, video.stems, video.shape)

    _ensure_generated(root, "eponet-paste.json", recipe, lambda: write_pasted(
        root, names, load, options["clips"], options["frames"], options["seed"], settings), context)
    return root, resolution


#: Data source kinds whose clips are written before training: the function that writes them (once per recipe)
#: and returns their DAVIS-layout root and resolution.
GENERATORS = {"rbsf": ensure_rbsf, "paste": ensure_pasted}
