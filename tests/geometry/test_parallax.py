"""The plane + parallax evidence (eponet.geometry.parallax) and the border prior of guided sampling, on
points with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from eponet.geometry.parallax import border_ratio, is_parallax, rigid_second_plane
from eponet.geometry.scoring import BORDER_PRIOR, border_weight


def _grid(h=100, w=200):
    ys, xs = np.mgrid[0:h, 0:w]
    return np.c_[xs.ravel(), ys.ravel()].astype(np.float64)


def test_border_ratio_known_answers():
    x = _grid()
    # band 0.05 * 100 = 5 px: the near-border pixels are those with x < 5, x > 194, y < 5 or y > 94
    near = (x[:, 0] < 5) | (x[:, 0] > 194) | (x[:, 1] < 5) | (x[:, 1] > 94)
    assert border_ratio(x, np.ones(len(x), bool), (100, 200)) == pytest.approx(1.0)
    assert border_ratio(x, near, (100, 200)) == pytest.approx(1.0 / near.mean())
    assert border_ratio(x, ~near, (100, 200)) == 0.0
    assert border_ratio(x, np.zeros(len(x), bool), (100, 200)) == 0.0


def test_rigid_second_plane_reads_fast_border_structure_as_parallax():
    x1 = _grid()
    n = len(x1)
    bottom = x1[:, 1] >= 80  # a fifth of the frame along the bottom edge
    centre = (np.abs(x1[:, 0] - 100) < 25) & (np.abs(x1[:, 1] - 50) < 20)  # 10% in the middle
    e2t = np.full(n, 0.01)
    for plane, speed, want in ((bottom, 6.0, True), (bottom, 0.3, False), (centre, 6.0, False)):
        e2h = np.where(plane, 100.0, 0.01)  # the dominant homography misses the plane ...
        e2h2 = np.where(plane, 0.01, 100.0)  # ... the second one and the trifocal model explain it
        x3 = x1 + np.where(plane[:, None], [speed, 0.0], [1.0, 0.0])
        ev = rigid_second_plane(e2t, e2h, e2h2, x1, x3, 0.25, (100, 200))
        assert ev["plane"] == pytest.approx(plane.mean(), abs=1e-4)
        assert ev["speed"] == pytest.approx(max(speed, 0.05) / 1.0, rel=1e-3)
        assert is_parallax(ev) is want, ev
    # a plane the trifocal model does not explain is no evidence of parallax
    e2h = np.where(bottom, 100.0, 0.01)
    ev = rigid_second_plane(np.where(bottom, 100.0, 0.01), e2h, np.where(bottom, 0.01, 100.0), x1,
                            x1 + [6.0, 0.0], 0.25, (100, 200))
    assert ev["plane"] == 0.0 and not is_parallax(ev)


def test_border_weight():
    x = np.array([[0.0, 50.0], [199.0, 50.0], [100.0, 0.0], [100.0, 50.0], [7.5, 50.0]])
    w = border_weight(x, (100, 200))
    # on the edge: 1; 50 px inside (beyond the 15 px band): the interior weight 0.1; halfway through the band: 0.5
    np.testing.assert_allclose(w, [1.0, 1.0, 1.0, 0.1, 0.5])
    assert BORDER_PRIOR == 0.15
