"""``python -m eponet.train spec.yaml [--resume] [--set KEY=VALUE ...]``: train the network the spec's ``task``
names (``motion_net``: the EpO motion network; ``fusion``: the EpO+ ConvGRU fusion), on one process or, under
``torchrun --nproc-per-node N -m eponet.train spec.yaml``, on N processes with DistributedDataParallel."""

from __future__ import annotations

import argparse
import logging
import sys

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    from eponet.cli import _configure_logging, guarded

    parser = argparse.ArgumentParser(prog="eponet train", description="Train a network from a training spec.")
    parser.add_argument("spec", help="training spec (YAML)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE")
    parser.add_argument("--resume", action="store_true", help="continue from the last checkpoint in output.dir")
    parser.add_argument("-v", "--verbose", action="store_true")
    parser.add_argument("-q", "--quiet", action="store_true")
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    _configure_logging(args.verbose, args.quiet)

    def run(args) -> int:
        from eponet.core.errors import EponetError
        from eponet.core.progress import set_quiet
        from eponet.training.config import load_train_config
        from eponet.training.distributed import DistributedError, distributed_session, environment

        set_quiet(args.quiet)
        rank, world = environment()[:2]
        if rank:  # rank 0 logs and shows progress for the run
            set_quiet(True)
            logging.getLogger().setLevel(logging.ERROR)
        try:
            config = load_train_config(args.spec, args.overrides)
            if config.task == "fusion":
                from eponet.training.fusion import FusionTrainer as trainer_class
            else:
                from eponet.training.trainer import MotionNetTrainer as trainer_class
            with distributed_session(config.device, config.distributed["timeout"]) as context:
                summary = trainer_class(config, context=context).run(resume=args.resume)
        except EponetError as exc:
            if world > 1 and exc.exit_code == 2 and rank:
                return exc.exit_code  # a bad spec or input: every process finds it alike, and rank 0 says so
            if world > 1 and exc.exit_code != 2 and not isinstance(exc, DistributedError):
                raise DistributedError(f"rank {rank}/{world}: {exc}") from exc
            raise
        except Exception as exc:
            if world > 1:
                raise DistributedError(f"rank {rank}/{world}: {exc.__class__.__name__}: {exc}") from exc
            raise
        if not args.quiet and not rank:
            final = summary["final"] or {}
            processes = f" on {world} processes" if world > 1 else ""
            print(f"trained {summary['epochs']} epochs{processes} in {summary['train_seconds']:.0f} s; "
                  f"final val J {final.get('val_j')}; weights {summary['weights']} (sha256 {summary['sha256'][:16]}...)")
        return 0

    return guarded(run, args)


if __name__ == "__main__":
    raise SystemExit(main())
