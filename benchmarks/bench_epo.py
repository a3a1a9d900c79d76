"""Throughput of a preset end to end (default ``epo``): 854x480 input processed at scale 0.5, CRF included.

    python benchmarks/bench_epo.py [--preset epo] [--sequences dog-agility,rollerblade] [--frames 40]
                                   [--set stages.refiner.scale=0.5 ...]

Reads DAVIS-2016 480p sequences from ``../shared/data/davis2016-train/DAVIS`` (or ``--root``); with no data
there, a synthetic 854x480 clip is generated. The cache is disabled, so every stage is computed. Prints
frames per second, and each stage's seconds per frame and share of the total (reading frames and writing
masks included as ``read`` and ``write``).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DAVIS = Path(os.environ.get("EPONET_SHARED_DATA", ROOT.parent / "shared" / "data")) / "davis2016-train" / "DAVIS"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="epo")
    parser.add_argument("--root", type=Path, default=DAVIS)
    parser.add_argument("--sequences", default="dog-agility,rollerblade")
    parser.add_argument("--frames", type=int, default=40, help="frames per sequence")
    parser.add_argument("--set", dest="overrides", action="append", default=[])
    args = parser.parse_args()

    from eponet.core.cache import Cache
    from eponet.core.inputs import discover_sequences, load_video
    from eponet.core.outputs import write_sequence
    from eponet.core.pipeline import Pipeline, _Timer
    from eponet.core.progress import set_quiet
    from eponet.core.spec import apply_overrides, parse_spec

    set_quiet(True)
    with tempfile.TemporaryDirectory() as tmp:
        root, sequences = args.root, args.sequences.split(",")
        if not (root / "JPEGImages" / "480p").is_dir():
            from eponet.synth import write_dataset

            root, sequences = Path(tmp) / "synthetic", ["rbsf-0000"]
            write_dataset(root, 1, args.frames, (854, 480), 0, flow=False, depth=False)
            print(f"no DAVIS data at {args.root}: using a synthetic 854x480 clip")
        document = {"preset": args.preset,
                    "input": {"path": str(root), "resolution": "480p", "sequences": sequences, "scale": 0.5,
                              "max_frames": args.frames},
                    "output": {"dir": str(Path(tmp) / "out"), "save": ["masks"]}, "seed": 0}
        document, overridden = apply_overrides(document, args.overrides)
        spec = parse_spec(document, base_dir=Path.cwd(), overridden=overridden)
        pipeline = Pipeline(spec, cache=Cache(Path(tmp) / "cache", enabled=False))
        totals: dict[str, float] = {}
        frames = 0
        for source in discover_sequences(root, sequences=sequences, resolution="480p", max_frames=args.frames):
            tick = time.perf_counter()
            video = load_video(source, scale=0.5, max_frames=args.frames)
            totals["read"] = totals.get("read", 0.0) + time.perf_counter() - tick
            timer = _Timer()
            result = pipeline.process(video, timer)
            tick = time.perf_counter()
            write_sequence(result, spec.output.dir, ["masks"])
            totals["write"] = totals.get("write", 0.0) + time.perf_counter() - tick
            for stage, seconds in timer.timings.items():
                totals[stage] = totals.get(stage, 0.0) + seconds
            frames += video.num_frames
            print(f"{video.name}: {video.num_frames} frames {video.size[1]}x{video.size[0]} -> "
                  f"{video.shape[1]}x{video.shape[0]}")
    total = sum(totals.values())
    print(f"preset {args.preset}: {frames} frames in {total:.1f} s = {frames / total:.2f} frames/s "
          f"({os.cpu_count()} cores)")
    for stage, seconds in sorted(totals.items(), key=lambda kv: -kv[1]):
        print(f"  {stage:<14}{seconds / frames * 1000:8.0f} ms/frame {seconds / total:7.1%}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
