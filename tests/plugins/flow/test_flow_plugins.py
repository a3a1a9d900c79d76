import numpy as np
import pytest

from eponet.core.errors import InputError
from eponet.core.io import read_flo, read_image, write_flo
from eponet.core.types import Video
from eponet.plugins.flow.dis import DisFlow
from eponet.plugins.flow.farneback import FarnebackFlow
from eponet.plugins.flow.flo import FloFlow
from tests.conftest import textured_frames


def _pair(a, b):
    first, second = read_image(a), read_image(b)
    return Video("pair", np.stack([first, second]), ["a", "b"], first.shape[:2])


def _epe(flow, gt):
    known = np.isfinite(gt).all(axis=2)
    return float(np.linalg.norm(flow - gt, axis=2)[known].mean())


@pytest.mark.parametrize("stage, bound", [(DisFlow(preset="medium"), 0.30), (DisFlow(preset="ultrafast"), 0.65),
                                          (DisFlow(preset="medium", finest_scale=0), 0.15),
                                          (DisFlow(preset="medium", finest_scale=0, patch_stride=5), 0.15),
                                          (FarnebackFlow(), 0.45)])
def test_middlebury_rubberwhale_endpoint_error(shared_data, stage, bound):
    root = shared_data / "flow-gt" / "middlebury" / "RubberWhale"
    flow = stage.estimate(_pair(root / "frame10.png", root / "frame11.png"))
    assert flow.forward.shape == (1, 388, 584, 2) and flow.forward.dtype == np.float32
    assert _epe(flow.forward[0], read_flo(root / "flow10.flo")) < bound  # zero flow scores 1.26


def test_dis_finest_scale_zero_halves_the_rubberwhale_error(shared_data):
    root = shared_data / "flow-gt" / "middlebury" / "RubberWhale"
    video, gt = _pair(root / "frame10.png", root / "frame11.png"), read_flo(root / "flow10.flo")
    coarse = _epe(DisFlow(preset="medium").estimate(video).forward[0], gt)  # OpenCV's medium stops at level 1
    fine = _epe(DisFlow(preset="medium", finest_scale=0).estimate(video).forward[0], gt)
    assert fine < 0.6 * coarse


def test_dis_settings_reach_opencv_and_default_to_the_preset():
    dis = DisFlow(finest_scale=0, patch_stride=5, refinement_iterations=2).create()
    assert (dis.getFinestScale(), dis.getPatchStride(), dis.getVariationalRefinementIterations()) == (0, 5, 2)
    preset = DisFlow().create()
    assert (preset.getFinestScale(), preset.getPatchStride(), preset.getVariationalRefinementIterations()) == (1, 3, 5)


@pytest.mark.parametrize("pair", ["0000003", "0000006"])
def test_flyingchairs_dis_beats_zero_flow_by_far(shared_data, pair):
    root = shared_data / "flow-gt" / "flyingchairs"
    gt = read_flo(root / f"{pair}-gt.flo")
    flow = DisFlow().estimate(_pair(root / f"{pair}-img0.ppm", root / f"{pair}-img1.ppm")).forward[0]
    assert _epe(flow, gt) < 0.6 * _epe(np.zeros_like(gt), gt)


def test_backward_is_the_reverse_direction():
    frames = textured_frames(count=3, size=(64, 80), shift=(2.0, -1.0))
    flow = DisFlow().estimate(Video("t", frames, ["0", "1", "2"], (64, 80)))
    inner = (slice(0, 2), slice(12, -12), slice(12, -12))
    np.testing.assert_allclose(flow.forward[inner].mean(axis=(0, 1, 2)), [2.0, -1.0], atol=0.1)
    np.testing.assert_allclose(flow.backward[inner].mean(axis=(0, 1, 2)), [-2.0, 1.0], atol=0.1)


def test_flo_reader_resizes_to_processing_size_and_names_missing_files(tmp_path):
    size, stems = (40, 60), ["a", "b", "c"]
    rng = np.random.default_rng(1)
    truth = {d: [rng.normal(0, 2, size + (2,)).astype(np.float32) for _ in range(2)] for d in ("forward", "backward")}
    for direction, fields in truth.items():
        for stem, field in zip(stems, fields):
            write_flo(tmp_path / "seq" / direction / f"{stem}.flo", field)
    full = Video("seq", np.zeros((3,) + size + (3,), np.uint8), stems, size)
    flow = FloFlow(path=str(tmp_path)).estimate(full)  # finds <path>/<sequence>/forward/
    np.testing.assert_array_equal(flow.forward[1], truth["forward"][1])
    half = Video("seq", np.zeros((3, 20, 30, 3), np.uint8), stems, size)
    constant = np.full(size + (2,), 4.0, np.float32)
    write_flo(tmp_path / "seq" / "forward" / "a.flo", constant)
    assert np.allclose(FloFlow(path=str(tmp_path / "seq")).estimate(half).forward[0], 2.0)  # vectors scale too
    (tmp_path / "seq" / "backward" / "b.flo").unlink()
    with pytest.raises(InputError, match=r"backward/b.flo: missing flow file for frame b of seq"):
        FloFlow(path=str(tmp_path)).estimate(full)
    write_flo(tmp_path / "seq" / "backward" / "b.flo", np.zeros((10, 10, 2), np.float32))
    with pytest.raises(InputError, match=r"backward/b.flo: flow is 10x10, expected 60x40"):
        FloFlow(path=str(tmp_path)).estimate(full)


def test_dis_backward_finest_scale_sets_only_the_backward_flows_level(shared_data):
    root = shared_data / "flow-gt" / "middlebury" / "RubberWhale"
    video = _pair(root / "frame10.png", root / "frame11.png")
    fine, coarse = DisFlow(finest_scale=0).estimate(video), DisFlow(finest_scale=1).estimate(video)
    mixed = DisFlow(finest_scale=0, backward_finest_scale=1).estimate(video)
    assert np.array_equal(mixed.forward, fine.forward)
    # (OpenCV's DIS object keeps buffers between calls, so one that computes only backward flows may differ from
    # one that alternates directions by thousandths of a pixel)
    assert np.abs(mixed.backward - coarse.backward).mean() < 0.01 < np.abs(fine.backward - coarse.backward).mean()
    assert DisFlow(finest_scale=0, backward_finest_scale=1).create().getFinestScale() == 0
