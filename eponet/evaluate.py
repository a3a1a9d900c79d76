"""``python -m eponet.evaluate``: score a results folder with the DAVIS protocol and print the paper's tables."""

from __future__ import annotations

import argparse
import logging
import sys
import traceback
from pathlib import Path

from .core.errors import EponetError, SpecError

__all__ = ["main", "build_parser"]

log = logging.getLogger("eponet")

_PROG = "python -m eponet.evaluate"


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line on stderr and exit code 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    from .evaluation.datasets import DATASETS

    parser = _Parser(
        prog=_PROG,
        description="Evaluate segmentation results with the DAVIS protocol (J, F, T; Mean/Recall/Decay) and print "
                    "the EpO paper's Table 2 and Table 3 (attributes).",
    )
    parser.add_argument("--dataset", required=True, metavar="NAME",
                        help=f"one of: {', '.join(DATASETS)} (aliases like DAVIS-2016 accepted)")
    parser.add_argument("--root", required=True, type=Path, help="the data set's root folder")
    parser.add_argument("--results", required=True, type=Path,
                        help="folder holding <seq>/masks/<frame>.png or <seq>/<frame>.png")
    parser.add_argument("--sequences", metavar="A,B", help="only these sequences (comma-separated)")
    parser.add_argument("--split", help="DAVIS: a set of db_info.yml / ImageSets (train, val); FBMS: train or test")
    parser.add_argument("--resolution", default="480p", help="DAVIS annotation resolution (default: 480p)")
    parser.add_argument("--frames", type=Path, help="folders dataset only: the frames folder that orders frames")
    parser.add_argument("--max-frames", type=int, metavar="N",
                        help="score only the first N frames of each sequence (default: the input.max_frames that "
                             "RESULTS/run.json records)")
    parser.add_argument("--json", type=Path, metavar="OUT.json", help="write the results as JSON")
    parser.add_argument("--csv", type=Path, metavar="OUT.csv", help="write per-sequence rows as CSV")
    parser.add_argument("--chart", type=Path, metavar="PATH.png",
                        help="per-sequence J/F bar chart (default: beside --json, same name with .png)")
    parser.add_argument("--no-t", action="store_true", help="skip the temporal stability T (the slow part)")
    parser.add_argument("--workers", type=int, default=None, metavar="N",
                        help="worker processes for T and DAVIS-2017 (default: min(2, CPUs))")
    parser.add_argument("--per-frame", action="store_true", help="keep per-frame values in the JSON")
    parser.add_argument("--method", default="eponet", help="column name in the printed tables")
    parser.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging and tracebacks")
    return parser


def _configure_logging(verbose: bool, quiet: bool) -> None:
    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    logging.basicConfig(level=level, format="eponet: %(levelname)s: %(message)s", stream=sys.stderr, force=True)
    for noisy in ("PIL", "matplotlib"):
        logging.getLogger(noisy).setLevel(logging.WARNING)


def _run(args: argparse.Namespace) -> int:
    from .core.errors import InputError
    from .evaluation import evaluate
    from .evaluation.report import default_chart_path, format_report, write_bar_chart, write_csv, write_json

    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers: expected a positive integer, got {args.workers}")
    sequences = None
    if args.sequences is not None:
        sequences = [s.strip() for s in args.sequences.split(",") if s.strip()]
        if not sequences:
            raise InputError("--sequences: no sequence names given")
    max_frames = args.max_frames if args.max_frames is not None else _recorded_max_frames(args.results)
    if max_frames is not None and max_frames < 1:
        raise InputError(f"--max-frames: expected a positive integer, got {max_frames}")
    result = evaluate(
        args.dataset, args.root, args.results, sequences=sequences, resolution=args.resolution, split=args.split,
        frames=args.frames, compute_t=not args.no_t, workers=args.workers, per_frame=args.per_frame,
        max_frames=max_frames,
    )
    if not args.quiet:
        sys.stdout.write(format_report(result, method=args.method))
    if args.json is not None:
        write_json(result, args.json)
        log.info("wrote %s", args.json)
    if args.csv is not None:
        write_csv(result, args.csv)
        log.info("wrote %s", args.csv)
    chart = args.chart if args.chart is not None else (default_chart_path(args.json) if args.json else None)
    if chart is not None:
        write_bar_chart(result, chart)
        log.info("wrote %s", chart)
    return 0


def _recorded_max_frames(results: Path) -> int | None:
    """The ``input.max_frames`` of the eponet run that wrote ``results`` (its ``run.json``), if any."""
    import json

    try:
        record = json.loads((results / "run.json").read_text())
        value = record["spec"]["input"]["max_frames"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if isinstance(value, int) and not isinstance(value, bool):
        log.info("%s: the run processed the first %d frames of each sequence (input.max_frames); scoring those",
                 results / "run.json", value)
        return value
    return None


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point; returns the exit code (0 success, 2 bad input, 1 other failure)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    _configure_logging(args.verbose, args.quiet)
    try:
        return _run(args)
    except SpecError as exc:
        if args.verbose:
            traceback.print_exc()
        print(f"error: {'; '.join(exc.problems)}", file=sys.stderr)
        return exc.exit_code
    except EponetError as exc:
        if args.verbose:
            traceback.print_exc()
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    except OSError as exc:  # e.g. an unreadable results folder
        if args.verbose:
            traceback.print_exc()
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
