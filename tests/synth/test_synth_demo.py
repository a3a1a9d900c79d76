"""The embedded demo clip ``examples/demo/`` is what ``examples/make_demo.py`` generates."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from eponet.core.io import read_image, read_mask

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _make_demo_module():
    spec = importlib.util.spec_from_file_location("make_demo", EXAMPLES / "make_demo.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.skipif(not (EXAMPLES / "demo" / "db_info.yml").is_file(), reason="examples/demo/ is not in this checkout")
def test_committed_demo_matches_its_generator():
    demo = _make_demo_module()
    clip = demo.generate_clip(demo.DEMO_SEED, demo.DEMO_FRAMES, demo.DEMO_SIZE, demo.DEMO_CONFIG)
    demo.check_demo(clip)  # one object, 20-35% of the frame, parallax, off the epipolar lines
    root = EXAMPLES / "demo"
    frames = sorted((root / "JPEGImages" / "240p" / "demo").glob("*.jpg"))
    masks = sorted((root / "Annotations" / "240p" / "demo").glob("*.png"))
    assert len(frames) == len(masks) == demo.DEMO_FRAMES
    for t, (frame_path, mask_path) in enumerate(zip(frames, masks)):
        assert np.array_equal(read_mask(mask_path), clip.masks[t])
        mse = np.mean((read_image(frame_path).astype(float) - clip.frames[t]) ** 2)
        assert 10 * np.log10(255**2 / mse) > 30  # JPEG quality 90 (exact bytes depend on the JPEG library)
    cameras = np.load(root / "Cameras" / "240p" / "demo.npz")
    # the last bits of the rotations depend on the numpy / scipy build, the geometry does not
    np.testing.assert_allclose(cameras["R"], clip.R, rtol=0, atol=1e-12)
    total = sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
    assert total < 1.5e6
