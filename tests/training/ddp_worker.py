"""One process of the DDP tests: ``python -m tests.training.ddp_worker spec.yaml [eponet train options]`` runs
``eponet train`` (torchrun's environment decides the process group) on the trainer tests' synthetic training
sets instead of the spec's DAVIS root.

Environment: ``DDP_TEST_SET=count,frames`` (the synthetic set's size), ``DDP_TEST_DIE=rank,epoch`` (that rank
kills itself with SIGKILL when that epoch starts). On ranks other than 0 every file write of the trainer fails,
so a test sees a rank that writes what only rank 0 may.
"""

from __future__ import annotations

import os
import signal
import sys


def main() -> int:
    from eponet.train import main as train_main
    from eponet.training import base
    from eponet.training.fusion import FusionTrainer
    from eponet.training.trainer import MotionNetTrainer
    from tests.training.test_fusion_trainer import easy_fusion_set
    from tests.training.test_trainer import easy_sequences

    count, frames = (int(v) for v in os.environ.get("DDP_TEST_SET", "2,6").split(","))
    rank = int(os.environ.get("RANK", "0"))
    MotionNetTrainer.load_data = lambda self, source: easy_sequences(count=count, frames=frames)
    FusionTrainer.load_data = lambda self, source: easy_fusion_set(count=count, frames=frames)
    import eponet.training.fusion as fusion

    fusion.probe_channels = lambda stage: 4  # easy_fusion_set's features

    if os.environ.get("DDP_TEST_DIE"):
        dying_rank, dying_epoch = (int(v) for v in os.environ["DDP_TEST_DIE"].split(","))
        for trainer in (MotionNetTrainer, FusionTrainer):
            def train_epoch(self, data, optimizer, epoch, samples, _original=trainer.train_epoch):
                if rank == dying_rank and epoch == dying_epoch:
                    os.kill(os.getpid(), signal.SIGKILL)
                return _original(self, data, optimizer, epoch, samples)

            trainer.train_epoch = train_epoch

    if rank:
        def refuse(*args, **kwargs):
            raise AssertionError(f"rank {rank} wrote a file")

        base.atomic_path = base.atomic_write_bytes = refuse
    return train_main(sys.argv[1:])


if __name__ == "__main__":
    raise SystemExit(main())
