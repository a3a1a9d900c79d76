"""Frames/s of a corpus run on a local Ray instance (``run.executor: ray``) against ``workers: 1``, and the figures
that bound the executor on N machines, measured here.

    python benchmarks/bench_ray.py [--preset epo] [--sequences 6] [--frames 40] [--storage-mbps 1000]

Both runs are ``python -m eponet.run`` as a user runs it (start-up, Ray's start and model loading included) on the
first ``--sequences`` DAVIS-2016 train sequences under ``--root`` (``../shared/data/davis2016-train/DAVIS``) as
854x480 frames (upsampled once from the 240p ones into ``runs/davis-480p-from-240p``: the shared data has 480p
frames of three sequences only), at most
``--frames`` frames each, scale 0.5, cache off, masks written: ``executor: local, workers: 1`` and ``executor:
ray, address: null`` (a local Ray instance with this machine's CPUs, one actor per CPU). Then, in this process:
the time to start a local Ray instance, to start one actor and build its pipeline (the model load per actor), the
round trip of an ``ActorPool`` call (the scheduling overhead per sequence), and the bytes read and written per
frame (what shared storage carries). From these, the estimate for N machines of C cores: one actor per core, a
corpus time of about ``start + actor start + ceil(S / (N C)) * (sequence time)`` and a throughput of at most
``N C`` times one actor's, capped by the storage bandwidth (``--storage-mbps``) over the bytes per frame.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
DAVIS = Path(os.environ.get("EPONET_SHARED_DATA", ROOT.parent / "shared" / "data")) / "davis2016-train" / "DAVIS"


def run_cli(spec: dict, folder: Path) -> dict:
    """``python -m eponet.run`` on ``spec`` in a child process: wall time, frames, frames/s and the run record."""
    import yaml

    path = folder / f"spec-{spec['run']['executor']}.yaml"
    path.write_text(yaml.safe_dump(spec))
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "eponet.run", str(path), "--no-cache", "-q"], cwd=folder,
                          capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"eponet.run failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
    record = json.loads((Path(spec["output"]["dir"]) / "run.json").read_text())
    frames = sum(s["frames"] for s in record["sequences"].values())
    return {"wall_s": wall, "frames": frames, "fps": frames / wall, "record": record}


def folder_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


def ray_overheads(spec_document: dict, pool_calls: int = 200) -> dict:
    """Seconds to start a local Ray instance and one actor with its pipeline, and ms per ActorPool round trip."""
    import logging

    import ray
    from ray.util import ActorPool

    from eponet.core.ray_executor import SequenceWorker
    from eponet.core.spec import parse_spec

    spec = parse_spec(spec_document)
    start = time.perf_counter()
    ray.init(address="local", include_dashboard=False, logging_level=logging.WARNING)
    started = time.perf_counter() - start
    try:
        @ray.remote(num_cpus=1)
        class Echo:
            def echo(self, value):
                return value

        start = time.perf_counter()
        worker = ray.remote(SequenceWorker).options(num_cpus=1).remote(spec, tempfile.gettempdir(), False, 1)
        ray.get(worker.describe.remote())
        actor = time.perf_counter() - start
        ray.kill(worker)
        echo = Echo.remote()
        ray.get(echo.echo.remote(0))  # started
        pool = ActorPool([echo])
        start = time.perf_counter()
        for k in range(pool_calls):
            pool.submit(lambda a, v: a.echo.remote(v), k)
        while pool.has_next():
            pool.get_next_unordered()
        per_call = (time.perf_counter() - start) * 1000 / pool_calls
    finally:
        ray.shutdown()
    return {"ray_start_s": started, "actor_start_s": actor, "pool_call_ms": per_call}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="epo")
    parser.add_argument("--root", type=Path, default=DAVIS)
    parser.add_argument("--sequences", type=int, default=6)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--scale", type=float, default=0.5)
    parser.add_argument("--storage-mbps", type=float, default=1000.0,
                        help="shared storage bandwidth (MB/s) for the estimate on N machines")
    args = parser.parse_args()

    from bench_run import reference_ms
    from epo_ablation import validation_root

    names = sorted(p.name for p in (args.root / "JPEGImages" / "240p").iterdir() if p.is_dir())[: args.sequences]
    if len(names) < args.sequences:
        raise SystemExit(f"{args.root}: {len(names)} sequences, fewer than --sequences {args.sequences}")
    root = validation_root(args.root, names, ROOT / "runs")
    frames_root = root / "JPEGImages" / "480p"
    r1 = np.mean([reference_ms(sorted((frames_root / n).iterdir())[: args.frames], args.scale, 1) for n in names])

    def spec(out: Path, **run) -> dict:
        return {"preset": args.preset, "input": {"path": str(root), "sequences": names, "scale": args.scale,
                                                 "max_frames": args.frames},
                "output": {"dir": str(out), "save": ["masks"]}, "cache": {"enabled": False}, "run": run}

    with tempfile.TemporaryDirectory(prefix="bench-ray-") as tmp:
        tmp = Path(tmp)
        local = run_cli(spec(tmp / "local", executor="local", workers=1), tmp)
        on_ray = run_cli(spec(tmp / "ray", executor="ray", address=None), tmp)
        written = folder_bytes(tmp / "ray") - (tmp / "ray" / "run.json").stat().st_size
        read = sum(f.stat().st_size for n in names for f in sorted((frames_root / n).iterdir())[: args.frames])
        overheads = ray_overheads(spec(tmp / "probe", executor="ray"))
    plan = on_ray["record"]["ray"]
    seconds = [e["seconds"] for e in on_ray["record"]["sequences"].values()]
    per_frame = (read + written) / on_ray["frames"]
    print(f"{len(names)} sequences x {args.frames} frames ({', '.join(names)}), preset {args.preset}, "
          f"{os.cpu_count()} cores")
    print(f"  reference R: DIS medium forward+backward at the processing size, one thread: {r1:.1f} ms/frame")
    print(f"  executor local, workers 1: {local['fps']:.2f} frames/s = {1000 / local['fps'] / r1:.1f} R per frame "
          f"(wall {local['wall_s']:.1f} s)")
    print(f"  executor ray, {plan['actors']} actors x {plan['cpus_per_actor']} CPU: {on_ray['fps']:.2f} frames/s "
          f"= {1000 / on_ray['fps'] / r1:.1f} R per frame (wall {on_ray['wall_s']:.1f} s); ratio "
          f"{on_ray['fps'] / local['fps']:.2f}x")
    print(f"  measured: Ray start {overheads['ray_start_s']:.1f} s, one actor with its pipeline "
          f"{overheads['actor_start_s']:.1f} s, ActorPool round trip {overheads['pool_call_ms']:.2f} ms per sequence, "
          f"a sequence {sum(seconds) / len(seconds):.1f} s in its actor, storage {per_frame / 1e6:.3f} MB per frame "
          f"(read {read / on_ray['frames'] / 1e6:.3f}, written {written / on_ray['frames'] / 1e6:.3f})")
    actor_fps = on_ray["frames"] / sum(seconds)  # one actor's frames/s while it works
    print(f"  estimate on N machines of C cores (one actor per core, {actor_fps:.2f} frames/s each; storage "
          f"{args.storage_mbps:g} MB/s caps the cluster at {args.storage_mbps * 1e6 / per_frame:.0f} frames/s):")
    for machines, cores in ((1, 2), (4, 16), (16, 16), (64, 16)):
        compute = machines * cores * actor_fps
        capped = min(compute, args.storage_mbps * 1e6 / per_frame)
        print(f"    N={machines:>3} C={cores:>2}: {capped:8.1f} frames/s ({'storage' if capped < compute else 'compute'}"
              f"-bound), start-up {overheads['ray_start_s'] + overheads['actor_start_s']:.0f} s once, scheduling "
              f"{overheads['pool_call_ms']:.1f} ms per sequence")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
