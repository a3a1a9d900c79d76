"""Training under DDP: the epoch sampler, and runs of 2 processes (gloo on 127.0.0.1, a free port, a timeout)
against one process, resume, a process that dies and more processes than samples.

The processes are started as torchrun starts them (``RANK``, ``WORLD_SIZE``, ``LOCAL_RANK``,
``LOCAL_WORLD_SIZE``, ``MASTER_ADDR``, ``MASTER_PORT``), each running ``eponet train`` through
:mod:`tests.training.ddp_worker` on the trainer tests' synthetic sets; one test goes through torchrun itself.
"""

from __future__ import annotations

import csv
import dataclasses
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

import eponet.training.base as base
from eponet.core.errors import InputError, SpecError
from eponet.training.config import load_train_config
from eponet.training.distributed import (DistributedContext, DistributedError, EpochSampler, collective_errors,
                                         threads_per_process)
from eponet.training.fusion import FusionTrainer
from eponet.training.trainer import MotionNetTrainer
from tests.training.test_fusion_trainer import easy_fusion_set
from tests.training.test_trainer import easy_sequences

REPO = Path(__file__).resolve().parents[2]
LAUNCH_TIMEOUT = 300  # seconds for a whole 2-process run (start-up of torch included, on a busy 2-core machine)


pytestmark = pytest.mark.usefixtures("one_torch_thread")


# -- the sampler and helpers, no processes ---------------------------------------------------------------------
@pytest.mark.parametrize("processes", [1, 2, 3])
def test_every_global_batch_is_shared_among_the_processes(processes):
    order = np.random.default_rng(0).permutation(10)
    samplers = [EpochSampler(lambda epoch: order, num_replicas=processes, rank=r) for r in range(processes)]
    for sampler in samplers:
        sampler.set_epoch(3)
        assert sampler.epoch == 3 and len(sampler) == -(-10 // processes)
    batches = samplers[0].steps(6)
    total = samplers[0].total_size  # padded with the first samples to a multiple of N, as DistributedSampler does
    assert total == 10 + (-10) % processes
    padded = [order[p % 10] for p in range(total)]
    assert np.concatenate(batches).tolist() == list(range(total))
    for batch in batches:
        shares = [batch[list(s.rows(batch))] for s in samplers]
        assert sorted(np.concatenate(shares).tolist()) == batch.tolist()  # together: the whole global batch
        assert len({len(share) for share in shares}) == 1  # as many samples each
    # iterating: DistributedSampler's sample ids, rank r taking positions r, r + N, ...
    assert [list(s) for s in samplers] == [[padded[p] for p in range(r, len(padded), processes)]
                                           for r in range(processes)]
    if processes == 1:
        assert list(samplers[0]) == order.tolist()  # one process: the order itself, in batches of 6
        assert [b.tolist() for b in batches] == [list(range(6)), list(range(6, 10))]


def test_set_epoch_draws_the_epochs_order_and_bad_sizes_are_one_line():
    sampler = EpochSampler(lambda epoch: np.arange(4) * epoch, num_replicas=2, rank=1)
    sampler.set_epoch(2)
    assert list(sampler) == [2, 6]
    with pytest.raises(SpecError, match=r"optimizer.batch_size: 3 is not a multiple of the 2 processes"):
        sampler.steps(3)
    few = EpochSampler(lambda epoch: np.arange(1), num_replicas=2, rank=0, what="phase 'easy'")
    with pytest.raises(InputError, match=r"^phase 'easy': 1 training sample per epoch for 2 processes.*at most 1 process$"):
        few.set_epoch(0)


def test_threads_and_data_order_per_process():
    cores = os.cpu_count() or 1
    assert threads_per_process(None, 2) == max(1, cores // 2) and threads_per_process(3, 2) == 3
    assert threads_per_process(None, 4 * cores) == 1
    assert DistributedContext(rank=1, world_size=3).share_first(7) == [1, 4, 0, 2, 3, 5, 6]
    assert DistributedContext().share_first(3) == [0, 1, 2]


def test_a_lost_process_is_one_line():
    context = DistributedContext(rank=0, world_size=2, backend="gloo", timeout=20)
    message = ("[/pytorch/third_party/gloo/gloo/transport/tcp/pair.cc:537] Read error [127.0.0.1]:4242: Connection "
               "reset by peer. This is typically caused by a remote worker hanging or bugs in the application.\nmore")
    with pytest.raises(DistributedError) as caught:
        with collective_errors(context):
            raise RuntimeError(message)
    assert str(caught.value) == ("rank 0/2: lost contact with the other processes of the run (one of them stopped, "
                                 "or did not answer within 20 s; see its own error line): Read error "
                                 "[127.0.0.1]:4242: Connection reset by peer")
    with pytest.raises(ValueError):  # other failures stay what they are
        with collective_errors(context):
            raise ValueError("shape")


def test_the_timeout_is_validated(tmp_path):
    spec = _spec(tmp_path, "motion_net", distributed={"timeout": 0})
    with pytest.raises(SpecError, match="distributed.timeout"):
        load_train_config(spec)
    assert load_train_config(_spec(tmp_path, "motion_net")).distributed == {"timeout": 60.0}


# -- runs of 2 processes ---------------------------------------------------------------------------------------
def _spec(folder: Path, task: str, epochs: int = 2, **changes) -> Path:
    (folder / "data" / "JPEGImages").mkdir(parents=True, exist_ok=True)  # a DAVIS root for validation; the
    source = {"davis": {"root": "data"}}                                 # worker trains on synthetic sets
    if task == "motion_net":
        document = {
            "task": task, "model": {"inputs": "ed+flow", "depth": 3, "widths": [8, 16, 16], "head_channels": 16},
            "phases": [{"name": "easy", "data": source, "epochs": epochs}],
            "optimizer": {"name": "adam", "lr": 0.003, "weight_decay": 0.0, "batch_size": 4},
            "input_dropout": {"probability": 0.5, "zero_epochs": 1},
            "augment": {"crop": [32, 48], "flip": True, "flow_shift": 0.3}}
    else:
        document = {
            "task": task, "model": {"bottleneck": 8, "hidden": 8, "kernel_size": 3},
            "appearance": {"plugin": "none"}, "clips": {"length": 6},
            "phases": [{"name": "easy", "data": source, "epochs": epochs, "samples_per_epoch": 4}],
            "optimizer": {"name": "rmsprop", "lr": 0.01, "batch_size": 2, "clip_gradients": 50.0},
            "input_dropout": {"probability": 0.2}, "augment": {"crop": [24, 40], "flip": True}}
    document.update({"seed": 0, "validation": source, "output": {"dir": "out"}, "cache": {"enabled": False},
                     "device": "cpu", "distributed": {"timeout": 60}}, **changes)
    path = folder / f"{task}.yaml"
    path.write_text(yaml.safe_dump(document))
    return path


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclasses.dataclass
class Process:
    returncode: int
    stdout: str
    stderr: str
    ended: float  # time.monotonic() when it was seen to end

    def errors(self) -> list[str]:
        """stderr without the INFO log lines."""
        return [line for line in self.stderr.splitlines() if line and not line.startswith("eponet: INFO")]


def _launch(spec: Path, *args: str, processes: int = 2, ranks: int | None = None,
            env: dict | None = None) -> list[Process]:
    """Run the first ``ranks`` (default: all) of ``processes`` ranks of the worker as torchrun would (its
    environment variables) and wait for them."""
    port, logs, running = _free_port(), spec.parent / "logs", []
    logs.mkdir(exist_ok=True)
    for rank in range(processes if ranks is None else ranks):
        variables = {**os.environ, "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": str(port), "RANK": str(rank),
                     "WORLD_SIZE": str(processes), "LOCAL_RANK": str(rank), "LOCAL_WORLD_SIZE": str(processes),
                     **(env or {})}
        out, err = (open(logs / f"{rank}.{name}", "w+") for name in ("out", "err"))
        command = [sys.executable, "-m", "tests.training.ddp_worker", str(spec), *args]
        running.append((subprocess.Popen(command, cwd=REPO, env=variables, stdout=out, stderr=err), out, err))
    ended: dict[int, float] = {}
    deadline = time.monotonic() + LAUNCH_TIMEOUT
    while len(ended) < len(running) and time.monotonic() < deadline:
        for rank, (process, _, _) in enumerate(running):
            if rank not in ended and process.poll() is not None:
                ended[rank] = time.monotonic()
        time.sleep(0.05)
    results = []
    for rank, (process, out, err) in enumerate(running):
        if rank not in ended:
            process.kill()
            process.wait()
        out.seek(0), err.seek(0)
        results.append(Process(process.returncode, out.read(), err.read(), ended.get(rank, float("inf"))))
        out.close(), err.close()
    assert len(ended) == len(running), f"the run did not end within {LAUNCH_TIMEOUT} s: {results}"
    return results


def _history(folder: Path) -> list[dict]:
    with open(folder / "history.csv") as handle:
        return [{k: v for k, v in row.items() if k != "seconds"} for row in csv.DictReader(handle)]


class PerProcessBatches(torch.nn.Module):
    """What DDP computes on N processes, on one: each process's share of a batch (rows r, r + N, ...) through
    the network on its own (BatchNorm with that share's statistics), the running statistics of rank 0's share
    (DDP copies rank 0's to the others before every forward, and rank 0 exports them)."""

    def __init__(self, model, processes: int):
        super().__init__()
        self.model, self.processes = model, processes

    def forward(self, x):
        norms = [m for m in self.model.modules() if isinstance(m, torch.nn.modules.batchnorm._BatchNorm)]
        names = ("running_mean", "running_var", "num_batches_tracked")
        kept = [[getattr(m, n) for n in names] for m in norms]
        for m in norms:  # the other shares update copies, which are then dropped
            for n in names:
                setattr(m, n, getattr(m, n).clone())
        outputs = {r: self.model(x[r :: self.processes]) for r in range(1, self.processes)}
        for m, buffers in zip(norms, kept):
            for n, buffer in zip(names, buffers):
                setattr(m, n, buffer)
        outputs[0] = self.model(x[0 :: self.processes])
        out = torch.empty((len(x),) + outputs[0].shape[1:], dtype=outputs[0].dtype)
        for r, value in outputs.items():
            out[r :: self.processes] = value
        return out


def _single_process(trainer_class, spec: Path, data, out: Path, *overrides: str, **kwargs):
    config = dataclasses.replace(load_train_config(spec, [f"output.dir={out}", *overrides]), threads=1)
    trainer = trainer_class(config, **kwargs)
    trainer.data = lambda source: data
    trainer.run()
    return trainer


def _assert_same_state(expected: dict, actual: dict, atol: float) -> None:
    for name, value in expected.items():
        assert torch.allclose(value.float(), actual[name].float(), rtol=0, atol=atol), \
            (name, float((value.float() - actual[name].float()).abs().max()))


def test_motion_net_on_two_processes_is_one_process_with_per_process_batchnorm(tmp_path, monkeypatch):
    spec = _spec(tmp_path, "motion_net")  # 12 frames, global batch 4: 3 steps per epoch, 2 epochs
    ranks = _launch(spec)
    assert [r.returncode for r in ranks] == [0, 0], ranks
    assert "trained 2 epochs on 2 processes" in ranks[0].stdout and not ranks[1].stdout
    assert ranks[0].errors() == [] and ranks[1].stderr == ""  # only rank 0 logs (and only it writes: the worker)
    out = tmp_path / "out"
    exported = torch.load(out / "weights.pt", weights_only=False)
    assert exported["meta"]["processes"] == 2 and "2 processes under DDP (gloo)" in (out / "model-card.md").read_text()
    # The U-Net's BatchNorm normalises each process's 2 samples with their own statistics: the same global batch
    # on one process, each share through the network on its own, gives the same weights, BatchNorm running
    # statistics and validation (float32 sums in another order: 1e-5).
    monkeypatch.setattr(base, "wrap_model", lambda context, model: PerProcessBatches(model, 2))
    reference = _single_process(MotionNetTrainer, spec, easy_sequences(count=2, frames=6), tmp_path / "single")
    _assert_same_state(reference.model.state_dict(), exported["state_dict"], atol=1e-5)
    assert _history(out) == _history(tmp_path / "single")


def test_fusion_on_two_processes_is_one_process_and_resumes_after_a_crash(tmp_path):
    # ConvGRU, no BatchNorm: 2 processes of 1 clip each train as one process on the global batch of 2 clips
    spec = _spec(tmp_path, "fusion", epochs=3)  # 4 clips per epoch: 2 steps per epoch
    crashed = _launch(spec, env={"DDP_TEST_SET": "2,8", "DDP_TEST_DIE": "1,2"})  # rank 1 killed in epoch 3
    assert [r.returncode for r in crashed] == [1, -9], crashed
    assert len(_history(tmp_path / "out")) == 2 and not (tmp_path / "out" / "weights.pt").exists()
    resumed = _launch(spec, "--resume", env={"DDP_TEST_SET": "2,8"})
    assert [r.returncode for r in resumed] == [0, 0], resumed
    assert "resuming after epoch 2" in resumed[0].stderr
    reference = _single_process(FusionTrainer, spec, easy_fusion_set(count=2, frames=8), tmp_path / "single",
                                appearance_channels=4)
    exported = torch.load(tmp_path / "out" / "weights.pt", weights_only=False)["state_dict"]
    # RMSProp divides by the root of small running means, which magnifies float32 differences of order 1e-7
    _assert_same_state(reference.model.state_dict(), exported, atol=1e-4)
    assert _history(tmp_path / "out") == _history(tmp_path / "single")


def test_a_process_that_dies_fails_the_run_in_one_line(tmp_path):
    spec = _spec(tmp_path, "motion_net", epochs=50)
    ranks = _launch(spec, env={"DDP_TEST_DIE": "1,1"})  # rank 1 is killed (SIGKILL) as its second epoch starts
    assert ranks[1].returncode == -9
    assert ranks[0].returncode == 1
    [line] = ranks[0].errors()
    assert line.startswith("error: rank 0/2: lost contact with the other processes of the run"), line
    assert ranks[0].ended - ranks[1].ended < 30  # noticed at once (its connections close), not after a timeout
    assert len(_history(tmp_path / "out")) == 1  # what rank 0 had finished is kept


def test_a_process_that_never_comes_fails_the_run_after_the_timeout(tmp_path):
    spec = _spec(tmp_path, "motion_net", distributed={"timeout": 5})
    started = time.monotonic()
    [rank0] = _launch(spec, ranks=1)  # rank 1 of 2 is never started
    assert rank0.returncode == 1
    [line] = rank0.errors()
    assert line.startswith("error: rank 0/2: could not join the 2 processes of the run at 127.0.0.1:"), line
    assert "within 5 s (gloo)" in line
    assert rank0.ended - started < LAUNCH_TIMEOUT / 2  # start-up, then 5 s of waiting


def test_more_processes_than_samples_under_torchrun(tmp_path):
    spec = _spec(tmp_path, "motion_net", phases=[{"name": "easy", "data": {"davis": {"root": "data"}}, "epochs": 1,
                                                   "samples_per_epoch": 1}])
    command = [sys.executable, "-m", "torch.distributed.run", "--nproc-per-node", "2", "--master-addr", "127.0.0.1",
               "--master-port", str(_free_port()), "-m", "tests.training.ddp_worker", str(spec)]
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=LAUNCH_TIMEOUT)
    ours = [line for line in (done.stdout + done.stderr).splitlines() if line.startswith("error:")]
    assert ours == ["error: phase 'easy': 1 training sample per epoch for 2 processes, and each process needs at "
                    "least one; run at most 1 process"]
    assert "exitcode  : 2" in done.stderr and done.returncode != 0  # each process exits 2; torchrun itself 1
    assert not (tmp_path / "out" / "checkpoint-last.pt").exists()
