"""The public generator API: shapes and dtypes, determinism, configuration errors, bundled photos."""

from __future__ import annotations

import numpy as np
import pytest
from synth_helpers import SIZE, cached_clip

import eponet.synth as synth
from eponet.core.errors import SpecError
from eponet.synth import Clip, SceneConfig, generate_clip

ARRAYS = ("frames", "masks", "object_ids", "forward", "backward", "occlusion_forward", "occlusion_backward", "K", "R", "t", "depth", "dynamic")


def test_public_names():
    for name in ("Clip", "SceneConfig", "generate_clip", "write_dataset", "write_clip", "sample_scene", "Scene", "TextureBank"):
        assert name in synth.__all__ and hasattr(synth, name), name


def test_clip_layout_follows_the_conventions():
    clip = cached_clip(0, 5)
    W, H = SIZE
    assert isinstance(clip, Clip)
    expected = {
        "frames": ((5, H, W, 3), np.uint8),
        "masks": ((5, H, W), np.uint8),
        "object_ids": ((5, H, W), np.uint8),
        "forward": ((4, H, W, 2), np.float32),
        "backward": ((4, H, W, 2), np.float32),
        "occlusion_forward": ((4, H, W), np.bool_),
        "occlusion_backward": ((4, H, W), np.bool_),
        "K": ((3, 3), np.float64),
        "R": ((5, 3, 3), np.float64),
        "t": ((5, 3), np.float64),
        "depth": ((5, H, W), np.float32),
        "dynamic": ((5, H, W), np.bool_),
    }
    for name, (shape, dtype) in expected.items():
        array = getattr(clip, name)
        assert array.shape == shape and array.dtype == dtype, (name, array.shape, array.dtype)
    assert set(np.unique(clip.masks)) <= {0, 1}
    assert clip.object_ids.max() <= clip.num_objects
    assert np.all(np.isfinite(clip.forward)) and np.all(np.isfinite(clip.depth)) and clip.depth.min() > 0
    # rotations are orthonormal, pixel centres at integers: principal point at the image centre
    np.testing.assert_allclose(clip.R @ np.transpose(clip.R, (0, 2, 1)), np.broadcast_to(np.eye(3), (5, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(clip.K[:2, 2], [(W - 1) / 2, (H - 1) / 2])


def test_default_objects_cover_30_to_50_percent_of_the_first_frame():
    for seed in range(3):
        scene = cached_clip(seed, 5).scene
        assert 0.28 <= scene.info["fg_fraction_frame0"] <= 0.52, scene.info


def test_same_seed_gives_identical_clips_and_another_seed_does_not():
    a = generate_clip(7, 4, SIZE)
    b = generate_clip(7, 4, SIZE)
    for name in ARRAYS:
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert a.attributes == b.attributes and a.static_camera == b.static_camera
    c = generate_clip(8, 4, SIZE)
    assert not np.array_equal(a.frames, c.frames)


def test_bad_arguments_are_reported():
    with pytest.raises(ValueError, match="size"):
        generate_clip(0, 4, (8, 8))
    with pytest.raises(ValueError, match="frames"):
        generate_clip(0, 2, SIZE)
    with pytest.raises(SpecError) as info:
        SceneConfig(fg_fraction=(0.6, 0.3), num_objects=(0, 2))
    assert len(info.value.problems) == 2
    with pytest.raises(SpecError, match="unknown setting"):
        SceneConfig.from_dict({"fg_fractoin": [0.3, 0.5]})


def test_bundled_photos_are_read_from_the_wheel_never_fetched(monkeypatch):
    import skimage.data._fetchers as fetchers

    from eponet.synth import textures

    def no_download(*args, **kwargs):
        raise AssertionError("scikit-image tried to fetch a data file")

    monkeypatch.setattr(fetchers, "_fetch", no_download)
    textures.bundled_photos.cache_clear()
    try:
        photos = textures.bundled_photos()
    finally:
        textures.bundled_photos.cache_clear()
    assert len(photos) >= 8
    assert all(p.rgb.dtype == np.uint8 and p.rgb.ndim == 3 and p.rgb.shape[2] == 3 for p in photos)
