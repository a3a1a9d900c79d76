"""Regenerate the embedded demo clip ``examples/demo/`` (exactly: the generator is deterministic).

The clip is one sequence, ``demo``: 30 frames at 427x240 in the DAVIS layout (JPEG quality 90 frames, palette
PNG masks, cameras), made by eponet's RBSF-style generator. The camera translates sideways while turning to
keep looking at a point about as far away as the object (a tracking shot), so the room's floor, walls and
boxes show real parallax; one textured object covering about a quarter of the frame moves on its own by a
few pixels per frame, off the background's epipolar lines. No flow files are stored (the repository stays
small); ``generate_clip(DEMO_SEED, DEMO_FRAMES, DEMO_SIZE, DEMO_CONFIG)`` gives the full ground truth.

    python examples/make_demo.py            # rewrite examples/demo/
    python examples/make_demo.py --check    # regenerate elsewhere and compare byte for byte
"""

from __future__ import annotations

import argparse
import filecmp
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from eponet.synth import SceneConfig, generate_clip, write_clip, write_index

HERE = Path(__file__).resolve().parent
DEMO_DIR = HERE / "demo"
DEMO_NAME = "demo"
DEMO_FRAMES = 30
DEMO_SIZE = (427, 240)
DEMO_CONFIG = SceneConfig(
    num_objects=(1, 1),
    fg_fraction=(0.25, 0.28),
    object_speed=(0.009, 0.013),
    object_rotation=0.5,
    pause_probability=0.0,
    static_camera_probability=0.0,
    camera_speed=(0.01, 0.014),
    camera_rotation=0.2,
    look_at_probability=1.0,
    num_boxes=(2, 4),
    dynamic_texture_probability=0.0,
)
DEMO_SEED = 100  # chosen among seeds 0-260 for the properties that check_demo() asserts


def _epipolar_medians(clip) -> np.ndarray:
    """Per frame pair, the median distance (px) of the object's flow targets to the background's epipolar lines."""
    H, W = clip.masks.shape[1:]
    ys, xs = np.mgrid[0:H, 0:W].astype(np.float64)
    p = np.stack([xs, ys, np.ones_like(xs)], axis=-1)
    K_inv = np.linalg.inv(clip.K)
    out = []
    for t in range(clip.num_frames - 1):
        R = clip.R[t + 1] @ clip.R[t].T
        tr = clip.t[t + 1] - R @ clip.t[t]
        tx = np.array([[0, -tr[2], tr[1]], [tr[2], 0, -tr[0]], [-tr[1], tr[0], 0]])
        F = K_inv.T @ tx @ R @ K_inv
        q = p.copy()
        q[..., :2] += clip.forward[t]
        lines = p @ F.T
        d = np.abs(np.sum(q * lines, axis=-1)) / np.hypot(lines[..., 0], lines[..., 1])
        out.append(np.median(d[clip.masks[t] > 0]))
    return np.array(out)


def check_demo(clip) -> dict:
    """The properties the demo is chosen for; raises AssertionError if the generator no longer gives them."""
    fraction = clip.masks.reshape(clip.num_frames, -1).mean(axis=1)
    fg = clip.masks[:-1] > 0
    object_motion = float(np.median(np.linalg.norm(clip.forward[fg], axis=-1)))
    background_motion = np.linalg.norm(clip.forward[~fg], axis=-1)
    epipolar = _epipolar_medians(clip)
    summary = {
        "object fraction": (round(float(fraction.min()), 3), round(float(fraction.max()), 3)),
        "object motion px/frame (median)": round(object_motion, 2),
        "background motion px/frame (10th, 50th, 90th percentile)": tuple(
            round(float(v), 2) for v in np.percentile(background_motion, [10, 50, 90])
        ),
        "object distance to epipolar lines px (min, median over frames)": (round(float(epipolar.min()), 2), round(float(np.median(epipolar)), 2)),
    }
    assert clip.num_objects == 1 and not clip.static_camera, summary
    assert 0.20 <= fraction.min() and fraction.max() <= 0.35, summary
    assert 2.0 <= object_motion <= 8.0, summary
    # real parallax: near and far background move differently
    assert np.percentile(background_motion, 90) > 2.0 * np.percentile(background_motion, 10), summary
    assert epipolar.min() > 1.0, summary
    return summary


def make_demo(out: Path) -> dict:
    clip = generate_clip(DEMO_SEED, DEMO_FRAMES, DEMO_SIZE, DEMO_CONFIG)
    summary = check_demo(clip)
    entry = write_clip(out, DEMO_NAME, clip, flow=False, depth=False, objects=False, jpeg_quality=90)
    write_index(out, [entry], extra={"name": "examples/make_demo.py", "seed": DEMO_SEED, "frames": DEMO_FRAMES, "size": list(DEMO_SIZE)})
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Regenerate the embedded demo clip examples/demo/.")
    parser.add_argument("--out", type=Path, default=DEMO_DIR, help=f"output folder (default {DEMO_DIR})")
    parser.add_argument("--check", action="store_true", help="regenerate into a temporary folder and compare with --out")
    args = parser.parse_args(argv)

    with tempfile.TemporaryDirectory(prefix="eponet-demo-") as tmp:
        fresh = Path(tmp) / "demo"
        summary = make_demo(fresh)
        for key, value in summary.items():
            print(f"{key}: {value}")
        files = sorted(p.relative_to(fresh) for p in fresh.rglob("*") if p.is_file())
        if args.check:
            old = sorted(p.relative_to(args.out) for p in args.out.rglob("*") if p.is_file()) if args.out.is_dir() else []
            same = files == old and all(filecmp.cmp(fresh / f, args.out / f, shallow=False) for f in files)
            print(f"{args.out}: {'identical to' if same else 'DIFFERS from'} a fresh regeneration")
            return 0 if same else 1
        if args.out.exists():
            if not (args.out / "db_info.yml").is_file():
                print(f"{args.out}: exists and is not a demo folder (no db_info.yml); not replacing it", file=sys.stderr)
                return 2
            shutil.rmtree(args.out)
        shutil.copytree(fresh, args.out)
    size = sum((args.out / f).stat().st_size for f in files)
    print(f"wrote {len(files)} files, {size / 1e6:.2f} MB, to {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
