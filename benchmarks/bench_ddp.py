"""Training throughput of the EpO motion network on 1 and on N processes under DDP (samples per second).

    python benchmarks/bench_ddp.py [--processes 1,2] [--samples 96] [--epochs 3] [--batch 12] [--device cpu]

Each setting is one ``torchrun --nproc-per-node N`` run of this script in ``--worker`` mode: the shipped recipe's
network, optimiser, loss, crops and input-dropout (``examples/train-epo.yaml``), global batch ``--batch``, on
synthetic 427x240 motion images held in memory (so the figure is the training loop's, not the geometry's), with
no validation. The first epoch is a warm-up; samples/s is over the others, from rank 0's epoch times. On one
machine the processes share its cores (``cores // N`` threads each), so on a CPU this is a check that DDP costs
little more than one process, not a speed-up; on GPUs (``--device cuda``, NCCL) run one process per GPU.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

RECIPE = {
    "task": "motion_net", "seed": 0,
    "model": {"inputs": "ed+flow", "depth": 4, "widths": [8, 16, 32, 64], "head_channels": 32, "ed_encoding": "log"},
    "optimizer": {"name": "adam", "lr": 0.001, "weight_decay": 0.0001, "batch_size": 12, "step_epochs": 6},
    "loss": {"name": "bce+iou"}, "input_dropout": {"probability": 0.2, "zero_epochs": 3},
    "augment": {"crop": [160, 288], "flip": True}, "cache": {"enabled": False},
}


def synthetic_sequences(samples: int, size=(240, 427), frames: int = 24):
    """Motion images float16 ``(F, 3, H, W)`` with a moving box of high ED, and its masks, ``samples`` frames in all."""
    from eponet.training.data import SequenceData

    rng = np.random.default_rng(0)
    out = []
    for s in range(-(-samples // frames)):
        count = min(frames, samples - s * frames)
        motion = rng.normal(0, 0.1, (count, 3, *size)).astype(np.float32)
        masks = np.zeros((count, *size), np.uint8)
        for t in range(count):
            y, x = 40 + 3 * t, 60 + 5 * t
            masks[t, y : y + 80, x : x + 120] = 1
        motion[:, 2] = np.abs(rng.normal(0.05, 0.03, (count, *size))) + 0.8 * masks
        out.append(SequenceData(f"synthetic{s}", motion.astype(np.float16), masks, np.zeros((count, 1, 1, 3), np.uint8)))
    return out


def worker(args) -> int:
    """One process of a run: train on the synthetic set under the process group torchrun describes."""
    from eponet.training.config import parse_train_config
    from eponet.training.distributed import distributed_session
    from eponet.training.trainer import MotionNetTrainer

    data = synthetic_sequences(args.samples)

    class SyntheticTrainer(MotionNetTrainer):
        def load_data(self, source):
            return data

    out = Path(args.out)
    (out / "data" / "JPEGImages").mkdir(parents=True, exist_ok=True)
    document = {**RECIPE, "phases": [{"name": "synthetic", "data": {"davis": {"root": str(out / "data")}},
                                      "epochs": args.epochs}],
                "optimizer": {**RECIPE["optimizer"], "batch_size": args.batch}, "output": {"dir": str(out / "train")},
                "device": args.device}
    config = parse_train_config(document, base_dir=out)
    with distributed_session(config.device, config.distributed["timeout"]) as context:
        SyntheticTrainer(config, context=context).run()
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--processes", default="1,2", help="comma-separated process counts")
    parser.add_argument("--samples", type=int, default=96, help="training samples (frames) per epoch")
    parser.add_argument("--epochs", type=int, default=3, help="epochs per run, the first one a warm-up")
    parser.add_argument("--batch", type=int, default=12, help="global batch (a multiple of every process count)")
    parser.add_argument("--device", default="cpu", choices=("cpu", "cuda", "auto"))
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        return worker(args)
    if args.epochs < 2:
        parser.error("--epochs: at least 2 (the first is a warm-up)")
    results = {}
    for processes in (int(p) for p in args.processes.split(",")):
        with tempfile.TemporaryDirectory() as tmp:
            command = [sys.executable, "-m", "torch.distributed.run", "--nproc-per-node", str(processes),
                       "--master-addr", "127.0.0.1", "--master-port", str(29400 + processes), __file__, "--worker",
                       "--out", tmp, "--samples", str(args.samples), "--epochs", str(args.epochs),
                       "--batch", str(args.batch), "--device", args.device]
            threads = max(1, (os.cpu_count() or 1) // processes)  # what each process sets; silences torchrun's notice
            subprocess.run(command, check=True, env={**os.environ, "OMP_NUM_THREADS": str(threads)},
                           stdout=subprocess.DEVNULL)
            with open(Path(tmp) / "train" / "history.csv") as handle:
                seconds = [float(row["seconds"]) for row in csv.DictReader(handle)][1:]
        results[processes] = args.samples * len(seconds) / sum(seconds)
        print(f"{processes} process{'es' if processes > 1 else ''}: {results[processes]:.1f} samples/s "
              f"({args.samples} samples x {len(seconds)} epochs after a warm-up, global batch {args.batch}, "
              f"{threads} thread{'s' if threads > 1 else ''} each, device {args.device})", flush=True)
    if 1 in results:
        for processes, rate in results.items():
            if processes != 1:
                print(f"{processes} processes / 1: {rate / results[1]:.2f}x")
    print(json.dumps({"samples_per_second": results}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
