"""The ``dense`` trajectory stage: schema, contract, bad input."""

from __future__ import annotations

import inspect

import numpy as np
import pytest

from eponet.core.errors import InputError
from eponet.core.protocols import TrajectoryBuilder
from eponet.core.types import FlowPair
from eponet.plugins.trajectories import dense


def _flow(frames=5, h=20, w=24, dx=1.0, dy=0.5):
    fw = np.zeros((frames - 1, h, w, 2), np.float32)
    fw[..., 0], fw[..., 1] = dx, dy
    return FlowPair(fw, -fw)


def test_spec_defaults_match_constructor():
    (spec,) = dense.eponet_stages()
    assert (spec.kind, spec.name) == ("trajectories", "dense")
    sig = inspect.signature(spec.factory)
    for p in spec.params:
        assert sig.parameters[p.name].default == p.default, p.name
    assert set(sig.parameters) == {p.name for p in spec.params}
    stage = spec.factory(**{p.name: p.default for p in spec.params})
    assert isinstance(stage, TrajectoryBuilder)


@pytest.mark.parametrize("consistency", ["tolerance", "exact"])
def test_build_covers_every_pixel(consistency):
    stage = dense.DenseTrajectories(consistency=consistency)
    tr = stage.build(_flow(dy=0.25))  # (the exact round trip fails everywhere for half-pixel flow)
    assert tr.labels.shape == (5, 20, 24) and (tr.labels >= 0).all()
    assert tr.count >= 20 * 24 and tr.positions.dtype == np.float32
    # ids painted in frame 0 live on, exactly translated (the flow is constant)
    j = tr.labels[0, 5, 5]
    np.testing.assert_array_equal(tr.positions_of(j)[2], [7.0, 5.5])


def test_bad_input():
    stage = dense.DenseTrajectories()
    with pytest.raises(InputError, match="at least 3 frames"):
        stage.build(_flow(frames=2))
    bad = _flow()
    bad.forward = bad.forward[..., :1]  # wrong channel count (bypassing FlowPair's own check)
    with pytest.raises(InputError, match="H, W, 2"):
        stage.build(bad)
    with pytest.raises(ValueError, match="consistency"):
        dense.DenseTrajectories(consistency="nope")


def test_non_finite_flow_is_a_documented_fallback(caplog):
    flow = _flow()
    flow.forward[1, 3:6, 3:6] = np.inf
    flow.backward[2, 0, 0] = np.nan
    tr = dense.DenseTrajectories().build(flow)
    assert (tr.labels >= 0).all() and np.isfinite(tr.positions).all()
    assert "not finite" in caplog.text


def test_float64_flow_accepted():
    flow = _flow()
    tr = dense.DenseTrajectories().build(FlowPair(flow.forward.astype(np.float64), flow.backward.astype(np.float64)))
    assert tr.positions.dtype == np.float32
