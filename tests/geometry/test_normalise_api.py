"""The per-video ED normalisation, frame groups, and the package's public names."""

from __future__ import annotations

import numpy as np
import pytest

import eponet.geometry as geometry
from eponet.geometry import ED_TARGET, ed_scale, frame_groups, normalise_ed


def test_public_api_names_exist():
    expected = {
        "build_dense_trajectories", "forward_backward_consistency", "exact_round_trip", "trifocal_six_point",
        "trifocal_linear", "fundamentals_from_trifocal", "epipolar_line_distances", "triplet_epipolar_distance",
        "homography_dlt", "gric", "robust_search", "estimate_triplet", "paint_trajectory_values",
        "fill_from_neighbourhood", "normalise_ed", "hartley_normalisation", "RigidityStage",
    }
    assert expected <= set(geometry.__all__)
    for name in geometry.__all__:
        assert getattr(geometry, name) is not None, name
    assert len(set(geometry.__all__)) == len(geometry.__all__)


def test_normalise_ed_maps_percentile_and_saturates():
    rng = np.random.default_rng(0)
    ed = rng.uniform(0, 10, (4, 30, 40)).astype(np.float32)
    out = normalise_ed(ed)
    assert out.dtype == np.float32 and out.shape == ed.shape
    assert out.min() >= 0 and out.max() <= 1
    p95 = np.percentile(ed, 95)
    np.testing.assert_allclose(np.percentile(out, 95), ED_TARGET, rtol=1e-4)
    assert (out[ed > 1.03 * p95] == 1.0).all()
    # the scale is per video: scaling the input leaves the output unchanged
    np.testing.assert_allclose(normalise_ed(ed * 3), out, atol=1e-6)


def test_unsaturated_normalisation_keeps_the_range_above_the_percentile():
    rng = np.random.default_rng(1)
    ed = rng.uniform(0, 10, (4, 30, 40)).astype(np.float32)
    ed[0, :3, :3] = 400.0  # a small, fast object: 40 times the background's largest
    out = normalise_ed(ed, saturate=False)
    s = np.percentile(ed, 95)
    np.testing.assert_allclose(out, ed * ED_TARGET / s, rtol=1e-5)
    assert out[0, 0, 0] > 35 and out.min() >= 0
    np.testing.assert_array_equal(np.minimum(out, 1.0), normalise_ed(ed))  # clipping it gives the paper's


def test_normalise_ed_floor_and_non_finite():
    quiet = np.full((2, 5, 5), 0.2, np.float32)  # a rigid video: ED is flow noise only
    assert ed_scale(quiet) == 1.0
    np.testing.assert_allclose(normalise_ed(quiet), 0.2 * ED_TARGET, rtol=1e-6)
    bad = quiet.copy()
    bad[0, 0, 0], bad[0, 0, 1] = np.nan, np.inf
    out = normalise_ed(bad)
    assert out[0, 0, 0] == 0 and out[0, 0, 1] == 1 and np.isfinite(out).all()
    assert normalise_ed(np.zeros((3, 4, 4), np.float32)).max() == 0


@pytest.mark.parametrize("frames,views,stride,first,count", [(10, 3, 1, (0, 1, 2), 8), (10, 3, 3, (0, 3, 6), 4),
                                                             (5, 3, 4, (0, 2, 4), 1), (4, 2, 1, (0, 1), 3)])
def test_frame_groups(frames, views, stride, first, count):
    groups = frame_groups(frames, views, stride)
    assert groups[0] == first and len(groups) == count


@pytest.mark.parametrize("name", ["consistency", "epipolar", "homography", "normalise", "robust", "scoring",
                                  "trajectories", "trifocal", "triplets"])
def test_docstring_examples(name):
    import doctest
    import importlib

    module = importlib.import_module(f"eponet.geometry.{name}")
    result = doctest.testmod(module, extraglobs={"np": np}, optionflags=doctest.ELLIPSIS)
    assert result.failed == 0
