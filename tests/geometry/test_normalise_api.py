"""Frame groups and the geometry package's public names."""

from __future__ import annotations

import numpy as np
import pytest

import eponet.geometry as geometry
from eponet.geometry import frame_groups


def test_public_api_names_exist():
    expected = {
        "build_dense_trajectories", "forward_backward_consistency", "exact_round_trip", "trifocal_six_point",
        "trifocal_linear", "fundamentals_from_trifocal", "epipolar_line_distances", "triplet_epipolar_distance",
        "homography_dlt", "gric", "robust_search", "estimate_triplet", "paint_trajectory_values",
        "fill_from_neighbourhood", "hartley_normalisation", "RigidityStage",
    }
    assert expected <= set(geometry.__all__)
    for name in geometry.__all__:
        assert getattr(geometry, name) is not None, name
    assert len(set(geometry.__all__)) == len(geometry.__all__)


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
