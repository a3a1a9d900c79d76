"""The training loop of the EpO motion network: phases (e.g. RBSF, then DAVIS), checkpoints, resume, curves."""

from __future__ import annotations

import csv
import io
import json
import logging
import os
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from eponet.core.cache import Cache
from eponet.core.errors import EponetError, InputError
from eponet.core.io import atomic_path, atomic_write_bytes
from eponet.core.progress import track
from eponet.training.augment import InputDropout, random_crop_flip
from eponet.training.config import DataSource, TrainConfig
from eponet.training.data import SequenceData, load_motion_sequences

__all__ = ["MotionNetTrainer", "sequence_j"]

log = logging.getLogger(__name__)

HISTORY_FIELDS = ("epoch", "phase", "lr", "train_loss", "val_loss", "val_j", "seconds")


def sequence_j(pred: np.ndarray, gt: np.ndarray) -> float:
    """DAVIS-2016 J mean of one sequence (first and last frame dropped), from the evaluation module."""
    from eponet.evaluation.metrics import db_eval_iou
    from eponet.evaluation.stats import davis2016_scored, mean

    scored = davis2016_scored(len(gt))
    return float(mean([db_eval_iou(p, g) for p, g in zip(pred[scored], gt[scored])]))


class MotionNetTrainer:
    """Trains an :class:`~eponet.nets.EpoUNet` as a :class:`TrainConfig` says."""

    def __init__(self, config: TrainConfig):
        import torch

        from eponet.nets import EpoUNet

        self.config = config
        self.out = Path(config.output_dir)
        self.cache = Cache(config.cache_dir, enabled=config.cache_enabled)
        torch.manual_seed(config.seed)
        torch.set_num_threads(max(1, os.cpu_count() or 1))
        self.device = torch.device("cuda" if config.device in ("auto", "cuda") and torch.cuda.is_available() else "cpu")
        self.model = EpoUNet(**self.model_config()).to(self.device).to(memory_format=torch.channels_last)
        self.dropout = InputDropout(**config.input_dropout)
        self._data: dict[str, list[SequenceData]] = {}

    def model_config(self) -> dict:
        model = dict(self.config.model)
        model["widths"] = tuple(model["widths"])
        return model

    # -- data ------------------------------------------------------------------------------------
    def data(self, source: DataSource) -> list[SequenceData]:
        key = json.dumps({"kind": source.kind, **{k: str(v) for k, v in source.options.items()}}, sort_keys=True)
        if key not in self._data:
            options = source.options
            if source.kind == "rbsf":
                root, resolution = self._ensure_rbsf(options)
                sequences, exclude = None, []
            else:
                root, resolution = options["root"], options["resolution"]
                sequences, exclude = options["sequences"], options["exclude"]
            self._data[key] = load_motion_sequences(self.config.geometry, Path(root), resolution=resolution,
                                                    sequences=sequences, exclude=exclude, cache=self.cache)
            if not self._data[key]:
                raise InputError(f"{root}: no training sequences left after exclusions")
        return self._data[key]

    def _ensure_rbsf(self, options: dict) -> tuple[Path, str]:
        from eponet.synth import write_dataset

        width, _, height = options["size"].partition("x")
        size = (int(width), int(height))
        root = Path(options["dir"])
        marker = root / "eponet-rbsf.json"
        recipe = {k: options[k] for k in ("sequences", "frames", "size", "seed")}
        if not (marker.is_file() and json.loads(marker.read_text()) == recipe):
            log.info("generating RBSF-style data in %s", root)
            write_dataset(root, options["sequences"], options["frames"], size, options["seed"], flow=False, depth=False)
            atomic_write_bytes(marker, json.dumps(recipe).encode())
        return root, f"{size[1]}p"

    # -- optimisation ----------------------------------------------------------------------------
    def _optimizer(self):
        import torch

        o = self.config.optimizer
        params = self.model.parameters()
        if o["name"] == "sgd":
            return torch.optim.SGD(params, lr=o["lr"], momentum=o["momentum"], weight_decay=o["weight_decay"])
        if o["name"] == "rmsprop":
            return torch.optim.RMSprop(params, lr=o["lr"], momentum=o["momentum"], weight_decay=o["weight_decay"])
        if o["name"] == "adamw":
            return torch.optim.AdamW(params, lr=o["lr"], weight_decay=o["weight_decay"])
        return torch.optim.Adam(params, lr=o["lr"], weight_decay=o["weight_decay"])

    def _lr(self, epoch_in_phase: int) -> float:
        o = self.config.optimizer
        return o["lr"] * o["gamma"] ** (epoch_in_phase // o["step_epochs"])

    def train_epoch(self, data: list[SequenceData], optimizer, epoch: int, samples: int | None) -> float:
        import torch
        import torch.nn.functional as F

        rng = np.random.default_rng([self.config.seed, epoch])
        index = np.array([(s, t) for s, seq in enumerate(data) for t in range(len(seq.masks))])
        order = rng.permutation(len(index))
        if samples is not None:
            order = np.resize(order, samples)
        batch_size = self.config.optimizer["batch_size"]
        crop = tuple(self.config.augment["crop"]) if self.config.augment["crop"] else None
        self.model.train()
        losses = []
        batches = range(0, len(order), batch_size)
        for start in track(batches, desc=f"epoch {epoch + 1}", total=len(batches)):
            images, masks = [], []
            for s, t in index[order[start : start + batch_size]]:
                image, mask = random_crop_flip(data[s].motion[t].astype(np.float32), data[s].masks[t], crop,
                                               self.config.augment["flip"], rng)
                images.append(image)
                masks.append(mask)
            shapes = {m.shape for m in masks}
            if len(shapes) > 1:  # sequences of different sizes without a crop: train them one by one
                h, w = min(s[0] for s in shapes), min(s[1] for s in shapes)
                images = [i[:, :h, :w] for i in images]
                masks = [m[:h, :w] for m in masks]
            batch, _ = self.dropout.apply(np.stack(images), epoch, rng)
            x = torch.from_numpy(batch).to(self.device)
            x = self.model.select_inputs(x).contiguous(memory_format=torch.channels_last)
            y = torch.from_numpy(np.stack(masks).astype(np.float32)).to(self.device)[:, None]
            loss = F.binary_cross_entropy_with_logits(self.model(x), y)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            losses.append(loss.item())
        return float(np.mean(losses))

    def validate(self, data: list[SequenceData]) -> tuple[float, float]:
        """(mean BCE loss, mean J over sequences) of whole frames, threshold 0.5, no CRF."""
        import torch
        import torch.nn.functional as F

        self.model.eval()
        losses, scores = [], []
        with torch.inference_mode():
            for seq in data:
                probs = []
                for start in range(0, len(seq.masks), 8):
                    x = torch.from_numpy(seq.motion[start : start + 8].astype(np.float32)).to(self.device)
                    x = self.model.select_inputs(x).contiguous(memory_format=torch.channels_last)
                    logits = self.model(x)
                    y = torch.from_numpy(seq.masks[start : start + 8].astype(np.float32)).to(self.device)[:, None]
                    losses.append(float(F.binary_cross_entropy_with_logits(logits, y)) * len(y))
                    probs.append(torch.sigmoid(logits)[:, 0].cpu().numpy())
                pred = np.concatenate(probs) >= 0.5
                scores.append(sequence_j(pred, seq.masks.astype(bool)))
        frames = sum(len(s.masks) for s in data)
        return sum(losses) / frames, float(np.mean(scores))

    # -- checkpoints -----------------------------------------------------------------------------
    def _save_checkpoint(self, optimizer, epoch: int, history: list[dict]) -> None:
        import torch

        state = {"model": self.model.state_dict(), "optimizer": optimizer.state_dict(), "epoch": epoch,
                 "history": history, "config": json.loads(json.dumps(self.config.document, default=str))}
        with atomic_path(self.out / "checkpoint-last.pt") as tmp:
            torch.save(state, tmp)

    def export_weights(self, path: Path, meta: dict) -> str:
        """Write inference weights (config + state dict + metadata) atomically; returns their sha256."""
        import torch

        from eponet.weights import sha256_of

        state = {"config": {**self.model.config, "widths": list(self.model.config["widths"])},
                 "state_dict": {k: v.detach().cpu() for k, v in self.model.state_dict().items()}, "meta": meta}
        with atomic_path(path) as tmp:
            torch.save(state, tmp)
        return sha256_of(path)

    # -- the whole run ---------------------------------------------------------------------------
    def run(self, resume: bool = False) -> dict:
        import torch

        self.out.mkdir(parents=True, exist_ok=True)
        optimizer = self._optimizer()
        history: list[dict] = []
        start_epoch = 0
        checkpoint = self.out / "checkpoint-last.pt"
        if resume:
            if not checkpoint.is_file():
                raise InputError(f"{checkpoint}: no checkpoint to resume from")
            state = torch.load(checkpoint, map_location=self.device, weights_only=False)
            self.model.load_state_dict(state["model"])
            optimizer.load_state_dict(state["optimizer"])
            start_epoch, history = state["epoch"] + 1, state["history"]
            log.info("resuming after epoch %d", start_epoch)
        validation = self.data(self.config.validation) if self.config.validation else None
        schedule = [(phase, e) for phase in self.config.phases for e in range(phase.epochs)]
        started = time.time()
        for epoch in range(start_epoch, len(schedule)):
            phase, epoch_in_phase = schedule[epoch]
            data = self.data(phase.data)
            lr = self._lr(epoch_in_phase)
            for group in optimizer.param_groups:
                group["lr"] = lr
            tick = time.time()
            loss = self.train_epoch(data, optimizer, epoch, phase.samples_per_epoch)
            val_loss, val_j = self.validate(validation) if validation else (float("nan"), float("nan"))
            row = {"epoch": epoch + 1, "phase": phase.name, "lr": lr, "train_loss": round(loss, 5),
                   "val_loss": round(val_loss, 5), "val_j": round(val_j, 4), "seconds": round(time.time() - tick, 1)}
            history.append(row)
            log.info("epoch %d (%s): loss %.4f, val loss %.4f, val J %.3f, %.0f s", epoch + 1, phase.name, loss,
                     val_loss, val_j, row["seconds"])
            self._save_checkpoint(optimizer, epoch, history)
            self._write_history(history)
        total = sum(r["seconds"] for r in history)
        meta = {"history": history, "train_seconds": round(total, 1), "seed": self.config.seed,
                "spec": json.loads(json.dumps(self.config.document, default=str))}
        sha = self.export_weights(self.out / "weights.pt", meta)
        summary = {"weights": str(self.out / "weights.pt"), "sha256": sha, "epochs": len(history),
                   "train_seconds": round(total, 1), "final": history[-1] if history else None}
        atomic_write_bytes(self.out / "summary.json", json.dumps(summary, indent=2).encode())
        return summary

    def _write_history(self, history: list[dict]) -> None:
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=HISTORY_FIELDS)
        writer.writeheader()
        writer.writerows(history)
        atomic_write_bytes(self.out / "history.csv", buffer.getvalue().encode())
        plot_history(history, self.out / "curves.png")


def plot_history(history: list[dict], path: Path) -> None:
    """Loss and validation-J curves per epoch as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [r["epoch"] for r in history]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    left.plot(epochs, [r["train_loss"] for r in history], "o-", label="train")
    left.plot(epochs, [r["val_loss"] for r in history], "s-", label="validation")
    left.set_xlabel("epoch"), left.set_ylabel("BCE loss"), left.legend(), left.grid(alpha=0.3)
    right.plot(epochs, [r["val_j"] for r in history], "o-", color="tab:green")
    right.set_xlabel("epoch"), right.set_ylabel("validation J mean (no CRF)"), right.grid(alpha=0.3)
    for boundary in [i for i in range(1, len(history)) if history[i]["phase"] != history[i - 1]["phase"]]:
        for axis in (left, right):
            axis.axvline(epochs[boundary] - 0.5, color="grey", linestyle="--")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)
