"""Guided sampling's memory across windows (SamplingHistory) and the sampling rule it feeds."""

import numpy as np
import pytest

from eponet.geometry.scoring import SamplingHistory, largest, score_frame_groups
from eponet.geometry.trajectories import build_dense_trajectories
from eponet.geometry.fits import FittedModel


def test_history_lookup_store_keep_known_answers():
    h = SamplingHistory()
    sums, counts = h.lookup(np.array([3, 1]))
    assert sums.tolist() == [0.0, 0.0] and counts.tolist() == [0, 0]
    h.store(np.array([5, 2, 9]), np.array([1.5, 2.0, 7.0]), np.array([1, 2, 0]))  # 9: never scored, left out
    assert h.ids.tolist() == [2, 5]
    h.store(np.array([2, 7]), np.array([4.0, 0.5]), np.array([3, 1]))  # 2 replaced, 7 added
    assert h.ids.tolist() == [2, 5, 7] and h.sums.tolist() == [4.0, 1.5, 0.5] and h.counts.tolist() == [3, 1, 1]
    sums, counts = h.lookup(np.array([7, 4, 2]))
    assert sums.tolist() == [0.5, 0.0, 4.0] and counts.tolist() == [1, 0, 3]
    h.keep(np.array([5, 7, 8]))
    assert h.ids.tolist() == [5, 7]


def _identity_estimator(log):
    """An estimator that records each group's sample and fits the identity homography (distance = how far a
    point moved), drawing one number as a RANSAC would."""

    def estimate(points, generator):
        log.append(np.concatenate(points, axis=1))
        generator.random()
        return FittedModel(kind="homography", matrices=(np.eye(3), np.eye(3)),
                           inliers=np.ones(len(points[0]), bool))

    return estimate


def test_groups_split_over_calls_with_a_history_equal_one_call():
    """Scoring groups 0-2, then 3-5, in two calls sharing a history gives the samples, sums and counts of one
    call over groups 0-5 (the same generator drawn in order); without the history the later groups sample
    other points."""
    rng = np.random.default_rng(0)
    f, h, w = 8, 12, 16
    fw = rng.normal(0, 0.3, (f - 1, h, w, 2)).astype(np.float32)
    fw[:, 3:9, 4:12] += 2.0  # an "object": large distances, so a low sampling weight in later groups
    tracks = build_dense_trajectories(fw, -fw)
    groups = [(t, t + 1, t + 2) for t in range(f - 2)]
    settings = {"max_points": 40, "border": 0.0}

    whole_log = []
    whole = score_frame_groups(tracks, groups, _identity_estimator(whole_log), np.random.default_rng(1), **settings)
    split_log, history, ids, gen = [], SamplingHistory(), np.arange(tracks.count), np.random.default_rng(1)
    a = score_frame_groups(tracks, groups[:3], _identity_estimator(split_log), gen, history=history, track_ids=ids,
                           **settings)
    b = score_frame_groups(tracks, groups[3:], _identity_estimator(split_log), gen, history=history, track_ids=ids,
                           **settings)
    assert len(split_log) == len(whole_log) == 6
    for got, expected in zip(split_log, whole_log):
        np.testing.assert_array_equal(got, expected)
    np.testing.assert_allclose(a[0] + b[0], whole[0])
    np.testing.assert_array_equal(a[1] + b[1], whole[1])
    assert history.scale is not None
    np.testing.assert_array_equal(history.lookup(ids)[1], whole[1])  # every group a trajectory was scored in

    fresh_log, gen = [], np.random.default_rng(1)
    score_frame_groups(tracks, groups[:3], _identity_estimator([]), gen, **settings)
    score_frame_groups(tracks, groups[3:], _identity_estimator(fresh_log), gen, **settings)
    assert not np.array_equal(fresh_log[0], whole_log[3])


def test_a_history_needs_the_global_ids():
    fw = np.zeros((3, 6, 6, 2), np.float32)
    tracks = build_dense_trajectories(fw, fw)
    with pytest.raises(ValueError, match="track_ids"):
        score_frame_groups(tracks, [(0, 1, 2)], _identity_estimator([]), np.random.default_rng(0), max_points=20,
                           history=SamplingHistory())


def _uneven_survival_tracks(seed: int = 0):
    """One triplet of exact tracks in a 120 x 160 frame: a camera translating sideways past a rigid scene 4-12 m
    deep, and an object strip 2.5-3.5 m deep along the bottom of the frame (30% of it, touching three edges)
    that the camera follows sideways while it moves up: it moves across the epipolar lines, by its own rigid
    motion. Every object pixel has a track through the
    triplet; only one background pixel in five has one (the others end after frame 0, as on a blurred
    background). Returns the tracks, which are on the object, and the frame size."""
    from eponet.core.types import Trajectories

    rng = np.random.default_rng(seed)
    h, w, f = 120, 160, 200.0
    ys, xs = np.mgrid[0:h, 0:w]
    x0 = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float64)
    on_object = x0[:, 1] >= 0.7 * h
    depth = np.where(on_object, rng.uniform(2.5, 3.5, len(x0)), rng.uniform(4.0, 12.0, len(x0)))
    rays = np.column_stack([(x0[:, 0] - w / 2) / f, (x0[:, 1] - h / 2) / f, np.ones(len(x0))]) * depth[:, None]
    frames = []
    for k in range(3):
        points = rays - np.array([0.15 * k, 0.0, 0.0])  # the camera moves 15 cm per frame along x
        points[on_object] += np.array([0.15 * k, -0.08 * k, 0.0])  # the object moves with the camera, and up
        frames.append(np.column_stack([points[:, 0] / points[:, 2] * f + w / 2, points[:, 1] / points[:, 2] * f + h / 2]))
    through = on_object | (rng.random(len(x0)) < 0.2)
    length = np.where(through, 3, 1).astype(np.int32)
    offsets = np.concatenate([[0], np.cumsum(length)]).astype(np.int64)
    positions = np.empty((int(offsets[-1]), 2), np.float32)
    for k in range(3):
        rows = offsets[:-1][length > k] + k
        positions[rows] = frames[k][length > k]
    labels = np.broadcast_to(np.arange(h * w, dtype=np.int32).reshape(h, w), (3, h, w)).copy()
    tracks = Trajectories(start=np.zeros(len(x0), np.int32), length=length, offsets=offsets, positions=positions,
                          labels=labels)
    return tracks, on_object, (h, w)


def test_area_sampling_keeps_the_background_where_its_tracks_die():
    """Where the background keeps one track in five through the triplet and the object all of its own, the
    object holds 68% of the tracks alive through it: guided sampling fits the object's motion (the object gets
    zero distances), area sampling the background's (zero there, the object far off). The epipolar model is
    kept in both (``degeneracy="none"``), so that only the sample differs."""
    from eponet.plugins.rigidity.trifocal import TrifocalRigidity

    tracks, on_object, size = _uneven_survival_tracks()
    alive = tracks.length == 3
    assert 0.6 < on_object[alive].mean() < 0.75
    medians = {}
    for sampling in ("guided", "area"):
        stage = TrifocalRigidity(sampling=sampling, max_points=1000, degeneracy="none")
        sums, counts, _ = score_frame_groups(
            tracks, [(0, 1, 2)], lambda p, g: stage.estimate(p, g, size), np.random.default_rng(0),
            max_points=1000, sampling=sampling)
        d = sums[alive] / counts[alive]
        medians[sampling] = (np.median(d[on_object[alive]]), np.median(d[~on_object[alive]]))
    assert medians["guided"][0] < 0.1 < 10 < medians["guided"][1]  # the object taken for the background
    assert medians["area"][1] < 0.1 < 10 < medians["area"][0]  # the background fitted, the object far off it


def test_area_weight_known_answers():
    """Four points in one 10 px cell of a 160 x 160 frame and one alone in another: weights 1/4 and 1."""
    from eponet.geometry.scoring import area_weight

    x = np.array([[1.0, 1.0], [2.0, 3.0], [9.0, 9.0], [5.0, 0.0], [100.0, 50.0]])
    assert area_weight(x, (160, 160)).tolist() == [0.25, 0.25, 0.25, 0.25, 1.0]


def _spray_tracks(seed: int = 0, frames: int = 9, jitter: float = 1.0):
    """Exact tracks of a camera translating sideways past a rigid scene 4-12 m deep in a 96 x 128 frame, with an
    object block (24 x 32 px) moving up on its own, tracked through every frame, and a spray patch (32 x 48 px,
    top left) whose tracks last three frames each (one triplet) and jitter by ``jitter`` px per frame: motion
    that no rigid model explains, measured once per track. Returns the tracks and the object's and the spray's
    pixels (bool (96, 128))."""
    from eponet.core.types import Trajectories

    rng = np.random.default_rng(seed)
    h, w, f = 96, 128, 150.0
    ys, xs = np.mgrid[0:h, 0:w]
    x0 = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float64)
    on_object = ((ys >= 40) & (ys < 64) & (xs >= 60) & (xs < 92)).ravel()
    spray = ((ys < 32) & (xs < 48)).ravel()
    rays = np.column_stack([(x0[:, 0] - w / 2) / f, (x0[:, 1] - h / 2) / f, np.ones(len(x0))])
    rays *= rng.uniform(4.0, 12.0, len(x0))[:, None]
    projected = []
    for k in range(frames):
        points = rays - np.array([0.1 * k, 0.0, 0.0])  # the camera moves 10 cm per frame along x
        points[on_object] += np.array([0.0, -0.03 * k, 0.0])  # the object moves up
        projected.append(np.column_stack([points[:, 0] / points[:, 2] * f + w / 2,
                                          points[:, 1] / points[:, 2] * f + h / 2]))
    projected = np.stack(projected)
    pixel = np.concatenate([np.flatnonzero(~spray)] + [np.flatnonzero(spray)] * len(range(0, frames, 3)))
    start = np.concatenate([np.zeros((~spray).sum(), np.int32)]
                           + [np.full(spray.sum(), s, np.int32) for s in range(0, frames, 3)])
    length = np.where(spray[pixel], np.minimum(3, frames - start), frames).astype(np.int32)
    offsets = np.concatenate([[0], np.cumsum(length)]).astype(np.int64)
    track = np.repeat(np.arange(len(pixel)), length)  # the track of each row of positions
    frame = start[track] + np.arange(len(track)) - offsets[track]
    at = pixel[track]
    positions = (projected[frame, at] + rng.normal(0, jitter, (len(track), 2)) * spray[at, None]).astype(np.float32)
    labels = np.empty((frames, h, w), np.int32)
    labels[frame, at // w, at % w] = track
    tracks = Trajectories(start=start, length=length, offsets=offsets, positions=positions, labels=labels)
    return tracks, on_object.reshape(h, w), spray.reshape(h, w)


def test_prior_groups_pull_one_group_spray_below_a_tracked_object():
    """Spray measured in one triplet per track scores above the independently moving object with plain means;
    shrunk toward the median by ``prior_groups`` (the rigid background's ~0 here) it falls below the object,
    whose seven triplets keep most of its own distance, and the object's per-frame ROC AUC rises to >= 0.98.
    The background stays at ~0 and ``per_trajectory`` stays the plain mean."""
    from eponet.plugins.rigidity.trifocal import TrifocalRigidity
    from tests.geometry.scenes import roc_auc

    tracks, on_object, spray = _spray_tracks()
    background = ~on_object & ~spray
    result = {}
    for k in (0.0, 4.0):
        r = TrifocalRigidity(prior_groups=k, degeneracy="none").score(tracks, None, np.random.default_rng(0))
        assert all(info["model"] == "trifocal" for info in r.triplets)
        auc = np.mean([roc_auc(r.ed[t], on_object) for t in range(len(r.ed))])
        result[k] = (np.median(r.ed[:, on_object]), np.median(r.ed[:, spray]), np.median(r.ed[:, background]), auc,
                     r.per_trajectory)
    (obj0, spray0, bg0, auc0, plain0), (obj4, spray4, bg4, auc4, plain4) = result[0.0], result[4.0]
    assert spray0 > obj0 > 2.0 and bg0 < 0.05 and auc0 < 0.95
    assert obj4 > 2 * spray4 and bg4 < 0.05 and auc4 >= 0.98
    np.testing.assert_array_equal(plain0, plain4)


def test_shrunk_means_known_answers():
    """k = 0: the plain mean; the median ``m`` of the scored means; (sum + k m) / (n + k); unscored: NaN."""
    from eponet.core.motion import shrunk_means

    sums, counts = np.array([2.0, 6.0, 40.0, 0.0]), np.array([1, 2, 10, 0])
    plain, m = shrunk_means(sums, counts, 0.0)
    assert m == 3.0 and plain[:3].tolist() == [2.0, 3.0, 4.0] and np.isnan(plain[3])
    shrunk, m = shrunk_means(sums, counts, 2.0)
    np.testing.assert_allclose(shrunk[:3], [(2 + 6) / 3, (6 + 6) / 4, (40 + 6) / 12], rtol=1e-6)
    assert np.isnan(shrunk[3]) and shrunk.dtype == np.float32



def test_largest_selects_the_k_largest_keys_as_a_full_partition_does():
    """The sampled threshold only narrows where the exact selection runs: the same indices as selecting among all
    keys, for weighted sampling keys (``log(u) / w``, ``-inf`` included), few keys, and a threshold that too few
    keys pass."""
    rng = np.random.default_rng(0)
    for n, k in ((430_000, 10_000), (50_000, 1_000), (10_001, 10_000), (100, 7)):
        keys = np.log(rng.random(n)) / rng.uniform(0.1, 1.0, n)
        keys[:3] = -np.inf
        got = largest(keys, k)
        assert got.dtype == np.int64 and len(got) == k and (np.diff(got) > 0).all()
        np.testing.assert_array_equal(got, np.sort(np.argpartition(-keys, k)[:k]))
    keys = np.zeros(100_000)  # every 64th key is the largest: the threshold passes only those, fewer than k
    keys[::64] = 1.0
    keys[5] = 0.5
    np.testing.assert_array_equal(largest(keys, 1_564), np.sort(np.r_[np.arange(0, 100_000, 64), 5]))
