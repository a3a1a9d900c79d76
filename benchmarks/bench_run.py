"""Throughput and memory of ``python -m eponet.run`` as a user runs it (start-up and model loading included),
against the machine's reference: OpenCV DIS ``medium`` forward+backward on the same frames at the processing size.

    python benchmarks/bench_run.py [--preset epo] [--frames 40] [--workers auto,1] [--lengths 300,1000] [--device cuda]

Multi-sequence run: the first ``--sequences`` DAVIS-2016 train sequences (sorted names) under ``--root``
(``../shared/data/davis2016-train/DAVIS``) as 854x480 frames (the shared data has 480p frames of three
sequences only, so the 240p frames are upsampled once into ``runs/davis-480p-from-240p``, as every held-out
figure does), at most ``--frames`` frames each (``input.max_frames``), scale 0.5, cache off, masks written
(ED maps for ``--preset geometry``, which has no refiner). For each ``--workers``
setting: frames/s, CPU % of one core (user + system time of the run's processes over its wall time), peak RSS of
the largest process and the share of each stage (from ``run.json``). Each figure is also given in reference
units: ``R`` = milliseconds per frame of DIS medium forward+backward, measured in the same invocation on the
same frames, single-threaded and with OpenCV's threads, so that figures from different days and machines
compare as ratios (cost = wall ms per frame / R). ``--device`` sets the ``device`` of every stage of the preset that
has one (the networks; the presets' ``auto`` takes a GPU when torch finds one); the first line names the GPU.

``--lengths``: one long video per length, a DAVIS sequence played forwards and backwards (a folder of symbolic
links to the frames, nothing copied) through the same command: frames/s and peak RSS against length;
``--rss-curve 300``: the run process's peak RSS per 300 frames written, to tell memory that grows with the video
from a higher constant. The child inherits the environment, so glibc's ``MALLOC_MMAP_THRESHOLD_`` (see the
README's "Speed" section) is measured by setting it for this command.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
DAVIS = Path(os.environ.get("EPONET_SHARED_DATA", ROOT.parent / "shared" / "data")) / "davis2016-train" / "DAVIS"


def reference_ms(files: list[Path], scale: float, threads: int | None) -> float:
    """Milliseconds per frame of DIS ``medium`` forward + backward between consecutive frames at ``scale``."""
    previous = cv2.getNumThreads()
    if threads is not None:
        cv2.setNumThreads(threads)
    try:
        grey = []
        for file in files:
            image = cv2.imread(str(file), cv2.IMREAD_GRAYSCALE)
            h, w = image.shape
            grey.append(cv2.resize(image, (int(round(w * scale)), int(round(h * scale))), interpolation=cv2.INTER_AREA))
        dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
        dis.calc(grey[0], grey[1], None)  # warm-up
        start = time.perf_counter()
        for a, b in zip(grey[:-1], grey[1:]):
            dis.calc(a, b, None)
            dis.calc(b, a, None)
        return (time.perf_counter() - start) * 1000 / (len(grey) - 1)
    finally:
        cv2.setNumThreads(previous)


def _rss_mb(pid: int) -> float:
    """Resident set of process ``pid`` in MB (0 once it is gone)."""
    try:
        with open(f"/proc/{pid}/status") as status:
            return next(int(line.split()[1]) for line in status if line.startswith("VmRSS")) / 1024
    except (OSError, StopIteration):
        return 0.0


def run_cli(spec: dict, folder: Path, quiet: bool = True, prefix: tuple = (), curve: int = 0) -> dict:
    """Run ``python -m eponet.run`` on ``spec`` in a child process (after ``prefix``, e.g. ``taskset -c 0``);
    wall time, CPU time and peak RSS. ``curve``: also sample the run process's RSS every second against the
    masks (or ED maps) written so far, and give its peak per ``curve`` frames (``rss_curve``: ``[(first frame, MB), ...]``)."""
    import yaml

    path = folder / "spec.yaml"
    path.write_text(yaml.safe_dump(spec))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    child = subprocess.Popen([*prefix, sys.executable, "-m", "eponet.run", str(path), "--no-cache", "-q"], cwd=folder,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    peaks: dict[int, float] = {}
    masks = Path(spec["output"]["dir"])
    while curve and child.poll() is None:
        written = sum(1 for f in masks.rglob("*") if f.suffix in (".png", ".npy")) if masks.is_dir() else 0
        peaks[written // curve] = max(peaks.get(written // curve, 0.0), _rss_mb(child.pid))
        time.sleep(1.0)
    stderr = child.communicate()[1]
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if child.returncode != 0:
        raise SystemExit(f"eponet.run failed ({child.returncode}): {stderr.strip()}")
    manifest = json.loads((Path(spec["output"]["dir"]) / "run.json").read_text())
    frames = sum(s["frames"] for s in manifest["sequences"].values())
    stages: dict[str, float] = {}
    for entry in manifest["sequences"].values():
        for kind, seconds in entry["timings_s"].items():
            stages[kind] = stages.get(kind, 0.0) + seconds
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"frames": frames, "wall_s": wall, "fps": frames / wall, "cpu_percent": 100 * cpu / wall,
            # ru_maxrss of RUSAGE_CHILDREN is the largest single descendant (KiB on Linux)
            "peak_rss_mb": after.ru_maxrss / 1024, "stages_s": stages, "workers": manifest.get("workers"),
            "resolved": manifest.get("resolved", {}),
            "rss_curve": [(k * curve, mb) for k, mb in sorted(peaks.items()) if mb > 0]}


def resolved_note(result: dict) -> str:
    """What the run's stages resolved at build (e.g. the motion net's device and precision), for the report."""
    parts = [f"{kind} {', '.join(f'{k} {v}' for k, v in values.items())}" for kind, values in result["resolved"].items()]
    return f"; resolved: {'; '.join(parts)}" if parts else ""


def long_video(folder: Path, files: list[Path], length: int) -> Path:
    """A frame folder of ``length`` symbolic links: the sequence forwards, backwards, forwards, ..."""
    folder.mkdir(parents=True, exist_ok=True)
    cycle = files + files[-2:0:-1]
    for t in range(length):
        (folder / f"{t:05d}{files[0].suffix}").symlink_to(cycle[t % len(cycle)])
    return folder


def device_stages(preset: str) -> list[str]:
    """The stage kinds of ``preset`` whose plugin has a ``device`` parameter (the networks)."""
    from eponet.core.registry import get_registry

    registry = get_registry()
    stages = registry.resolve_preset(preset)
    return [kind for kind, stage in stages.items() if isinstance(stage, dict) and "plugin" in stage
            and any(p.name == "device" for p in registry.get(kind, stage["plugin"]).params)]


def accelerator() -> str:
    """The GPU that ``device: auto`` finds, in words, or ``none``."""
    import torch

    if not torch.cuda.is_available():
        return "none"
    return f"{torch.cuda.get_device_name(0)} (torch {torch.__version__})"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="epo")
    parser.add_argument("--root", type=Path, default=DAVIS)
    parser.add_argument("--sequences", type=int, default=6, help="DAVIS sequences of the multi-sequence run")
    parser.add_argument("--frames", type=int, default=40, help="frames per sequence of the multi-sequence run")
    parser.add_argument("--workers", default="auto,1", help="comma-separated run.workers settings to measure "
                        "('': none, only the --lengths runs)")
    parser.add_argument("--lengths", default="", help="comma-separated lengths of single long videos (e.g. 300,1000)")
    parser.add_argument("--one-core", action="store_true",
                        help="also run each long video on one core (taskset -c 0): what the other cores add to one video")
    parser.add_argument("--rss-curve", type=int, default=0, metavar="FRAMES",
                        help="with --lengths: the run process's peak RSS per this many frames written (sampled every s)")
    parser.add_argument("--scale", type=float, default=0.5)
    parser.add_argument("--device", choices=("auto", "cpu", "cuda"), default=None,
                        help="device of every stage of the preset that has one (the networks; default: the "
                        "preset's, auto)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        help="extra spec values KEY.PATH=VALUE (YAML), e.g. run.chunk=32")
    args = parser.parse_args()

    import yaml

    from epo_ablation import validation_root

    if args.device:
        args.overrides[:0] = [f"stages.{kind}.device={args.device}" for kind in device_stages(args.preset)]

    sequences = sorted(p.name for p in (args.root / "JPEGImages" / "240p").iterdir() if p.is_dir())[: args.sequences]
    root = validation_root(args.root, sequences, ROOT / "runs")
    frames_root = root / "JPEGImages" / "480p"
    files = {name: sorted((frames_root / name).iterdir())[: args.frames] for name in sequences}
    all_files = [f for name in sequences for f in files[name]]
    r1 = np.mean([reference_ms(files[name], args.scale, 1) for name in sequences])
    rn = np.mean([reference_ms(files[name], args.scale, None) for name in sequences])
    h, w = cv2.imread(str(all_files[0])).shape[:2]
    print(f"reference R: DIS medium forward+backward at {int(round(w * args.scale))}x{int(round(h * args.scale))}: "
          f"{r1:.1f} ms/frame on one thread, {rn:.1f} ms/frame with {cv2.getNumThreads()} OpenCV threads "
          f"({os.cpu_count()} cores); GPU: {accelerator()}")

    def spec_for(path: Path, out: Path, workers, max_frames=None) -> dict:
        save = ["ed"] if args.preset == "geometry" else ["masks"]  # the geometry preset has no refiner
        spec = {"preset": args.preset, "input": {"path": str(path), "scale": args.scale, "max_frames": max_frames},
                "output": {"dir": str(out), "save": save}, "run": {"workers": workers},
                "cache": {"enabled": False}}
        for item in args.overrides:
            key, _, value = item.partition("=")
            node = spec
            for part in key.split(".")[:-1]:
                node = node.setdefault(part, {})
            node[key.split(".")[-1]] = yaml.safe_load(value)
        return spec

    with tempfile.TemporaryDirectory(prefix="bench-run-") as tmp:
        tmp = Path(tmp)
        results = {}
        print(f"\n{len(sequences)} sequences x {args.frames} frames ({', '.join(sequences)}), preset {args.preset}:")
        for workers in filter(None, args.workers.split(",")):  # --workers '': only the long videos
            workers = workers if workers == "auto" else int(workers)
            result = run_cli(spec_for(root, tmp / f"out-{workers}", workers, args.frames), tmp)
            results[workers] = result
            ms = 1000 / result["fps"]
            total = sum(v for k, v in result["stages_s"].items()) or 1.0
            shares = ", ".join(f"{k} {100 * v / total:.0f}%" for k, v in
                               sorted(result["stages_s"].items(), key=lambda kv: -kv[1]))
            print(f"  workers {workers} ({result['workers']} processes): {result['fps']:.2f} frames/s = {ms:.0f} ms/frame "
                  f"= {ms / r1:.1f} R1 ({ms / rn:.1f} Rn); CPU {result['cpu_percent']:.0f}%; peak RSS "
                  f"{result['peak_rss_mb']:.0f} MB; wall {result['wall_s']:.1f} s; stage time: {shares}"
                  f"{resolved_note(result)}")
        if "auto" in results and 1 in results:
            print(f"  speed-up auto / 1: {results['auto']['fps'] / results[1]['fps']:.2f}x")
        lengths = [int(v) for v in args.lengths.split(",") if v]
        for length in lengths:
            folder = long_video(tmp / f"long-{length}" / "video", files[sequences[0]], length)
            result = run_cli(spec_for(folder, tmp / f"long-out-{length}", 1), tmp, curve=args.rss_curve)
            ms = 1000 / result["fps"]
            print(f"  one video of {length} frames ({sequences[0]} forwards and backwards): {result['fps']:.2f} frames/s "
                  f"= {ms / r1:.1f} R1; CPU {result['cpu_percent']:.0f}%; peak RSS {result['peak_rss_mb']:.0f} MB")
            if result["rss_curve"]:
                print("    peak RSS of the run process while frames " + ", ".join(
                    (f"{first}-{min(first + args.rss_curve, length) - 1}" if first < length else "(the end)") + f": {mb:.0f}"
                    for first, mb in result["rss_curve"]) + " MB were written")
            if args.one_core:
                alone = run_cli(spec_for(folder, tmp / f"long-one-core-{length}", 1), tmp, prefix=("taskset", "-c", "0"))
                print(f"    on one core (taskset -c 0): {alone['fps']:.2f} frames/s = {1000 / alone['fps'] / r1:.1f} R1; "
                      f"all {os.cpu_count()} cores / one: {result['fps'] / alone['fps']:.2f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
