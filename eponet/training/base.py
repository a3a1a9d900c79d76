"""What every eponet trainer shares: seeding, the epoch loop over phases, checkpoints and resume, the history
CSV and curves, weights export and the pieces of a model card."""

from __future__ import annotations

import csv
from abc import ABC, abstractmethod
import io
import json
import logging
import time
from pathlib import Path

import numpy as np

from eponet.core.cache import Cache
from eponet.core.errors import InputError
from eponet.core.io import atomic_path, atomic_write_bytes
from eponet.training.config import DataSource, TrainConfig
from eponet.training.distributed import (SINGLE, DistributedContext, EpochSampler, all_sum, broadcast_module,
                                         broadcast_object, check_global_batch, collective_errors, threads_per_process,
                                         wrap_model)

__all__ = ["Trainer", "HISTORY_FIELDS", "sequence_j", "plot_history", "data_line", "history_table"]

log = logging.getLogger(__name__)

HISTORY_FIELDS = ("epoch", "phase", "lr", "train_loss", "val_loss", "val_j", "seconds")


def sequence_j(pred: np.ndarray, gt: np.ndarray) -> float:
    """DAVIS-2016 J mean of one sequence (first and last frame dropped), from the evaluation module."""
    from eponet.evaluation.metrics import db_eval_iou
    from eponet.evaluation.stats import davis2016_scored, mean

    scored = davis2016_scored(len(gt))
    return float(mean([db_eval_iou(p, g) for p, g in zip(pred[scored], gt[scored])]))


class Trainer(ABC):
    """The training loop; a subclass provides the model and the task.

    A subclass sets ``self.model`` (a torch module with a JSON-able ``config`` dict) in its ``__init__`` after
    calling this one (which seeds torch, so the model's initialisation is reproducible) and implements
    :meth:`load_data`, :meth:`train_epoch`, :meth:`validate_sequence`, :meth:`learning_rate` and
    :meth:`model_card`.

    ``context`` is where this process stands in a torchrun run (:func:`~.distributed.distributed_session`;
    default: one process). Under DDP, :meth:`train_epoch` trains ``self.net`` (the model wrapped in
    DistributedDataParallel) on this process's share of each global batch (:meth:`epoch_sampler`), validation is
    shared among the processes and all-reduced, and only rank 0 writes files.
    """

    def __init__(self, config: TrainConfig, *, context: DistributedContext = SINGLE):
        import torch

        self.config = config
        self.context = context
        self.out = Path(config.output_dir)
        self.cache = Cache(config.cache_dir, enabled=config.cache_enabled)
        torch.manual_seed(config.seed)
        threads = threads_per_process(config.threads, context.local_world_size)
        torch.set_num_threads(threads)
        if context.active:  # OpenCV (the geometry of the training data) shares the cores the same way
            import cv2

            cv2.setNumThreads(threads)
            self.device = torch.device(context.device)
        else:
            self.device = torch.device("cuda" if config.device in ("auto", "cuda") and torch.cuda.is_available() else "cpu")
        self.model = None
        self.net = None
        self.ema = None
        self.phase = None
        self._data: dict[str, list] = {}

    # -- what a task provides --------------------------------------------------------------------
    @abstractmethod
    def load_data(self, source: DataSource) -> list:
        """The training or validation sequences of ``source`` (called once per source)."""
        ...

    @abstractmethod
    def train_epoch(self, data: list, optimizer, epoch: int, samples: int | None) -> float:
        """One epoch of optimisation (``epoch`` counts from 0 over all phases) of ``self.net`` on this process's
        share of the epoch (:meth:`epoch_sampler`); returns the mean loss of its steps."""
        ...

    @abstractmethod
    def validate_sequence(self, model, sequence) -> tuple[float, int, float]:
        """``(sum of the per-frame BCE losses, frames, J)`` of ``model`` on one validation sequence."""
        ...

    @abstractmethod
    def learning_rate(self, epoch: int, epoch_in_phase: int) -> float:
        ...

    @abstractmethod
    def model_card(self, summary: dict, history: list[dict]) -> str:
        ...

    # -- shared ----------------------------------------------------------------------------------
    def data(self, source: DataSource | tuple[DataSource, ...]) -> list:
        """:meth:`load_data` of ``source``, kept in memory for the whole run; of several sources, their
        sequences one after the other (an epoch then draws from all of them, in proportion to their frames)."""
        if isinstance(source, tuple):
            return [sequence for one in source for sequence in self.data(one)]
        key = json.dumps({"kind": source.kind, **{k: str(v) for k, v in source.options.items()}}, sort_keys=True)
        if key not in self._data:
            self._data[key] = self.load_data(source)
        return self._data[key]

    def epoch_sampler(self, draw, epoch: int) -> EpochSampler:
        """The sampler of one epoch whose order ``draw(epoch)`` gives (see :class:`~.distributed.EpochSampler`),
        ``set_epoch(epoch)`` called. ``draw`` draws the order from the epoch's generator, which then draws the
        augmentation of every global batch in turn, the same on every process (each applies it to its rows)."""
        what = f"phase {self.phase.name!r}" if self.phase is not None else "the epoch"
        sampler = EpochSampler(draw, num_replicas=self.context.world_size, rank=self.context.rank,
                               seed=self.config.seed, what=what)
        sampler.set_epoch(epoch)
        return sampler

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

    def _start_ema(self) -> None:
        """With ``optimizer.ema`` > 0, keep an exponential moving average of the weights (BatchNorm statistics
        included) in ``self.ema``."""
        from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn

        decay = self.config.optimizer.get("ema") or 0.0
        self.ema = AveragedModel(self.model, multi_avg_fn=get_ema_multi_avg_fn(decay), use_buffers=True) if decay else None

    def after_step(self) -> None:
        """Called by :meth:`train_epoch` after every optimiser step: updates the weight average."""
        if self.ema is not None:
            self.ema.update_parameters(self.model)

    def inference_model(self):
        """The network that is validated and exported: the weight average when there is one."""
        return self.ema.module if self.ema is not None else self.model

    def validate(self, data: list) -> tuple[float, float]:
        """(mean BCE loss per frame, mean J over sequences) of :meth:`inference_model`. Under DDP every process
        first takes rank 0's weights and BatchNorm statistics (what is exported), scores its share of the
        sequences (``rank, rank + N, ...``), and the sums are all-reduced: every process gets the figures of the
        whole validation set, in about 1/N of the time."""
        model = self.inference_model()
        broadcast_module(self.context, model)
        totals = [0.0, 0.0, 0.0, 0.0]  # loss sum, frames, J sum, sequences
        for sequence in data[self.context.rank :: self.context.world_size]:
            loss, frames, j = self.validate_sequence(model, sequence)
            totals = [totals[0] + loss, totals[1] + frames, totals[2] + j, totals[3] + 1]
        loss, frames, j, count = all_sum(self.context, totals)
        return loss / frames, j / count

    def _save_checkpoint(self, optimizer, epoch: int, history: list[dict]) -> None:
        import torch

        state = {"model": self.model.state_dict(), "optimizer": optimizer.state_dict(), "epoch": epoch,
                 "history": history, "config": json.loads(json.dumps(self.config.document, default=str))}
        if self.ema is not None:
            state["ema"] = self.ema.state_dict()
        with atomic_path(self.out / "checkpoint-last.pt") as tmp:
            torch.save(state, tmp)

    def _load_checkpoint(self) -> dict:
        """``checkpoint-last.pt``, read by rank 0 and sent to the others (so ``output.dir`` need be on rank 0's
        machine only)."""
        import torch

        checkpoint = self.out / "checkpoint-last.pt"
        state = None
        if self.context.is_main and checkpoint.is_file():
            state = torch.load(checkpoint, map_location="cpu", weights_only=False)
        state = broadcast_object(self.context, state)
        if state is None:
            raise InputError(f"{checkpoint}: no checkpoint to resume from")
        return state

    def export_weights(self, path: Path, meta: dict) -> str:
        """Write inference weights (config + state dict + metadata) atomically; returns their sha256."""
        import torch

        from eponet.weights import sha256_of

        model = self.inference_model()
        state = {"config": json.loads(json.dumps(model.config)),
                 "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()}, "meta": meta}
        with atomic_path(path) as tmp:
            torch.save(state, tmp)
        return sha256_of(path)

    def weights_meta(self) -> dict:
        """Extra metadata stored with the exported weights (a subclass may add to it)."""
        return {}

    def run(self, resume: bool = False) -> dict:
        """Train every phase's epochs (continuing after the last checkpoint with ``resume``), writing a
        checkpoint, ``history.csv`` and ``curves.png`` after each epoch, then ``weights.pt``, ``summary.json`` and
        ``model-card.md``; returns the summary (on every process under DDP; rank 0 writes the files)."""
        with collective_errors(self.context):
            return self._run(resume)

    def _run(self, resume: bool) -> dict:
        import torch

        context = self.context
        check_global_batch(self.config.optimizer["batch_size"], context.world_size)  # before loading any data
        if context.is_main:
            self.out.mkdir(parents=True, exist_ok=True)
        self.net = wrap_model(context, self.model)
        if context.rank:  # torch's own randomness in training (dropout) differs between processes
            torch.manual_seed(int(np.random.SeedSequence([self.config.seed, context.rank]).generate_state(1)[0]))
        optimizer = self._optimizer()
        self._start_ema()
        history: list[dict] = []
        start_epoch = 0
        if resume:
            state = self._load_checkpoint()
            self.model.load_state_dict(state["model"])
            optimizer.load_state_dict(state["optimizer"])
            if self.ema is not None and "ema" in state:
                self.ema.load_state_dict(state["ema"])
            start_epoch, history = state["epoch"] + 1, state["history"]
            log.info("resuming after epoch %d", start_epoch)
        validation = self.data(self.config.validation) if self.config.validation else None
        schedule = [(phase, e) for phase in self.config.phases for e in range(phase.epochs)]
        for epoch in range(start_epoch, len(schedule)):
            phase, epoch_in_phase = schedule[epoch]
            self.phase = phase
            data = self.data(phase.data)
            lr = self.learning_rate(epoch, epoch_in_phase)
            for group in optimizer.param_groups:
                group["lr"] = lr
            tick = time.time()
            # every process has as many steps of equally many samples: the mean of the processes' means is the
            # mean over the global batches
            [loss] = all_sum(context, [self.train_epoch(data, optimizer, epoch, phase.samples_per_epoch)])
            loss /= context.world_size
            val_loss, val_j = self.validate(validation) if validation else (float("nan"), float("nan"))
            row = {"epoch": epoch + 1, "phase": phase.name, "lr": lr, "train_loss": round(loss, 5),
                   "val_loss": round(val_loss, 5), "val_j": round(val_j, 4), "seconds": round(time.time() - tick, 1)}
            history.append(row)
            if context.is_main:
                log.info("epoch %d (%s): loss %.4f, val loss %.4f, val J %.3f, %.0f s", epoch + 1, phase.name, loss,
                         val_loss, val_j, row["seconds"])
                self._save_checkpoint(optimizer, epoch, history)
                self._write_history(history)
        total = sum(r["seconds"] for r in history)
        summary = None
        if context.is_main:
            meta = {"history": history, "train_seconds": round(total, 1), "seed": self.config.seed,
                    "processes": context.world_size, "spec": json.loads(json.dumps(self.config.document, default=str)),
                    **self.weights_meta()}
            sha = self.export_weights(self.out / "weights.pt", meta)
            summary = {"weights": str(self.out / "weights.pt"), "sha256": sha, "epochs": len(history),
                       "train_seconds": round(total, 1), "processes": context.world_size,
                       "backend": context.backend, "final": history[-1] if history else None}
            atomic_write_bytes(self.out / "summary.json", json.dumps(summary, indent=2).encode())
            atomic_write_bytes(self.out / "model-card.md", self.model_card(summary, history).encode())
        # the others wait for rank 0's files, and return the same summary
        return broadcast_object(context, summary)

    def _write_history(self, history: list[dict]) -> None:
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=HISTORY_FIELDS)
        writer.writeheader()
        writer.writerows(history)
        atomic_write_bytes(self.out / "history.csv", buffer.getvalue().encode())
        plot_history(history, self.out / "curves.png")


def data_line(source: DataSource | tuple[DataSource, ...]) -> str:
    """One Markdown line describing a training or validation data source (or sources mixed)."""
    if isinstance(source, tuple):
        return " mixed with ".join(data_line(one) for one in source)
    o = source.options
    if source.kind == "rbsf":
        scene = o.get("scene") or {}
        settings = "".join(f", {k} {v}" for k, v in sorted(scene.items()))
        return (f"RBSF-style synthetic clips ({o.get('sequences')} x {o.get('frames')} frames, {o.get('size')}, "
                f"seed {o.get('seed')}{settings})")
    chosen = ", ".join(o["sequences"]) if o.get("sequences") else "all sequences"
    excluded = f" except {', '.join(o['exclude'])}" if o.get("exclude") else ""
    if source.kind == "paste":
        return (f"{o.get('clips')} clips x {o.get('frames')} frames of objects pasted over other sequences (seed "
                f"{o.get('seed')}, object area {o.get('object_area')} of the frame, speed {o.get('speed')} px per "
                f"frame) from DAVIS-layout root `{Path(str(o.get('root'))).name}` {o.get('resolution', '')}: "
                f"{chosen}{excluded}")
    return f"DAVIS-layout root `{Path(str(o.get('root'))).name}` {o.get('resolution', '')}: {chosen}{excluded}"


def trained_line(config: TrainConfig, summary: dict) -> str:
    """The model card's "trained with" line: spec, seed, epochs, wall time, machine, threads and device."""
    import platform

    import torch

    threads = torch.get_num_threads()
    processes = summary.get("processes", 1)
    where = (f"{threads} thread{'s' if threads != 1 else ''}" if processes == 1 else
             f"{processes} processes under DDP ({summary.get('backend')}), {threads} thread{'s' if threads != 1 else ''} each")
    return (f"- trained with `eponet train {Path(config.file).name if config.file else '<spec>'}`, seed {config.seed}, "
            f"{summary['epochs']} epochs in {summary['train_seconds'] / 60:.1f} min on {platform.machine()} "
            f"({where}, device {config.device})")


def history_table(history: list[dict]) -> list[str]:
    """The per-epoch figures as Markdown table lines (with the section heading)."""
    lines = ["", "## Training history", "", "| epoch | phase | lr | train loss | val loss | val J | s |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    lines += [f"| {r['epoch']} | {r['phase']} | {r['lr']:g} | {r['train_loss']} | {r['val_loss']} | {r['val_j']} | "
              f"{r['seconds']} |" for r in history]
    return lines


def plot_history(history: list[dict], path: Path) -> None:
    """Loss and validation-J curves per epoch as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    epochs = [r["epoch"] for r in history]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    left.plot(epochs, [r["train_loss"] for r in history], "o-", label="train")
    left.plot(epochs, [r["val_loss"] for r in history], "s-", label="validation")
    left.set_xlabel("epoch"), left.set_ylabel("loss (validation: BCE)"), left.legend(), left.grid(alpha=0.3)
    right.plot(epochs, [r["val_j"] for r in history], "o-", color="tab:green")
    right.set_xlabel("epoch"), right.set_ylabel("validation J mean (no CRF)"), right.grid(alpha=0.3)
    for boundary in [i for i in range(1, len(history)) if history[i]["phase"] != history[i - 1]["phase"]]:
        for axis in (left, right):
            axis.axvline(epochs[boundary] - 0.5, color="grey", linestyle="--")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    plt.close(fig)
