"""``eponet make-rbsf``: generate an RBSF-style synthetic data set in the DAVIS layout."""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from ..core.errors import EponetError, SpecError

__all__ = ["main", "build_parser", "parse_size"]

PROG = "eponet make-rbsf"


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage block) and exit code 2."""

    def error(self, message: str):  # noqa: D401 - argparse API
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def parse_size(text: str) -> tuple[int, int]:
    """``"427x240"`` -> ``(427, 240)``; sides from 16 to 8192."""
    parts = text.lower().replace("*", "x").split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH such as 427x240, got {text!r}") from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise argparse.ArgumentTypeError(f"each side must be 16..8192 pixels, got {text!r}")
    return w, h


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def _frames(text: str) -> int:
    value = _positive(text)
    if value < 3:
        raise argparse.ArgumentTypeError(f"expected at least 3 frames, got {text!r}")
    return value


def _seed(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a non-negative integer, got {text!r}")
    return value


def _quality(text: str) -> int:
    value = _positive(text)
    if value > 100:
        raise argparse.ArgumentTypeError(f"expected 1..100, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog=PROG,
        description=(
            "Generate RBSF-style synthetic videos (photographs on 3D planes seen by a moving camera, with "
            "independently moving textured objects) with exact ground truth, in the DAVIS layout: "
            "JPEGImages/, Annotations/, Annotations_unsupervised/, Flow/ (.flo + occlusions), Cameras/ (.npz), "
            "ImageSets/all.txt, db_info.yml."
        ),
    )
    parser.add_argument("--out", required=True, type=Path, help="output folder (created if missing)")
    parser.add_argument("--sequences", required=True, type=_positive, help="number of sequences")
    parser.add_argument("--frames", required=True, type=_frames, help="frames per sequence (>= 3)")
    parser.add_argument("--size", required=True, type=parse_size, help="frame size WxH, e.g. 427x240")
    parser.add_argument("--seed", required=True, type=_seed, help="seed; the same seed gives identical output")
    parser.add_argument("--backgrounds", type=Path, default=None, help="folder of photographs for the background (default: scikit-image's bundled photos)")
    parser.add_argument("--config", type=Path, default=None, help="YAML file of scene settings (eponet.synth.SceneConfig fields)")
    parser.add_argument("--no-flow", action="store_true", help="skip the .flo and occlusion files")
    parser.add_argument("--no-depth", action="store_true", help="skip the depth maps in Cameras/*.npz")
    parser.add_argument("--jpeg-quality", type=_quality, default=90, help="JPEG quality 1..100 (default 90)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging; tracebacks on errors")
    return parser


def _load_config(path: Path):
    import yaml

    from .scene import SceneConfig

    try:
        text = path.read_text()
    except OSError as exc:
        raise SpecError(f"cannot read the config file ({exc.strerror or exc})", file=str(path)) from None
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as exc:
        raise SpecError(f"not valid YAML ({str(exc).splitlines()[0]})", file=str(path)) from None
    return SceneConfig.from_dict(data, file=str(path))


def main(argv: list[str] | None = None) -> int:
    """Run ``eponet make-rbsf``; returns the exit code (0 ok, 2 bad arguments/input/output, 1 failure)."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help, or a bad argument (already reported on one line)
        return int(exc.code or 0) if not isinstance(exc.code, str) else 2
    if args.verbose:
        logging.basicConfig(level=logging.DEBUG, format="%(levelname)s %(name)s: %(message)s")
    from .writer import write_dataset

    try:
        config = _load_config(args.config) if args.config is not None else None
        entries = write_dataset(
            args.out,
            args.sequences,
            args.frames,
            args.size,
            args.seed,
            backgrounds=args.backgrounds,
            config=config,
            progress=not args.quiet and sys.stderr.isatty(),
            flow=not args.no_flow,
            depth=not args.no_depth,
            jpeg_quality=args.jpeg_quality,
        )
    except EponetError as exc:
        if args.verbose:
            raise
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except ValueError as exc:
        if args.verbose:
            raise
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug or an environment failure: one line, details behind -v
        if args.verbose:
            raise
        print(f"{PROG}: error: {exc.__class__.__name__}: {exc} (run with -v for the traceback)", file=sys.stderr)
        return 1
    if not args.quiet:
        frames = sum(e["num_frames"] for e in entries)
        print(f"wrote {len(entries)} sequences ({frames} frames) to {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
