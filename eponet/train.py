"""``python -m eponet.train spec.yaml [--resume] [--set KEY=VALUE ...]``: train the network the spec's ``task``
names (``motion_net``: the EpO motion network; ``fusion``: the EpO+ ConvGRU fusion)."""

from __future__ import annotations

import argparse
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
        from eponet.core.progress import set_quiet
        from eponet.training.config import load_train_config

        set_quiet(args.quiet)
        config = load_train_config(args.spec, args.overrides)
        if config.task == "fusion":
            from eponet.training.fusion import FusionTrainer as trainer_class
        else:
            from eponet.training.trainer import MotionNetTrainer as trainer_class
        summary = trainer_class(config).run(resume=args.resume)
        if not args.quiet:
            final = summary["final"] or {}
            print(f"trained {summary['epochs']} epochs in {summary['train_seconds']:.0f} s; "
                  f"final val J {final.get('val_j')}; weights {summary['weights']} (sha256 {summary['sha256'][:16]}...)")
        return 0

    return guarded(run, args)


if __name__ == "__main__":
    raise SystemExit(main())
