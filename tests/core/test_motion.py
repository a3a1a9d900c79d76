"""The ED scaling and encoding the motion net reads (eponet.core.motion), and the motion images."""

from __future__ import annotations

import doctest

import numpy as np
import pytest
import torch

import eponet.core.motion as motion
from eponet.core.motion import (
    ED_SAMPLE,
    ED_TARGET,
    ED_WINDOW,
    ed_frame_sample,
    ed_scales,
    ed_window_scale,
    encode_ed,
    normalise_ed,
)


def test_whole_video_scale_maps_the_percentile_and_saturates():
    rng = np.random.default_rng(0)
    ed = rng.uniform(0, 10, (4, 30, 40)).astype(np.float32)
    out = normalise_ed(ed, window=None)
    assert out.dtype == np.float32 and out.shape == ed.shape
    assert out.min() >= 0 and out.max() <= 1
    np.testing.assert_allclose(np.percentile(out, 95), ED_TARGET, rtol=1e-4)
    assert (out[ed > 1.03 * np.percentile(ed, 95)] == 1.0).all()
    # the scale is relative: scaling the input leaves the output unchanged
    np.testing.assert_allclose(normalise_ed(ed * 3, window=None), out, atol=1e-6)


def test_unsaturated_scaling_keeps_the_range_above_the_percentile():
    rng = np.random.default_rng(1)
    ed = rng.uniform(0, 10, (4, 30, 40)).astype(np.float32)
    ed[0, :3, :3] = 400.0  # a small, fast object: 40 times the background's largest
    out = normalise_ed(ed, window=None, saturate=False)
    np.testing.assert_allclose(out, ed * ED_TARGET / np.percentile(ed, 95), rtol=1e-5)
    assert out[0, 0, 0] > 35 and out.min() >= 0
    np.testing.assert_array_equal(np.minimum(out, 1.0), normalise_ed(ed, window=None))


def test_floor_and_non_finite_values():
    quiet = np.full((2, 5, 5), 0.2, np.float32)  # a rigid video: ED is flow noise only
    assert ed_scales(quiet).tolist() == [1.0, 1.0]
    np.testing.assert_allclose(normalise_ed(quiet), 0.2 * ED_TARGET, rtol=1e-6)
    bad = quiet.copy()
    bad[0, 0, 0], bad[0, 0, 1] = np.nan, np.inf
    out = normalise_ed(bad)
    assert out[0, 0, 0] == 0 and out[0, 0, 1] == 1 and np.isfinite(out).all()
    assert normalise_ed(np.zeros((3, 4, 4), np.float32)).max() == 0


def test_window_scale_follows_the_scene_and_matches_a_stream():
    """A long video whose ED level changes halfway: each frame is scaled by the frames around it, so both
    halves end at the same range, and a stream holding half a window of look-ahead computes the same scales
    from per-frame samples alone."""
    rng = np.random.default_rng(2)
    levels = np.r_[np.full(100, 2.0), np.full(100, 20.0)]
    ed = (rng.uniform(0, 1, (200, 12, 16)) * levels[:, None, None]).astype(np.float32)
    scales = ed_scales(ed)
    assert scales.shape == (200,)
    np.testing.assert_allclose(scales[:60], np.percentile(ed[:60], 95), rtol=0.02)
    np.testing.assert_allclose(scales[-60:], np.percentile(ed[-60:], 95), rtol=0.02)
    whole = ed_scales(ed, window=None)
    assert np.ptp(whole) == 0 and 2.0 < whole[0] < 20.0
    half = ED_WINDOW // 2
    samples = [ed_frame_sample(f) for f in ed]
    streamed = [ed_window_scale(samples[max(0, t - half): t + half + 1]) for t in range(len(ed))]
    np.testing.assert_array_equal(scales, streamed)


def test_frame_sample_is_bounded_and_deterministic():
    frame = np.arange(100 * 100, dtype=np.float32).reshape(100, 100)
    frame[0, 0] = np.nan
    sample = ed_frame_sample(frame)
    assert sample.size <= ED_SAMPLE and np.isfinite(sample).all()
    np.testing.assert_array_equal(sample, ed_frame_sample(frame.copy()))
    assert ed_frame_sample(np.full((4, 4), np.nan)).size == 0
    with pytest.raises(ValueError, match="window"):
        ed_scales(frame[None], window=0)


def test_encode_ed_numpy_and_torch_agree():
    values = np.array([0.0, 0.5, 1.0, 2.0, 50.0], np.float32)
    np.testing.assert_allclose(encode_ed(values, "clip"), [0, 0.5, 1, 1, 1])
    np.testing.assert_allclose(encode_ed(values, "log"), [0, 0.5, 1, 1 + np.log(2), 1 + np.log(50)], rtol=1e-6)
    np.testing.assert_allclose(encode_ed(torch.from_numpy(values), "log").numpy(), encode_ed(values, "log"))
    with pytest.raises(ValueError, match="ed_encoding"):
        encode_ed(values, "sqrt")


def test_docstring_examples():
    assert doctest.testmod(motion, extraglobs={"np": np}).failed == 0
