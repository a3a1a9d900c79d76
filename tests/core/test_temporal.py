"""Temporal averaging along the flow (eponet.core.temporal) and the run loop's use of it (refiner.temporal)."""

import numpy as np

from eponet.core.inputs import discover_sequences, load_video
from eponet.core.pipeline import Pipeline
from eponet.core.temporal import temporal_mean, warp_into
from tests.core.test_stream import _clip, _spec


def _square(shape, x, y, side=6):
    p = np.zeros(shape, np.float32)
    p[y : y + side, x : x + side] = 1.0
    return p


def _constant_flow(shape, dx, dy):
    flow = np.zeros(shape + (2,), np.float32)
    flow[..., 0], flow[..., 1] = dx, dy
    return flow


def test_a_neighbour_warped_along_exact_flow_lands_on_the_object():
    shape = (24, 32)
    here = _square(shape, 10, 8)
    there = _square(shape, 13, 10)  # the object moved (3, 2) px
    warped, consistent = warp_into(there, _constant_flow(shape, 3, 2), _constant_flow(shape, -3, -2))
    assert consistent.all()
    np.testing.assert_allclose(warped[:, :27], here[:, :27], atol=1e-6)  # (the last columns sample beyond the edge)


def test_inconsistent_flow_is_flagged_and_replaced_by_the_frames_own_value():
    shape = (24, 32)
    here = np.full(shape, 0.2, np.float32)
    there = np.full(shape, 1.0, np.float32)
    forward = _constant_flow(shape, 2, 0)
    back = _constant_flow(shape, -2, 0)
    back[:, 16:] = (5.0, 5.0)  # occluded: the return flow does not come back
    _, consistent = warp_into(there, forward, back)
    assert consistent[:, :12].all() and not consistent[:, 16:].any()
    averaged = temporal_mean(here, None, (there, forward, back))
    np.testing.assert_allclose(averaged[:, :12], 0.6, atol=1e-6)  # (0.2 + 1.0) / 2
    np.testing.assert_allclose(averaged[:, 16:], 0.2, atol=1e-6)  # the frame's own value stands in


def test_a_frame_that_lost_the_object_gets_two_thirds_of_it_back():
    """The object moves 2 px right per frame; the network missed it in frame t only."""
    shape = (24, 40)
    before, after = _square(shape, 8, 9), _square(shape, 12, 9)
    missed = np.zeros(shape, np.float32)
    right, left = _constant_flow(shape, 2, 0), _constant_flow(shape, -2, 0)
    averaged = temporal_mean(missed, (before, left, right), (after, right, left))
    np.testing.assert_allclose(averaged[9:15, 10:16], 2 / 3, atol=1e-6)
    assert averaged[:9].max() == 0 and averaged[15:].max() == 0


def test_the_run_loop_averages_the_probability_it_hands_the_refiner(tmp_path):
    """refiner.temporal 1: each frame's probability is the temporal mean of the run without it, computed with the
    run's own flow (at scale 1 the processing size is the input size)."""
    folder = _clip(tmp_path / "clip", count=8)
    video = load_video(discover_sequences(folder)[0], scale=1.0)
    stages = {"refiner": {"plugin": "densecrf", "temporal": 1}, "rigidity": {"max_points": 300}}
    plain = Pipeline(_spec(folder, tmp_path / "a", preset="epo", stages={**stages, "refiner": {"plugin": "densecrf", "temporal": 0}},
                           save=("masks",))).process(video)
    averaged = Pipeline(_spec(folder, tmp_path / "b", preset="epo", stages=stages, save=("masks",))).process(video)
    p, flow = plain.saliency, plain.flow
    assert not np.allclose(averaged.saliency, p)
    for t in range(len(p)):
        before = (p[t - 1], flow.backward[t - 1], flow.forward[t - 1]) if t > 0 else None
        after = (p[t + 1], flow.forward[t], flow.backward[t]) if t + 1 < len(p) else None
        np.testing.assert_allclose(averaged.saliency[t], temporal_mean(p[t], before, after).clip(0, 1), atol=1e-5)


def test_the_presets_that_refine_average():
    from eponet.core.registry import get_registry

    registry = get_registry()
    for preset in ("epo", "epo-st", "epo+"):
        assert registry.resolve_preset(preset)["refiner"]["temporal"] == 1
    assert "refiner" not in registry.resolve_preset("geometry")
