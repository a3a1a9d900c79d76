"""Dense trajectories, consistency tests, painting and filling on flow fields with exact answers."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from eponet.geometry import (
    alive_in_frames,
    build_dense_trajectories,
    exact_round_trip,
    fb_consistent_points,
    fill_from_neighbourhood,
    forward_backward_consistency,
    paint_trajectory_values,
    sample_bilinear,
    trajectory_ends,
    trajectory_positions,
)


def _translation(frames, h, w, dx, dy):
    fw = np.zeros((frames - 1, h, w, 2), np.float32)
    fw[..., 0], fw[..., 1] = dx, dy
    return fw, -fw


def _check_invariants(tr, h, w):
    """CSR layout, coverage of every pixel by a trajectory whose rounded position is that pixel."""
    f = tr.num_frames
    assert tr.labels.shape == (f, h, w) and tr.labels.dtype == np.int32
    assert tr.positions.dtype == np.float32 and tr.positions.shape == (int(tr.offsets[-1]), 2)
    np.testing.assert_array_equal(np.diff(tr.offsets), tr.length)
    assert tr.count >= h * w and (tr.length >= 1).all() and (np.diff(tr.start) >= 0).all()
    ys, xs = np.mgrid[0:h, 0:w]
    for t in range(f):
        ids = tr.labels[t].ravel()
        assert (ids >= 0).all()
        assert (tr.start[ids] <= t).all() and (trajectory_ends(tr)[ids] >= t).all()
        p = trajectory_positions(tr, ids, t)
        np.testing.assert_array_equal(np.floor(p[:, 0] + 0.5), xs.ravel())
        np.testing.assert_array_equal(np.floor(p[:, 1] + 0.5), ys.ravel())


def test_sample_bilinear_exact_on_linear_field():
    h, w = 30, 40
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    field = np.stack([2 * xs + 1, -ys], -1)
    rng = np.random.default_rng(0)
    p = rng.uniform([0, 0], [w - 1, h - 1], (1000, 2)).astype(np.float32)
    v = sample_bilinear(field, p)
    # remap's weights are quantised to 1/32 px: a unit-slope field is reproduced within 1/64 px per unit
    np.testing.assert_allclose(v[:, 0], 2 * p[:, 0] + 1, atol=2 / 32)
    np.testing.assert_allclose(v[:, 1], -p[:, 1], atol=1 / 32)
    assert sample_bilinear(field, np.zeros((0, 2), np.float32)).shape == (0, 2)


def test_trajectories_exact_under_translation():
    h, w, f = 24, 32, 6
    fw, bw = _translation(f, h, w, 1.25, -0.5)
    tr = build_dense_trajectories(fw, bw)
    _check_invariants(tr, h, w)
    for j in range(0, tr.count, 37):
        p = tr.positions_of(j)
        steps = np.arange(len(p))[:, None] * np.array([1.25, -0.5], np.float32)
        np.testing.assert_array_equal(p, p[0] + steps)  # exact: constant flow, exact sums in float32
    # trajectories end when they leave the frame: the first column born at x = w-1 ends after its frame
    ids = tr.labels[0, 10]
    assert tr.length[ids[-1]] == 1
    # a pixel of the interior of frame 0 survives until its position leaves the frame
    j = tr.labels[0, 20, 5]
    assert tr.length[j] == f and np.allclose(tr.positions_of(j)[-1], [5 + 1.25 * 5, 20 - 2.5])


def test_trajectories_cover_every_pixel_with_births():
    h, w, f = 20, 26, 5
    rng = np.random.default_rng(1)
    fw = rng.normal(0, 1.5, (f - 1, h, w, 2)).astype(np.float32)  # incoherent flow: many deaths and births
    bw = rng.normal(0, 1.5, (f - 1, h, w, 2)).astype(np.float32)
    tr = build_dense_trajectories(fw, bw)
    _check_invariants(tr, h, w)
    assert tr.count > h * w


def test_trajectories_end_at_occlusion():
    h, w, f = 20, 30, 4
    fw, bw = _translation(f, h, w, 1.0, 0.0)
    # backward flow disagrees on a block of frame 1 (an occluder appears there): points landing on it end
    bw[0, 5:10, 10:15] = (6.0, 0.0)
    tr = build_dense_trajectories(fw, bw)
    _check_invariants(tr, h, w)
    j = tr.labels[0, 7, 11]  # lands on (12, 7) in frame 1: inside the block
    assert tr.length[j] == 1
    j = tr.labels[0, 2, 11]  # outside the block: continues
    assert tr.length[j] == f
    # the occluded pixels of frame 1 are covered by newborn trajectories
    assert (tr.start[tr.labels[1, 5:10, 11:15]] == 1).all()


def test_forward_backward_tests():
    h, w = 10, 12
    fw, bw = _translation(2, h, w, 1.0, 0.0)
    ok = forward_backward_consistency(fw[0], bw[0])
    assert ok[:, :-1].all() and not ok[:, -1].any()  # the last column leaves the frame
    np.testing.assert_array_equal(exact_round_trip(fw[0], bw[0])[:, :-1], True)
    # the tolerance: |f + b|^2 < 0.01 (|f|^2 + |b|^2) + 0.5
    f = np.zeros((h, w, 2), np.float32)
    f[..., 0] = 10.0
    b = -f.copy()
    b[..., 0] += 0.7  # |f+b|^2 = 0.49 < 0.01 (100 + 86.49) + 0.5
    _, good = fb_consistent_points(f, b, np.array([[1.0, 1.0]], np.float32))
    assert good[0]
    b[..., 0] += 0.8  # |f+b|^2 = 2.25 > 0.01 (100 + 72.25) + 0.5 = 2.2225
    _, good = fb_consistent_points(f, b, np.array([[1.0, 1.0]], np.float32))
    assert not good[0]
    with pytest.raises(ValueError):
        forward_backward_consistency(f, b, method="bogus")


def test_exact_mode_matches_translation_and_rejects_half_pixel_drift():
    h, w, f = 16, 20, 4
    fw, bw = _translation(f, h, w, 2.0, 1.0)
    tr = build_dense_trajectories(fw, bw, consistency="exact")
    _check_invariants(tr, h, w)
    assert tr.length[tr.labels[0, 2, 2]] == f
    bw2 = bw.copy()
    bw2[..., 0] += 0.6  # the rounded round trip now misses by one pixel everywhere
    assert not exact_round_trip(fw[0], bw2[0]).any()


def test_cull_collisions_keeps_oldest():
    h, w, f = 12, 16, 3
    fw = np.zeros((f - 1, h, w, 2), np.float32)
    fw[0, :, 5, 0] = 1.0  # column 5 moves onto column 6: two trajectories on each pixel of column 6
    bw = np.zeros_like(fw)
    bw[0, :, 6, 0] = -0.4  # tolerant enough for both (|f+b|^2 <= 0.36 < 0.5 + ...)
    keep = build_dense_trajectories(fw, bw)
    cull = build_dense_trajectories(fw, bw, cull_collisions=True)
    _check_invariants(keep, h, w)
    _check_invariants(cull, h, w)
    older, younger = keep.labels[0, 3, 5], keep.labels[0, 3, 6]
    assert older < younger and keep.labels[1, 3, 6] == older
    assert keep.length[older] == f and keep.length[younger] == f  # without culling both continue
    assert cull.length[cull.labels[0, 3, 5]] == f and cull.length[cull.labels[0, 3, 6]] == 1


def test_max_live_bounds_the_trajectories_that_pile_up_ending_the_youngest_hidden_first():
    """Column 5 moves onto column 6 in every pair: each frame hides 12 more trajectories under older ones, so
    without a bound their number grows with the video; with ``max_live`` it stops at that many times the
    pixels, the youngest hidden ones ending first, and no pixel changes its trajectory."""
    h, w, f = 12, 16, 10
    fw = np.zeros((f - 1, h, w, 2), np.float32)
    fw[:, :, 5, 0] = 1.0
    bw = np.zeros_like(fw)
    bw[:, :, 6, 0] = -0.4
    free = build_dense_trajectories(fw, bw, max_live=None)
    bounded = build_dense_trajectories(fw, bw, max_live=1.25)
    _check_invariants(free, h, w)
    _check_invariants(bounded, h, w)

    def alive(tr, t):
        return set(np.flatnonzero((tr.start <= t) & (trajectory_ends(tr) >= t)).tolist())

    assert [len(alive(free, t)) for t in range(f)] == [h * w + h * t for t in range(f)]
    assert [len(alive(bounded, t)) for t in range(f)] == [192, 204, 216, 228, 240, 240, 240, 240, 240, 240]
    np.testing.assert_array_equal(bounded.labels, free.labels)  # the same trajectory covers every pixel
    last = f - 1
    dropped = alive(free, last) - alive(bounded, last)
    hidden = alive(bounded, last) - set(bounded.labels[last].ravel().tolist())
    assert len(dropped) == 12 * 5 and min(dropped) > max(hidden)
    with pytest.raises(ValueError, match="max_live must be at least 1"):
        build_dense_trajectories(fw, bw, max_live=0.5)


def test_nan_flow_is_treated_as_occlusion(caplog):
    h, w, f = 10, 12, 4
    fw, bw = _translation(f, h, w, 1.0, 0.0)
    fw[1, 4, 4] = np.nan
    with caplog.at_level(logging.WARNING):
        tr = build_dense_trajectories(fw, bw)
    assert "not finite" in caplog.text
    _check_invariants(tr, h, w)
    j = tr.labels[1, 4, 4]
    assert trajectory_ends(tr)[j] == 1


def test_alive_in_frames_and_paint():
    h, w, f = 8, 10, 5
    fw, bw = _translation(f, h, w, 1.0, 0.0)
    tr = build_dense_trajectories(fw, bw)
    ids = alive_in_frames(tr, 1, 3)
    ends = trajectory_ends(tr)
    brute = np.flatnonzero((tr.start <= 1) & (ends >= 3))
    np.testing.assert_array_equal(ids, brute)
    values = np.arange(tr.count, dtype=np.float32)
    painted = paint_trajectory_values(tr.labels, values)
    assert painted.dtype == np.float32 and np.array_equal(painted, tr.labels.astype(np.float32))


def test_positions_of_a_frame_group_are_those_of_each_frame():
    """One gather for a triplet's frames (strided or not) gives each frame's positions exactly."""
    h, w, f = 8, 10, 7
    fw, bw = _translation(f, h, w, 0.7, -0.3)
    tr = build_dense_trajectories(fw, bw)
    for frames in ((1, 2, 3), (0, 2, 4), (3, 5)):
        ids = alive_in_frames(tr, frames[0], frames[-1])
        assert len(ids) > 0
        together = trajectory_positions(tr, ids, frames)
        assert len(together) == len(frames)
        for t, p in zip(frames, together):
            assert p.dtype == np.float32 and p.shape == (len(ids), 2)
            np.testing.assert_array_equal(p, trajectory_positions(tr, ids, t))


def test_stream_frames_assemble_into_the_whole_video_trajectories_and_a_window_reads_them_as_they_are():
    """The run loop's windows: stream frames assembled are the whole-video builder's trajectories (labels as
    window-local ids); a TrackWindow over the same frames gives every frame group's trajectories (the same
    window-local indices) and positions exactly as the assembled trajectories do, for windows that start
    anywhere, with strided groups too."""
    from eponet.core.types import TrackWindow, assemble_trajectories
    from eponet.geometry.scoring import frame_groups
    from eponet.geometry.trajectories import DenseTrajectoryStream

    h, w, f = 8, 10, 9
    rng = np.random.default_rng(3)
    fw = rng.normal(0.0, 0.7, (f - 1, h, w, 2)).astype(np.float32)  # trajectories end and start everywhere
    bw = -fw + rng.normal(0.0, 0.3, fw.shape).astype(np.float32)
    stream = DenseTrajectoryStream((h, w))
    frames = [stream.first()] + [stream.push(fw[t], bw[t]) for t in range(f - 1)]
    whole = build_dense_trajectories(fw, bw)
    full, ids = assemble_trajectories(frames)
    np.testing.assert_array_equal(ids, np.arange(whole.count))
    for name in ("start", "length", "offsets", "positions", "labels"):
        np.testing.assert_array_equal(getattr(full, name), getattr(whole, name))
    for first, stop in ((0, f), (2, 7), (3, 6)):
        tracks, gids = assemble_trajectories(frames[first:stop])
        window = TrackWindow(frames[first:stop])
        np.testing.assert_array_equal(window.ids, gids)
        assert (window.count, window.num_frames, window.frame_shape) == (tracks.count, tracks.num_frames, (h, w))
        np.testing.assert_array_equal(gids[tracks.labels], whole.labels[first:stop])
        for stride in (1, 2):
            for group in frame_groups(stop - first, 3, stride):
                local, points = window.group(group)
                expected = alive_in_frames(tracks, group[0], group[-1])
                assert len(expected) > 0 and local.dtype == np.int64
                np.testing.assert_array_equal(local, expected)
                for p, q in zip(points, trajectory_positions(tracks, expected, group)):
                    assert p.dtype == np.float32
                    np.testing.assert_array_equal(p, q)
    with pytest.raises(ValueError, match="frame 1 is t=2, expected 1"):
        TrackWindow([frames[0], frames[2]])


def test_fill_from_neighbourhood():
    img = np.zeros((5, 6), np.float32)
    img[:, :3] = 1.0
    img[:, 3:] = 7.0
    valid = np.ones((5, 6), bool)
    valid[2, 1] = valid[2, 5] = False
    filled = fill_from_neighbourhood(np.where(valid, img, np.nan), valid)
    np.testing.assert_array_equal(filled, img)
    assert (fill_from_neighbourhood(img, np.zeros_like(valid), fallback=3.0) == 3.0).all()


def test_alive_in_frames_without_birth_order():
    from eponet.core.types import Trajectories

    start = np.array([2, 0, 1], np.int32)
    length = np.array([3, 5, 1], np.int32)
    offsets = np.r_[0, np.cumsum(length)].astype(np.int64)
    tr = Trajectories(start, length, offsets, np.zeros((9, 2), np.float32), np.zeros((5, 1, 1), np.int32))
    np.testing.assert_array_equal(alive_in_frames(tr, 2, 4, births_ordered=False), [0, 1])
    np.testing.assert_array_equal(alive_in_frames(tr, 1, 1, births_ordered=False), [1, 2])
