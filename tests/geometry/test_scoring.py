"""Guided sampling's memory across windows (SamplingHistory) and the sampling rule it feeds."""

import numpy as np
import pytest

from eponet.geometry.scoring import SamplingHistory, score_frame_groups
from eponet.geometry.trajectories import build_dense_trajectories
from eponet.geometry.triplets import FittedModel


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
