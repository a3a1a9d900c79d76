"""Per-stage micro-benchmarks of the throughput issue's targets, in milliseconds and in reference units.

    python benchmarks/bench_stages.py [--stages motion_net,refiner] [--frames 16] [--threads 1]

R is measured in the same invocation, before and after the stages (both printed: a drift between them means the
machine was not quiet): OpenCV DIS ``medium`` forward + backward per frame on the same DAVIS 480p frames at the
processing size (427x240). Every figure is per frame, at one worker's settings (``--threads`` torch/OpenCV threads,
default 1), after a warm-up batch:

- ``motion_net``: the ``epo`` preset's one U-Net (``epo-davis-v5``), then two (the ``epo+`` preset's pair) on
  427x240 motion images, batches of 8, the pair also as the stage ran it before (each :class:`~eponet.nets.EpoUNet` in eval mode, channels-last) and as it runs them now (each as its
  :class:`~eponet.nets.InferenceUNet`), in float32 and under ``precision: bfloat16``. The motion images are
  random: a convolution's cost does not depend on the values. Also the compute floor: both networks'
  multiply-adds per frame at the rate this CPU multiplies large float32 matrices on the same threads.
- ``flow``: the presets' flow (``dis``, ``medium`` with ``finest_scale: 0``) forward + backward per frame, the
  same with sparser patches (``patch_stride`` 5 and 6 instead of 3) and fewer variational refinements, and
  OpenCV's own ``medium`` (``finest_scale: null``, which is R's computation) through the same stage.
- ``rigidity``: the presets' trifocal stage on the dense trajectories of the frames (DIS flow, not timed), with
  numpy's BLAS on one thread, as runs hold it, and on every core; and on one thread with the robust settings of
  2026-12-04 (``RobustSettings``: trial counts without the noise floor, an LMedS-scored trifocal search, refits
  on 3000 inliers) (``--stages rigidity``, not in the default set).
- ``refiner``: the ``epo`` preset's dense CRF (854x480 frames and probabilities, run at 427 px wide) on real
  frames, split into its parts (resizing and unary, the Gaussian and bilateral kernels' set-up, the five
  mean-field iterations: pydensecrf's), and ``densecrf_mask`` as the stage calls it, with the preset's backend
  (``grid``) and with the other; and the presets' temporal averaging before it (``refiner: {temporal: 1}``, on
  random probabilities warped along the presets' DIS flow at 427x240).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_run import DAVIS, reference_ms  # noqa: E402

SIZE = (427, 240)  # processing size (w, h) of 854x480 input at scale 0.5


def _frames(count: int) -> tuple[list[Path], list[np.ndarray]]:
    files = sorted((DAVIS / "JPEGImages" / "480p").glob("*/*.jpg"))[:count]
    if len(files) < 2:
        raise SystemExit(f"no DAVIS 480p frames under {DAVIS} (set EPONET_SHARED_DATA)")
    frames = [cv2.resize(cv2.imread(str(f))[..., ::-1], (854, 480), interpolation=cv2.INTER_AREA) for f in files]
    return files, frames


def _timed(function, frames: int, repeats: int = 3) -> float:
    """Best of ``repeats`` calls of ``function()`` (after a warm-up call), in ms per frame."""
    function()
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, (time.perf_counter() - start) * 1000 / frames)
    return best


def bench_motion_net(frames: int) -> dict[str, float]:
    import torch

    from eponet.plugins.motion_net.epo_unet import EpoUNetStage, load_unet

    weights = ["epo-davis", "epo-davis-seed1"]
    motion = np.random.default_rng(0).standard_normal((frames, 3, SIZE[1], SIZE[0])).astype(np.float32)
    before = [load_unet(w)[0].to(memory_format=torch.channels_last) for w in weights]

    def old():
        with torch.inference_mode():
            for start in range(0, frames, 8):
                batch = torch.from_numpy(motion[start : start + 8])
                for model in before:
                    torch.sigmoid(model(model.select_inputs(batch).contiguous(memory_format=torch.channels_last)))

    figures = {"before (EpoUNet, eval)": _timed(old, frames)}
    for precision in ("float32", "bfloat16"):
        single = EpoUNetStage(weights="epo-davis-v5", device="cpu", precision=precision)
        figures[f"one network, the epo preset's ({precision})"] = _timed(lambda: single.predict(motion), frames)
        stage = EpoUNetStage(weights=weights, device="cpu", precision=precision)
        figures[f"now ({precision})"] = _timed(lambda: stage.predict(motion), frames)
    # the compute floor: the networks' multiply-adds at the rate of a large float32 matrix product on the same
    # threads (close to what this CPU can do at all)
    flops = 2 * sum(multiply_adds(model, (SIZE[1], SIZE[0])) for model in stage.models)
    rate = sgemm_flops()
    figures[f"floor: {flops / 1e9:.2f} GFLOP per frame at the sgemm rate ({rate / 1e9:.0f} GFLOP/s)"] = flops / rate * 1000
    return figures


def multiply_adds(model, shape: tuple[int, int]) -> int:
    """Multiply-adds of one forward pass of ``model`` (its convolutions and linear layers) on one frame of ``shape``
    ``(h, w)``, counted from the shapes the calls see."""
    import torch
    import torch.nn.functional as F

    count = 0
    conv, linear = F.conv2d, F.linear

    def counted_conv(x, weight, *args, **kwargs):
        nonlocal count
        y = conv(x, weight, *args, **kwargs)
        count += y.numel() * weight[0].numel()
        return y

    def counted_linear(x, weight, *args, **kwargs):
        nonlocal count
        y = linear(x, weight, *args, **kwargs)
        count += y.numel() * weight.shape[1]
        return y

    F.conv2d, F.linear = counted_conv, counted_linear
    try:
        with torch.inference_mode():
            model(torch.zeros(1, model.input_channels, *shape))
    finally:
        F.conv2d, F.linear = conv, linear
    return count


def sgemm_flops(n: int = 1536) -> float:
    """Float32 FLOP/s of an ``n`` x ``n`` matrix product (best of 5) on torch's current threads."""
    import torch

    a, b = torch.randn(n, n), torch.randn(n, n)
    torch.mm(a, b)
    best = float("inf")
    for _ in range(5):
        start = time.perf_counter()
        torch.mm(a, b)
        best = min(best, time.perf_counter() - start)
    return 2 * n**3 / best


#: The ``dis`` flow settings ``--stages flow`` times (on top of ``preset: medium``).
FLOW_VARIANTS = {
    "dis medium, finest_scale 0 (presets)": {"finest_scale": 0},
    "dis medium, finest_scale 0, patch_stride 5": {"finest_scale": 0, "patch_stride": 5},
    "dis medium, finest_scale 0, patch_stride 6": {"finest_scale": 0, "patch_stride": 6},
    "dis medium, finest_scale 0, stride 5, 3 refinements": {"finest_scale": 0, "patch_stride": 5,
                                                             "refinement_iterations": 3},
    "dis medium, finest_scale null": {"finest_scale": None},
}


def _video(frames: list[np.ndarray]):
    """``frames`` resized to the processing size, as a :class:`~eponet.core.types.Video`."""
    from eponet.core.types import Video

    small = np.stack([cv2.resize(f, SIZE, interpolation=cv2.INTER_AREA) for f in frames])
    return Video("bench", small, [f"{t:05d}" for t in range(len(small))], small.shape[1:3])


def bench_flow(frames: list[np.ndarray]) -> dict[str, float]:
    from eponet.plugins.flow.dis import DisFlow

    video = _video(frames)
    figures = {}
    for label, settings in FLOW_VARIANTS.items():
        stage = DisFlow(preset="medium", **settings)
        figures[label] = _timed(lambda: stage.estimate(video), len(frames) - 1)
    return figures


def _preset_flow(frames: list[np.ndarray]):
    """The presets' flow (DIS ``medium``, finest level 0) between consecutive ``frames`` at 427x240: a
    :class:`~eponet.core.types.FlowPair` (not timed: the input of the stages timed after it)."""
    from eponet.plugins.flow.dis import DisFlow

    return DisFlow(preset="medium", finest_scale=0).estimate(_video(frames))


def bench_rigidity(frames: list[np.ndarray]) -> dict[str, float]:
    """The presets' trifocal rigidity on the dense trajectories of ``frames`` at 427x240, with numpy's BLAS on
    one thread (as runs hold it, :data:`eponet.core.workers.BLAS_THREADS`) and on every core (its default)."""
    from threadpoolctl import threadpool_limits

    from eponet.plugins.rigidity.trifocal import TrifocalRigidity
    from eponet.plugins.trajectories.dense import DenseTrajectories

    flow = _preset_flow(frames)
    tracks = DenseTrajectories().build(flow)
    stage = TrifocalRigidity()
    # the robust settings of 2026-12-04: LMedS-scored six-point search with trial counts from its noise estimate
    # alone, refits on about 3000 inliers (the code's own speed-ups of 2026-12-05 cannot be switched off)
    before = TrifocalRigidity()
    before.settings = dataclasses.replace(before.settings, trial_floor=False, epipolar_msac=False, refit_points=3000)
    runs = [(f"trifocal, BLAS on {threads} thread(s)", stage, threads) for threads in (1, os.cpu_count() or 1)]
    runs.append(("trifocal, BLAS on 1 thread, the robust settings of 2026-12-04", before, 1))
    figures = {}
    for label, timed_stage, threads in runs:
        with threadpool_limits(limits=threads, user_api="blas"):
            figures[label] = _timed(lambda: timed_stage.score(tracks, flow, np.random.default_rng(0)), len(frames),
                                    repeats=2)
    return figures


def bench_refiner(frames: list[np.ndarray]) -> dict[str, float]:
    import pydensecrf.densecrf as dcrf
    from pydensecrf.utils import unary_from_softmax

    from crf_speed_sweep import preset_crf
    from eponet.plugins.refiner.densecrf import densecrf_mask

    params = preset_crf("epo")  # densecrf_mask's arguments: the CRF of one frame, in this process
    yy, xx = np.mgrid[0:480, 0:854]
    probability = np.exp(-(((xx - 500) / 150.0) ** 2 + ((yy - 260) / 110.0) ** 2)).astype(np.float32)
    scale = params["max_size"] / 854
    parts = dict.fromkeys(("resize + unary", "Gaussian kernel set-up", "bilateral kernel set-up",
                           f"{params['iterations']} mean-field iterations", "upsample + argmax"), 0.0)
    for frame in frames:
        tick = time.perf_counter()
        small_frame = cv2.resize(frame, SIZE, interpolation=cv2.INTER_AREA)
        small = cv2.resize(probability, SIZE, interpolation=cv2.INTER_LINEAR)
        crf = dcrf.DenseCRF2D(SIZE[0], SIZE[1], 2)
        crf.setUnaryEnergy(np.ascontiguousarray(unary_from_softmax(np.stack([1.0 - small, small]))))
        marks = [time.perf_counter()]
        crf.addPairwiseGaussian(sxy=params["gaussian_sxy"] * scale, compat=params["gaussian_compat"])  # (densecrf.py)
        marks.append(time.perf_counter())
        crf.addPairwiseBilateral(sxy=params["bilateral_sxy"] * scale, srgb=params["bilateral_srgb"],
                                 rgbim=np.ascontiguousarray(small_frame), compat=params["bilateral_compat"])
        marks.append(time.perf_counter())
        q = np.asarray(crf.inference(params["iterations"])).reshape(2, SIZE[1], SIZE[0])
        marks.append(time.perf_counter())
        cv2.resize(q[1] - q[0], (854, 480), interpolation=cv2.INTER_LINEAR) > 0
        marks.append(time.perf_counter())
        for name, a, b in zip(parts, [tick, *marks[:-1]], marks):
            parts[name] += (b - a) * 1000 / len(frames)
    figures = {f"  {name}": value for name, value in parts.items()}
    figures[f"densecrf_mask (the stage, preset epo: backend {params['backend']})"] = _timed(
        lambda: [densecrf_mask(f, probability, **params) for f in frames], len(frames), repeats=1)
    other = "pydensecrf" if params["backend"] == "grid" else "grid"
    figures[f"densecrf_mask, backend {other}"] = _timed(
        lambda: [densecrf_mask(f, probability, **{**params, "backend": other}) for f in frames], len(frames),
        repeats=1)
    figures["temporal averaging (refiner temporal: 1, 427x240)"] = bench_temporal(frames)
    return figures


def bench_temporal(frames: list[np.ndarray]) -> float:
    """``refiner: {temporal: 1}``: each frame's probability averaged with its two neighbours' warped into it along
    the presets' flow at 427x240 (:func:`_preset_flow`, not timed), in ms per frame."""
    from eponet.core.temporal import temporal_mean

    flow = _preset_flow(frames)
    forward, backward = flow.forward, flow.backward
    p = [np.random.default_rng(t).random(SIZE[::-1], dtype=np.float32) for t in range(len(frames))]
    inner = range(1, len(frames) - 1)
    return _timed(lambda: [temporal_mean(p[t], (p[t - 1], backward[t - 1], forward[t - 1]),
                                         (p[t + 1], forward[t], backward[t])) for t in inner], len(inner))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stages", default="flow,motion_net,refiner")
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--threads", type=int, default=1, help="torch and OpenCV threads (one worker's share)")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    files, frames = _frames(args.frames)
    before = reference_ms(files, 0.5, args.threads)
    results = {}
    for stage in args.stages.split(","):
        if stage == "motion_net":
            results[stage] = bench_motion_net(args.frames)
        elif stage == "flow":
            results[stage] = bench_flow(frames)
        elif stage == "rigidity":
            results[stage] = bench_rigidity(frames)
        elif stage == "refiner":
            results[stage] = bench_refiner(frames[: min(8, len(frames))])
        else:
            raise SystemExit(f"--stages: unknown stage {stage!r}; known: flow, motion_net, rigidity, refiner")
    after = reference_ms(files, 0.5, args.threads)
    reference = 0.5 * (before + after)
    print(f"R = {reference:.1f} ms (DIS medium fwd+bwd per frame at {SIZE[0]}x{SIZE[1]}, {args.threads} thread(s); "
          f"{before:.1f} before the stages, {after:.1f} after)")
    for stage, figures in results.items():
        print(stage)
        for name, ms in figures.items():
            print(f"  {name:<52} {ms:8.1f} ms {ms / reference:6.2f} R")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
