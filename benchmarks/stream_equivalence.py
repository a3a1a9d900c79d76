"""Streaming against the whole video on real data: how much the ED changes when a video is processed in chunks.

The `geometry` preset (the rigidity stage's defaults, DIS flow at the frame size, dense trajectories) runs on each
DAVIS-2016 train sequence at 240p (scale 1) twice through the run loop: in chunks (``run.chunk`` / ``run.lag``,
the defaults or ``--chunk`` and each of ``--lags``) and in one window (chunk and lag past the video's length, which is the
whole-video computation: ``tests/core/test_stream.py::test_one_window_equals_the_whole_video``). For each it
reports the mean per-frame ROC AUC of the ED against the ground-truth masks (reduced to 240p by area, as
``geometry_davis_auc.py`` does) and the largest per-frame ED difference, per sequence and on average. Usage::

    python benchmarks/stream_equivalence.py [--sequences bear boat ...] [--chunk 16] [--lags 30 10] [--frames N]

The cache is off, so each figure is computed afresh; flow is the same in both runs (the same frames and
settings), so the difference is the chunking's alone: trajectories still alive ``lag`` frames after a frame are
painted there with their mean so far.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from geometry_davis_auc import DAVIS, load_sequence, roc_auc  # noqa: E402

WHOLE = 1_000_000  # chunk and lag past any video's length: one window


def ed_of(name: str, chunk: int, lag: int, frames: int | None) -> np.ndarray:
    """ED maps float32 ``(F, 240, 427)`` of the ``geometry`` preset on a 240p DAVIS sequence, streamed in
    ``chunk`` frames with ``lag``."""
    from eponet.core.inputs import discover_sequences, load_video
    from eponet.core.pipeline import Pipeline, _Timer
    from eponet.core.progress import set_quiet
    from eponet.core.spec import parse_spec

    set_quiet(True)
    path = DAVIS / "JPEGImages" / "240p" / name
    spec = parse_spec({"preset": "geometry", "input": {"path": str(path), "scale": 1.0, "max_frames": frames},
                       "output": {"dir": str(ROOT / "runs" / "stream-equivalence"), "save": []},
                       "run": {"chunk": chunk, "lag": lag, "workers": 1}, "cache": {"enabled": False}, "seed": 0})
    clip = load_video(discover_sequences(path, max_frames=frames)[0], scale=1.0, max_frames=frames)
    return np.stack(Pipeline(spec).process(clip, _Timer()).ed)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences", nargs="*", help="default: the 30 DAVIS-2016 train sequences")
    parser.add_argument("--chunk", type=int, default=None, help="default: run.chunk's default")
    parser.add_argument("--lags", type=int, nargs="+", default=None, help="default: run.lag's default")
    parser.add_argument("--frames", type=int, default=None, help="only the first N frames of each sequence")
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "stream-equivalence.json")
    args = parser.parse_args(argv)
    if not (DAVIS / "ImageSets" / "train.txt").exists():
        print(f"DAVIS-2016 train data not found under {DAVIS} (set EPONET_SHARED_DATA)")
        return 1
    from eponet.core.spec import RunConfig

    chunk = args.chunk or RunConfig().chunk
    lags = args.lags or [RunConfig().lag]
    names = args.sequences or (DAVIS / "ImageSets" / "train.txt").read_text().split()
    print(f"geometry preset, 240p, chunk {chunk}, lag {' / '.join(map(str, lags))} against one window; mean "
          f"per-frame ED ROC AUC")
    rows = {}
    for name in names:
        _, masks = load_sequence(name, args.frames)
        whole = ed_of(name, WHOLE, WHOLE, args.frames)
        auc = lambda ed: float(np.nanmean([roc_auc(ed[t], masks[t]) for t in range(len(masks))]))  # noqa: E731
        rows[name] = {"whole": auc(whole)}
        for lag in lags:
            streamed = ed_of(name, chunk, lag, args.frames)
            changed = float(np.mean(~np.isclose(streamed, whole, rtol=1e-4, atol=1e-4)))
            rows[name][f"lag {lag}"] = {"auc": auc(streamed), "difference": auc(streamed) - rows[name]["whole"],
                                        "pixels_changed": changed, "max_abs_px": float(np.max(np.abs(streamed - whole)))}
        print(f"  {name:<18} whole {rows[name]['whole']:.4f}; " + "; ".join(
            f"lag {lag}: {r['auc']:.4f} ({r['difference']:+.4f}, {100 * r['pixels_changed']:.1f}% of pixels differ, "
            f"at most {r['max_abs_px']:.2f} px)" for lag in lags for r in [rows[name][f"lag {lag}"]]), flush=True)
    mean = {"whole": float(np.mean([r["whole"] for r in rows.values()]))}
    print(f"  mean ({len(rows)}): whole {mean['whole']:.4f}")
    for lag in lags:
        key = f"lag {lag}"
        mean[key] = float(np.mean([r[key]["auc"] for r in rows.values()]))
        worst = min(rows, key=lambda n: rows[n][key]["difference"])
        print(f"  mean ({len(rows)}): lag {lag} {mean[key]:.4f} ({mean[key] - mean['whole']:+.4f}); largest loss "
              f"{worst} {rows[worst][key]['difference']:+.4f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"chunk": chunk, "lags": lags, "mean": mean, "sequences": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
