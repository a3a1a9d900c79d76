"""Speed and memory of the geometry stages: dense trajectories + trifocal rigidity (with painting).

Prints seconds per frame, the cost in R (DIS ``medium`` forward + backward per frame on the same frames at the
same size, one thread, measured in the same run) and the peak resident memory of a fresh process for 25, 50 and
100 frames at 854x480 and 427x240. Flow is precomputed (OpenCV DIS, preset medium) and not timed. The video is a
real DAVIS sequence played forwards and backwards until it has 100 frames ("ping-pong": the flow of a reversed
pair is the original pair's backward/forward flow), or, without the shared data, a synthetic rendered scene.

Two paths (``--path``):

- ``loop`` (the default): what a user's run costs. ``python -m eponet.run`` with the ``geometry`` preset, its flow
  stage replaced by the ``flo`` stage reading the precomputed flow, on the frames written as PNG at the size:
  the streaming run loop (trajectories pushed pair by pair, rigidity in windows of ``run.chunk`` groups, every
  frame painted from the per-trajectory means), as the CLI runs it (its threads; start-up not counted). The
  stage times are ``run.json``'s ``trajectories`` and ``rigidity`` (the painting is in ``rigidity``).
- ``whole``: the whole-video builder (:meth:`DenseTrajectories.build`) and one ``score`` over all frames, one BLAS
  thread: what :mod:`eponet.geometry`'s functions cost when called on a whole video.

Usage::

    python benchmarks/bench_geometry.py [--frames 25 50 100] [--sizes 854x480 427x240] [--path loop|whole]
        [--variant trifocal]

Runs each measurement in its own subprocess (so that peak RSS is per measurement).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("EPONET_SHARED_DATA") or REPO.parent / "shared" / "data")
DAVIS = DATA / "davis2016-train" / "DAVIS"


def _frames(size: tuple[int, int]) -> tuple[list[np.ndarray], str]:
    """The benchmark's video in colour (BGR uint8) at ``size`` and its name: DAVIS motorbike (480p) or stroller
    (240p) resized to ``size``, or without the shared data a synthetic rendered scene."""
    import cv2

    w, h = size
    if w >= 854 and (DAVIS / "JPEGImages" / "480p" / "motorbike").is_dir():
        files, name = sorted((DAVIS / "JPEGImages" / "480p" / "motorbike").glob("*.jpg")), "DAVIS motorbike 480p"
    elif (DAVIS / "JPEGImages" / "240p" / "stroller").is_dir():
        files, name = sorted((DAVIS / "JPEGImages" / "240p" / "stroller").glob("*.jpg")), "DAVIS stroller 240p"
    else:
        sys.path.insert(0, str(REPO))
        from tests.geometry.scenes import render_scene

        video = render_scene(num_frames=40, size=(h, w), seed=0)
        return [np.ascontiguousarray(f[..., ::-1]) for f in video.frames], "synthetic scene"
    frames = [cv2.imread(str(f), cv2.IMREAD_COLOR) for f in files]
    resized = frames[0].shape[:2] != (h, w)
    frames = [cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA) if resized else f for f in frames]
    return frames, f"{name}, resized to {w}x{h}" if resized else name


def prepare_flow(size: tuple[int, int], frames: int, out: Path, frame_dir: Path | None = None) -> tuple[str, float]:
    """DIS flow of a ``frames``-long ping-pong video at ``size``, saved as ``out`` (.npz); returns the source's
    name and R, the milliseconds per frame of that flow (DIS ``medium`` forward + backward on one thread).
    With ``frame_dir``: the video's frames are also written there as PNG (``00000.png`` ...) and the flow as
    ``.flo`` files in ``frame_dir.parent / "flow"`` (``forward/``, ``backward/``), for the ``flo`` stage."""
    import cv2

    colour, name = _frames(size)
    gray = [cv2.cvtColor(f, cv2.COLOR_BGR2GRAY) for f in colour]
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    n = len(gray)
    previous = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        dis.calc(gray[0], gray[1], None)  # warm-up
        start = time.perf_counter()
        fw = [dis.calc(gray[t], gray[t + 1], None) for t in range(n - 1)]
        bw = [dis.calc(gray[t + 1], gray[t], None) for t in range(n - 1)]
        reference = (time.perf_counter() - start) * 1000 / (n - 1)
    finally:
        cv2.setNumThreads(previous)
    forward, backward, order = [], [], [0]
    t, step = 0, 1
    while len(forward) < frames - 1:  # ping-pong through the pairs
        if step > 0:
            forward.append(fw[t]), backward.append(bw[t])
            order.append(t + 1)
        else:
            forward.append(bw[t]), backward.append(fw[t])
            order.append(t)
        if not 0 <= t + step < n - 1:
            step = -step
        else:
            t += step
    np.savez(out, forward=np.stack(forward).astype(np.float32), backward=np.stack(backward).astype(np.float32))
    if frame_dir is not None:
        from eponet.core.io import write_flo

        flow_dir = frame_dir.parent / "flow"
        for sub in (frame_dir, flow_dir / "forward", flow_dir / "backward"):
            sub.mkdir(parents=True, exist_ok=True)
        for k, index in enumerate(order):
            cv2.imwrite(str(frame_dir / f"{k:05d}.png"), colour[index])
        for k, (f, b) in enumerate(zip(forward, backward)):
            write_flo(flow_dir / "forward" / f"{k:05d}.flo", f)
            write_flo(flow_dir / "backward" / f"{k:05d}.flo", b)
    return name, reference


def _peak_rss_mb() -> float:
    """Peak resident memory of this process (VmHWM; unlike ru_maxrss it restarts at exec, so the parent's
    memory at fork time does not count)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def measure(path: str, variant: str) -> dict:
    """Runs in the child process: load flow, build trajectories, score; report timings and memory."""
    from eponet.core.types import FlowPair
    from eponet.plugins.rigidity.fundamental import FundamentalRigidity
    from eponet.plugins.rigidity.homography import HomographyRigidity
    from eponet.plugins.rigidity.trifocal import TrifocalRigidity
    from eponet.plugins.trajectories.dense import DenseTrajectories

    data = np.load(path)
    flow = FlowPair(data["forward"], data["backward"])
    after_load = _peak_rss_mb()
    stages = {"trifocal": TrifocalRigidity, "homography": HomographyRigidity, "fundamental": FundamentalRigidity}
    stage = stages[variant]()
    t0 = time.perf_counter()
    traj = DenseTrajectories().build(flow)
    t1 = time.perf_counter()
    result = stage.score(traj, flow, np.random.default_rng(0))
    t2 = time.perf_counter()
    frames = traj.num_frames
    return {
        "frames": frames,
        "trajectories": traj.count,
        "points": int(traj.positions.shape[0]),
        "traj_s_per_frame": (t1 - t0) / frames,
        "rigidity_s_per_frame": (t2 - t1) / frames,
        "total_s_per_frame": (t2 - t0) / frames,
        "rss_after_flow_mb": after_load,
        "peak_rss_mb": _peak_rss_mb(),
        "ed_mb": result.ed.nbytes / 2**20,
    }


def measure_loop(frame_dir: Path, variant: str) -> dict:
    """``python -m eponet.run`` on the frames of ``frame_dir`` with the ``geometry`` preset, the flow read from
    ``frame_dir.parent / "flow"`` and the rigidity stage ``variant``; the stage times of its ``run.json``."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench_run import run_cli

    work = frame_dir.parent
    spec = {"preset": "geometry", "seed": 0, "input": {"path": str(frame_dir), "scale": 1.0},
            "stages": {"flow": {"plugin": "flo", "path": str(work / "flow")}, "rigidity": {"plugin": variant}},
            "output": {"dir": str(work / "out"), "save": ["ed"]}}
    result = run_cli(spec, work)
    frames, stages = result["frames"], result["stages_s"]
    return {
        "frames": frames,
        "traj_s_per_frame": stages.get("trajectories", 0.0) / frames,
        "rigidity_s_per_frame": stages.get("rigidity", 0.0) / frames,
        "total_s_per_frame": (stages.get("trajectories", 0.0) + stages.get("rigidity", 0.0)) / frames,
        "peak_rss_mb": result["peak_rss_mb"],
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, nargs="+", default=[25, 50, 100])
    parser.add_argument("--sizes", nargs="+", default=["854x480", "427x240"])
    parser.add_argument("--path", default="loop", choices=["loop", "whole"],
                        help="loop: the CLI's streaming run loop (default); whole: the whole-video functions")
    parser.add_argument("--variant", default="trifocal", choices=["trifocal", "homography", "fundamental"])
    parser.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    parser.add_argument("--child-loop", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(measure(*args.child)))
        return 0
    if args.child_loop:  # (a process of its own, so that the peak RSS of its children is this run's)
        print(json.dumps(measure_loop(Path(args.child_loop[0]), args.child_loop[1])))
        return 0
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    how = ("python -m eponet.run, streaming run loop, its own threads" if args.path == "loop"
           else "whole-video builder, one BLAS thread")
    print(f"geometry benchmark: dense trajectories + rigidity '{args.variant}' (defaults) + painting ({how}); "
          f"flow (DIS medium) precomputed; {os.cpu_count()} CPU cores")
    print("R: DIS medium forward + backward per frame on the same frames at that size, one thread, measured in "
          "the same run")
    print(f"{'size':>8} {'frames':>6} {'traj':>9} {'rigidity':>9} {'total':>9} {'R':>7} {'total':>7} {'T':>9} "
          f"{'RSS flow':>9} {'peak RSS':>9}")
    print(f"{'':>8} {'':>6} {'s/frame':>9} {'s/frame':>9} {'s/frame':>9} {'ms':>7} {'in R':>7} {'':>9} {'MB':>9} "
          f"{'MB':>9}")
    with tempfile.TemporaryDirectory() as tmp:
        for size_text in args.sizes:
            w, h = (int(v) for v in size_text.split("x"))
            for frames in args.frames:
                work = Path(tmp) / f"{w}x{h}_{frames}"
                path = work / "flow.npz"
                work.mkdir()
                if args.path == "loop":
                    source, reference = prepare_flow((w, h), frames, path, frame_dir=work / "frames")
                    command = [sys.executable, __file__, "--child-loop", str(work / "frames"), args.variant]
                else:
                    source, reference = prepare_flow((w, h), frames, path)
                    command = [sys.executable, __file__, "--child", str(path), args.variant]
                out = subprocess.run(command, env=None if args.path == "loop" else env, capture_output=True,
                                     text=True, check=False)
                if out.returncode != 0:
                    print(out.stderr.strip().splitlines()[-1] if out.stderr.strip() else "child failed")
                    return 1
                r = json.loads(out.stdout.strip().splitlines()[-1])
                print(f"{size_text:>8} {r['frames']:>6} {r['traj_s_per_frame']:>9.3f} "
                      f"{r['rigidity_s_per_frame']:>9.3f} {r['total_s_per_frame']:>9.3f} {reference:>7.1f} "
                      f"{r['total_s_per_frame'] * 1000 / reference:>7.2f} {r.get('trajectories', '-'):>9} "
                      f"{format(r['rss_after_flow_mb'], '.0f') if 'rss_after_flow_mb' in r else '-':>9} "
                      f"{r['peak_rss_mb']:>9.0f}   ({source})", flush=True)
                shutil.rmtree(work)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
