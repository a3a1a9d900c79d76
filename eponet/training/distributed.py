"""Training on several processes with torch DistributedDataParallel: the process group torchrun describes, the
epoch sampler that shards every global batch, and the few collectives the trainers need.

One process (no ``WORLD_SIZE`` in the environment, or 1) is the plain loop: no process group, every helper here
is the identity. Under ``torchrun --nproc-per-node N -m eponet.train spec.yaml`` each process joins the group
(gloo on CPU, NCCL on GPUs), trains a :class:`~torch.nn.parallel.DistributedDataParallel` copy of the network on
``batch_size / N`` samples of every global batch, and DDP averages the gradients, so that a step is the single
process's step on the whole batch (see :class:`EpochSampler` and the README's training section). BatchNorm layers
keep per-process statistics (``SyncBatchNorm`` is GPU-only in torch; eponet uses it on no backend), with rank 0's
running statistics, which DDP copies to the others before every forward.
"""

from __future__ import annotations

import gc
import logging
import os
import re
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta
from typing import Any, Callable, Iterator, Sequence

import numpy as np
import torch
import torch.distributed as dist
from torch.utils.data import DistributedSampler

from eponet.core.errors import EponetError, InputError, SpecError
from eponet.training.config import DEFAULT_TIMEOUT

__all__ = ["DistributedContext", "DistributedError", "EpochSampler", "SINGLE", "DEFAULT_TIMEOUT", "all_sum",
           "barrier", "broadcast_module", "broadcast_object", "check_global_batch", "collective_errors",
           "distributed_session", "environment", "threads_per_process", "wrap_model"]

log = logging.getLogger(__name__)


class DistributedError(EponetError):
    """The process group could not be joined, or another process of the run stopped answering."""

    exit_code = 1


@dataclass(frozen=True)
class DistributedContext:
    """Where this process stands in the run: ``rank`` of ``world_size`` processes (``local_rank`` of
    ``local_world_size`` on this machine), the ``backend`` and ``device`` of an active process group."""

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0
    local_world_size: int = 1
    backend: str | None = None
    device: str = "cpu"
    timeout: float = DEFAULT_TIMEOUT

    @property
    def active(self) -> bool:
        """Whether there is a process group (more than one process)."""
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        """Rank 0: the process that logs and writes checkpoints, history, curves, weights and the model card."""
        return self.rank == 0

    @property
    def label(self) -> str:
        return f"rank {self.rank}/{self.world_size}"

    def share_first(self, count: int) -> list[int]:
        """Indices ``0 .. count - 1`` with this process's share (``rank, rank + N, ...``) first: the order in
        which to compute data every process needs, so that the processes fill a shared cache side by side."""
        own = list(range(self.rank, count, self.world_size))
        return own + sorted(set(range(count)) - set(own))


#: The single-process context.
SINGLE = DistributedContext()


def environment() -> tuple[int, int, int, int]:
    """``(rank, world_size, local_rank, local_world_size)`` from the variables torchrun sets (all 0 / 1 without)."""
    names = ("RANK", "WORLD_SIZE", "LOCAL_RANK", "LOCAL_WORLD_SIZE")
    defaults = (0, 1, None, None)
    values = []
    for name, default in zip(names, defaults):
        raw = os.environ.get(name)
        if raw is None or raw == "":
            values.append(default)
            continue
        try:
            values.append(int(raw))
        except ValueError:
            raise InputError(f"environment variable {name}: expected an integer, got {raw!r}") from None
    rank, world, local_rank, local_world = values
    local_rank = rank if local_rank is None else local_rank
    local_world = world if local_world is None else local_world
    if world < 1 or not 0 <= rank < world:
        raise InputError(f"environment: RANK={rank} is not in [0, WORLD_SIZE={world})")
    return rank, world, local_rank, local_world


def threads_per_process(threads: int | None, local_world_size: int = 1) -> int:
    """``threads`` when given, else the machine's cores shared among its ``local_world_size`` processes."""
    return threads or max(1, (os.cpu_count() or 1) // max(1, local_world_size))


def _one_line(exc: BaseException) -> str:
    """The gist of a gloo / NCCL / c10d error: its first line, without the source location or the advice."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else exc.__class__.__name__
    text = re.sub(r"^\[[^\]]*\]\s*", "", text)
    return re.split(r"\.\s+This is typically caused", text)[0].strip()


def _is_collective_failure(exc: BaseException) -> bool:
    if isinstance(exc, getattr(dist, "DistError", ())):
        return True
    text = str(exc)
    return isinstance(exc, RuntimeError) and any(mark in text for mark in (
        "gloo", "NCCL", "Connection reset", "Connection closed", "Broken pipe", "Timed out", "timed out", "c10d"))


@contextmanager
def distributed_session(device: str = "auto", timeout: float = DEFAULT_TIMEOUT) -> Iterator[DistributedContext]:
    """Join the process group that torchrun's environment describes for the length of the block; yields the
    :class:`DistributedContext` (:data:`SINGLE` for one process, with no group).

    The backend is NCCL when ``device`` allows a GPU and this machine has one (each process then uses
    ``cuda:<local rank>``), else gloo. Joining waits at most ``timeout`` seconds for the others, and so does every
    collective afterwards. The group is left at the end of the block, also on failure.
    """
    rank, world, local_rank, local_world = environment()
    if world == 1:
        yield SINGLE
        return
    cuda = device in ("auto", "cuda") and torch.cuda.is_available()
    backend = "nccl" if cuda else "gloo"
    where = f"{os.environ.get('MASTER_ADDR', '?')}:{os.environ.get('MASTER_PORT', '?')}"
    if cuda:
        if local_rank >= torch.cuda.device_count():
            raise InputError(f"rank {rank}: local rank {local_rank} has no GPU ({torch.cuda.device_count()} on this "
                             "machine); run at most one process per GPU")
        torch.cuda.set_device(local_rank)
    context = DistributedContext(rank, world, local_rank, local_world, backend,
                                 f"cuda:{local_rank}" if cuda else "cpu", float(timeout))
    try:
        dist.init_process_group(backend, timeout=timedelta(seconds=timeout))
    except Exception as exc:
        raise DistributedError(f"{context.label}: could not join the {world} processes of the run at {where} "
                               f"within {timeout:g} s ({backend}): {_one_line(exc)}") from exc
    log.debug("%s: joined the process group (%s, %s)", context.label, backend, where)
    ended = False
    try:
        yield context
        ended = True
    finally:
        _leave(context, ended)


def _leave(context: DistributedContext, ended: bool) -> None:
    """Leave the process group. After a run that ended well every process first waits for the others (no process
    tears its connections down while a peer still uses them), and what still refers to the group (a DDP
    wrapper's reducer in a reference cycle) is collected first: gloo's worker threads are then joined while the
    interpreter is whole, not at its finalisation, where they abort the process ("terminate called without an
    active exception", exit -6)."""
    if ended:
        try:
            dist.barrier()
        except Exception:
            log.debug("%s: the closing barrier failed", context.label, exc_info=True)
    gc.collect()
    try:
        dist.destroy_process_group()
    except Exception:  # a peer that died may leave nothing to tear down cleanly
        log.debug("destroy_process_group failed", exc_info=True)


@contextmanager
def collective_errors(context: DistributedContext) -> Iterator[None]:
    """Turn the failure of a collective (another process died, or did not answer in time) into one
    :class:`DistributedError` line."""
    try:
        yield
    except EponetError:
        raise
    except Exception as exc:
        if context.active and _is_collective_failure(exc):
            raise DistributedError(
                f"{context.label}: lost contact with the other processes of the run (one of them stopped, or did not "
                f"answer within {context.timeout:g} s; see its own error line): {_one_line(exc)}") from exc
        raise


def wrap_model(context: DistributedContext, model):
    """``model`` in DistributedDataParallel under a process group (rank 0's parameters and buffers are copied to
    every process here, and its BatchNorm statistics before every forward), else ``model`` itself."""
    if not context.active:
        return model
    from torch.nn.parallel import DistributedDataParallel

    devices = [context.local_rank] if context.backend == "nccl" else None
    return DistributedDataParallel(model, device_ids=devices)


def all_sum(context: DistributedContext, values: Sequence[float]) -> list[float]:
    """Element-wise sums of ``values`` over the processes (float64); ``values`` itself for one process."""
    if not context.active:
        return [float(v) for v in values]
    tensor = torch.tensor([float(v) for v in values], dtype=torch.float64, device=context.device)
    dist.all_reduce(tensor, op=dist.ReduceOp.SUM)
    return tensor.cpu().tolist()


def broadcast_object(context: DistributedContext, value: Any) -> Any:
    """Rank 0's ``value`` (any picklable object; keep tensors on the CPU) on every process."""
    if not context.active:
        return value
    box = [value if context.is_main else None]
    dist.broadcast_object_list(box, src=0, device=torch.device(context.device))
    return box[0]


def barrier(context: DistributedContext) -> None:
    """Wait until every process gets here (nothing for one process)."""
    if context.active:
        dist.barrier()


def broadcast_module(context: DistributedContext, module) -> None:
    """Copy rank 0's parameters and buffers (BatchNorm statistics) of ``module`` into every process's copy."""
    if not context.active:
        return
    with torch.no_grad():
        for tensor in module.state_dict().values():
            dist.broadcast(tensor, src=0)


def check_global_batch(batch_size: int, processes: int) -> None:
    """A :class:`SpecError` unless the global batch ``batch_size`` is a multiple of the number of processes."""
    if batch_size % processes:
        raise SpecError(f"optimizer.batch_size: {batch_size} is not a multiple of the {processes} processes (it is "
                        f"the global batch; each process takes batch_size / {processes} samples of it)")


class _Epoch:
    """The sized "dataset" a DistributedSampler shards: the positions of one epoch's order."""

    def __init__(self, size: int):
        self.size = size

    def __len__(self) -> int:
        return self.size


class EpochSampler(DistributedSampler):
    """torch's :class:`~torch.utils.data.DistributedSampler` over one epoch's samples in an order the trainer
    draws.

    ``draw(epoch)`` returns the epoch's order: the ids of the samples in the order one process trains them, from
    the run's seed and the epoch, so every process draws the same. :meth:`set_epoch`, called every epoch, draws
    it. As in DistributedSampler, the order is padded with its first entries to a multiple of the number of
    processes ``N``, and process ``r`` takes positions ``r, r + N, ...`` (iterating yields their sample ids).
    :meth:`steps` cuts the order into global batches of ``batch_size`` positions (a multiple of ``N``) and
    :meth:`rows` gives this process's ``batch_size / N`` of one: global batch ``k`` is positions
    ``[k * batch_size, (k + 1) * batch_size)`` whatever ``N``, so with ``N`` dividing the epoch's length the
    processes together train on exactly the batches of one process. (torch's own shuffle is off: the order comes
    from ``draw``, which also knows ``samples_per_epoch`` and, for the fusion, the epoch's clips.)

    ``what`` names the samples in the error raised when an epoch has fewer of them than there are processes.
    """

    def __init__(self, draw: Callable[[int], np.ndarray], *, num_replicas: int = 1, rank: int = 0, seed: int = 0,
                 what: str = "the epoch"):
        super().__init__(_Epoch(0), num_replicas=num_replicas, rank=rank, shuffle=False, seed=seed, drop_last=False)
        self.draw = draw
        self.what = what
        self.order = np.zeros(0, np.int64)

    def set_epoch(self, epoch: int) -> None:
        super().set_epoch(epoch)
        self.order = np.asarray(self.draw(epoch), dtype=np.int64)
        count, processes = len(self.order), self.num_replicas
        if count < processes:
            raise InputError(f"{self.what}: {count} training sample{'s' if count != 1 else ''} per epoch for "
                             f"{processes} processes, and each process needs at least one; run at most {count} "
                             f"process{'es' if count != 1 else ''}")
        self.dataset = _Epoch(count)
        self.num_samples = -(-count // processes)
        self.total_size = self.num_samples * processes

    def sample(self, position: int) -> int:
        """The sample id at ``position`` of the (padded) epoch."""
        return int(self.order[position % len(self.order)])

    def positions(self) -> np.ndarray:
        """This process's positions in the padded epoch: ``rank, rank + N, ...``."""
        return np.arange(self.rank, self.total_size, self.num_replicas)

    def __iter__(self):
        return iter(self.order[self.positions() % len(self.order)].tolist())

    def __len__(self) -> int:
        return self.num_samples

    def steps(self, batch_size: int) -> list[np.ndarray]:
        """The epoch's global batches, as positions (the last one may be shorter, still a multiple of ``N``)."""
        check_global_batch(batch_size, self.num_replicas)
        return [np.arange(start, min(start + batch_size, self.total_size))
                for start in range(0, self.total_size, batch_size)]

    def rows(self, batch: np.ndarray) -> range:
        """This process's rows of a global batch from :meth:`steps` (its positions are ``batch[rows]``)."""
        return range(self.rank, len(batch), self.num_replicas)
