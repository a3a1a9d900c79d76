"""Benchmark the evaluation: J and F on a DAVIS-2016-val-sized job (1376 frames at 854x480), then T separately.

The job is built from the real DAVIS-2016 train annotations (``shared/data/davis2016-train``), reused in order
(cyclically if more frames are asked for than exist) and cut into sequences of DAVIS-val-like lengths; the
"results" are the ground truth shifted by 3 px and eroded by 2 px, so that every frame costs a real J and F.

    python benchmarks/bench_evaluate.py                 # J+F, then T on every pair
    python benchmarks/bench_evaluate.py --t-pairs 200   # T on the first 200 pairs only (extrapolated)
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _shared_data() -> Path:
    base = os.environ.get("EPONET_SHARED_DATA")
    return Path(base) if base else Path(__file__).resolve().parents[1].parent / "shared" / "data"


def build_job(source: Path, out: Path, n_frames: int, seq_len: int = 69) -> tuple[Path, Path, int]:
    """A DAVIS-2016 tree of ``n_frames`` ground-truth frames (symlinks) and shifted/eroded results."""
    import scipy.ndimage as ndi
    import yaml

    from eponet.core.io import read_mask, write_mask_png

    files = sorted(p for p in (source / "Annotations" / "480p").glob("*/*.png"))
    if not files:
        raise SystemExit(f"no annotations under {source}/Annotations/480p")
    root, results = out / "DAVIS", out / "results"
    lengths = [seq_len] * (n_frames // seq_len)
    rest = n_frames - sum(lengths)
    if rest >= 3 or not lengths:
        lengths.append(rest)
    else:  # DAVIS-2016 needs 3 frames a sequence: give a short remainder to the previous one
        lengths[-1] += rest
    seqs, k = [], 0
    for s_idx, length in enumerate(lengths):
        name = f"seq{s_idx:02d}"
        for t in range(length):
            src = files[(k + t) % len(files)]
            dst = root / "Annotations" / "480p" / name / f"{t:05d}.png"
            dst.parent.mkdir(parents=True, exist_ok=True)
            os.symlink(src, dst)
            gt = read_mask(src).astype(bool)
            res = ndi.binary_erosion(np.roll(gt, 3, axis=1), iterations=2)
            write_mask_png(results / name / "masks" / dst.name, res.astype(np.uint8))
        seqs.append((name, length))
        k += length
    info = {"attributes": [], "sequences": [{"name": n, "attributes": [], "eval_t": True, "set": "val"}
                                            for n, _ in seqs]}
    (root / "db_info.yml").write_text(yaml.safe_dump(info), encoding="utf-8")
    return root, results, len(seqs)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=1376, help="frames in the job (DAVIS-2016 val: 1376)")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default min(2, CPUs))")
    parser.add_argument("--t-pairs", type=int, default=None, help="time T on only this many frame pairs")
    parser.add_argument("--no-t", action="store_true", help="skip the T benchmark")
    parser.add_argument("--data", type=Path, default=_shared_data() / "davis2016-train" / "DAVIS")
    args = parser.parse_args(argv)

    from eponet.evaluation import evaluate
    from eponet.evaluation.evaluator import _job_t, _Runner, default_workers
    from eponet.evaluation.datasets import load_dataset, locate_results

    workers = default_workers() if args.workers is None else args.workers
    with tempfile.TemporaryDirectory(prefix="eponet-bench-eval-") as tmp:
        t0 = time.perf_counter()
        root, results, n_seq = build_job(args.data, Path(tmp), args.frames)
        print(f"built a job of {args.frames} frames at 854x480 in {n_seq} sequences "
              f"({time.perf_counter() - t0:.1f} s, not timed)")
        print(f"CPUs: {os.cpu_count()}, workers: {workers}, load average: {os.getloadavg()[0]:.2f}")

        t0 = time.perf_counter()
        out = evaluate("davis2016", root, results, compute_t=False, workers=workers)
        wall = time.perf_counter() - t0
        n = out["overall"]["n_frames"]
        print(f"J and F: {wall:.1f} s wall for {n} scored frames ({1000 * wall / n:.1f} ms/frame; all "
              f"{args.frames} frames: {wall * args.frames / n:.1f} s), including reading both PNGs; "
              f"J mean {out['overall']['J']['mean']:.3f}, F mean {out['overall']['F']['mean']:.3f}")
        target = "PASS" if wall * args.frames / n <= 60 else "FAIL"
        print(f"target <= 60 s for {args.frames} frames: {target}")

        if not args.no_t:
            ds = load_dataset("davis2016", root)
            found = locate_results(ds, results)
            jobs = []
            for seq in ds.sequences:
                files = found[seq.name].files
                jobs += [(files[a], files[b]) for a, b in zip(seq.scored[:-1], seq.scored[1:])]
            total_pairs = len(jobs)
            if args.t_pairs is not None:
                jobs = jobs[: args.t_pairs]
            runner = _Runner(workers)
            t0 = time.perf_counter()
            values = runner.map(_job_t, jobs, chunksize=4)
            runner.close()
            wall_t = time.perf_counter() - t0
            per_pair = wall_t / max(1, len(jobs))
            print(f"T: {wall_t:.1f} s wall for {len(jobs)} pairs ({1000 * per_pair:.0f} ms/pair wall); "
                  f"all {total_pairs} pairs of the job: {per_pair * total_pairs:.0f} s"
                  f"{' (extrapolated)' if len(jobs) < total_pairs else ''}; T mean {np.nanmean(values):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
