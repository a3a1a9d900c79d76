"""Benchmark of the RBSF-style generator: frames per second at 427x240 (target: >= 20 frames/s on 2 cores).

Three numbers: generation alone (``generate_clip``: rendering, exact flow both ways, occlusions, depth) and the
whole ``eponet make-rbsf`` path (``write_dataset``: the same plus JPEG, PNG masks, two ``.flo`` files per frame
and the camera/depth files, into a temporary folder), and the same without flow and depth files.

    python benchmarks/bench_rbsf.py [--sequences 6] [--frames 30] [--size 427x240] [--seed 0]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time

import cv2
import numpy as np

from eponet.synth import generate_clip, write_dataset
from eponet.synth.cli import parse_size
from eponet.synth.writer import sequence_seed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", type=int, default=6)
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--size", type=parse_size, default=(427, 240))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    W, H = args.size
    total = args.sequences * args.frames

    generate_clip(12345, 3, (W, H))  # warm-up: loads the bundled photographs once

    start = time.perf_counter()
    per_clip = []
    for i in range(args.sequences):
        t0 = time.perf_counter()
        generate_clip(sequence_seed(args.seed, i), args.frames, (W, H))
        per_clip.append(args.frames / (time.perf_counter() - t0))
    generation = total / (time.perf_counter() - start)

    with tempfile.TemporaryDirectory(prefix="bench-rbsf-") as tmp:
        start = time.perf_counter()
        write_dataset(tmp, args.sequences, args.frames, (W, H), args.seed, progress=False)
        end_to_end = total / (time.perf_counter() - start)
    with tempfile.TemporaryDirectory(prefix="bench-rbsf-") as tmp:
        start = time.perf_counter()
        write_dataset(tmp, args.sequences, args.frames, (W, H), args.seed, progress=False, flow=False, depth=False)
        images_only = total / (time.perf_counter() - start)

    print(f"eponet RBSF generator, {args.sequences} sequences x {args.frames} frames at {W}x{H}")
    print(f"  machine: {platform.machine()}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}, OpenCV {cv2.__version__}, {cv2.getNumThreads()} threads")
    print(f"  generate_clip:            {generation:6.1f} frames/s  (per clip: min {min(per_clip):.1f}, median {np.median(per_clip):.1f}, max {max(per_clip):.1f})")
    print(f"  write_dataset (make-rbsf): {end_to_end:6.1f} frames/s  (with .jpg, .png, 2 x .flo per frame, cameras + depth)")
    print(f"  ... --no-flow --no-depth:  {images_only:6.1f} frames/s  (.jpg and .png only)")
    print(f"  target >= 20 frames/s: generation {'met' if generation >= 20 else 'NOT met'}, end to end {'met' if end_to_end >= 20 else 'NOT met'}")


if __name__ == "__main__":
    main()
