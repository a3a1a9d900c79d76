import numpy as np
import pytest

from eponet.fusion.selftrain import MIN_SAMPLES, fit_appearance, self_trained_probability
from eponet.plugins.fusion.selftrain import SelfTrainStage


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _scene(frames=4, size=(12, 16), channels=6, seed=0):
    """Features on a (12, 16) grid where the object (rows 3-8, columns 4-9) has its own appearance (channels 0
    and 1 high), saliency at twice the grid's resolution that finds the object and also a distractor: a
    background patch (rows 0-2, columns 12-15 of the grid) that moves, so the motion map marks it too."""
    rng = np.random.default_rng(seed)
    h, w = size
    features = rng.normal(size=(frames, channels, h, w)).astype(np.float32)
    obj = np.zeros(size, bool)
    obj[3:9, 4:10] = True
    features[:, 0][:, obj] += 3.0
    features[:, 1][:, obj] += 3.0
    saliency = np.zeros((frames, 2 * h, 2 * w), np.float32)
    saliency[:, 6:18, 8:20] = 0.95
    saliency[:, 0:6, 24:32] = 0.95  # the distractor: confident motion, background appearance
    return features, saliency, np.kron(obj, np.ones((2, 2), bool))


def test_fit_appearance_separates_known_classes():
    features, _, _ = _scene()
    labels = np.full((4, 12, 16), -1, np.int8)
    labels[:, 3:9, 4:10] = 1
    labels[:, 10:, :] = 0
    p = fit_appearance(features, labels)
    assert p.shape == (4, 12, 16) and p.dtype == np.float32
    assert p[:, 3:9, 4:10].mean() > 0.9  # the labelled object
    assert p[:, 0:2, 0:3].mean() < 0.1  # unlabelled background of the same appearance as the negatives


def test_distractor_of_background_appearance_is_dropped_and_object_kept():
    features, saliency, obj = _scene()
    p = self_trained_probability(features, saliency, foreground=0.9, background=0.05, weight=1.0)
    assert p.shape == saliency.shape and p.dtype == np.float32
    assert 0.0 <= p.min() and p.max() <= 1.0
    assert p[:, obj].mean() > 0.8
    assert p[:, 0:6, 24:32].mean() < 0.3  # the distractor: the motion map said 0.95
    mixed = self_trained_probability(features, saliency, weight=0.5)
    np.testing.assert_allclose(mixed, 0.5 * saliency + 0.5 * p, atol=1e-6)


def test_too_few_confident_pixels_keep_the_saliency():
    features, saliency, _ = _scene()
    dim = saliency * 0.5  # nothing above the foreground threshold
    assert np.array_equal(self_trained_probability(features, dim), dim)
    labels = np.zeros((4, 12, 16), np.int8)
    labels[0, 0, : MIN_SAMPLES - 1] = 1
    assert fit_appearance(features, labels) is None


def test_foreground_share_seeds_a_window_that_is_nowhere_sure():
    """A small object the map only half marks (0.45 everywhere on it, nothing above 0.9): the fixed threshold keeps
    the saliency; with ``foreground_share`` the window's top cells seed the classifier, the object comes out sure
    and the distractor (0.4, background appearance) does not; a floor above the object's 0.45 keeps the saliency."""
    features, saliency, obj = _scene()
    dim = np.full(saliency.shape, 0.01, np.float32)
    dim[:, 6:18, 8:20] = 0.45
    dim[:, 0:6, 24:32] = 0.40
    assert np.array_equal(self_trained_probability(features, dim, weight=1.0), dim)
    share = obj.mean()  # the object's share of the frame: its cells are the window's top share
    p = self_trained_probability(features, dim, weight=1.0, foreground_share=share, foreground_floor=0.3)
    assert p[:, obj].mean() > 0.8 and p[:, 0:6, 24:32].mean() < 0.3
    floored = self_trained_probability(features, dim, weight=1.0, foreground_share=share, foreground_floor=0.5)
    assert np.array_equal(floored, dim)
    # where the map is sure about enough cells, the share changes nothing
    sure = self_trained_probability(features, saliency, weight=1.0)
    assert np.array_equal(self_trained_probability(features, saliency, weight=1.0, foreground_share=0.01,
                                                   foreground_floor=0.3), sure)


def test_background_examples_can_require_the_motion_map_to_agree():
    """With ``motion`` and ``background_motion``, a cell the fused map calls background is a negative only where the
    motion map is below ``background_motion`` too: the result is exactly the fit on those labels."""
    import cv2

    features, saliency, obj = _scene()
    fused = np.where(saliency > 0.5, 0.95, 0.01).astype(np.float32)
    fused[:, 0:6, 24:32] = 0.01  # the fusion dropped the moving patch ...
    motion = saliency.copy()  # ... which the motion map still marks (0.95)
    p = self_trained_probability(features, fused, weight=1.0, motion=motion, background_motion=0.1)
    grid = np.stack([cv2.resize(f, (16, 12), interpolation=cv2.INTER_AREA) for f in fused])
    moving = np.stack([cv2.resize(m, (16, 12), interpolation=cv2.INTER_AREA) for m in motion])
    labels = np.full(grid.shape, -1, np.int8)
    labels[grid > 0.9] = 1
    labels[(grid < 0.05) & (moving < 0.1)] = 0
    assert (labels[:, 0:3, 12:16] == -1).all()  # the patch is no background example
    expected = fit_appearance(features, labels)
    expected = np.stack([cv2.resize(e, (32, 24), interpolation=cv2.INTER_LINEAR) for e in expected])
    np.testing.assert_allclose(p, np.clip(expected, 0, 1), atol=1e-6)
    assert p[:, obj].mean() > 0.8
    # without a threshold the motion map is ignored
    np.testing.assert_array_equal(self_trained_probability(features, fused, weight=1.0, motion=motion),
                                  self_trained_probability(features, fused, weight=1.0))


def test_seeded_and_deterministic_stage():
    features, saliency, _ = _scene()
    stage = SelfTrainStage(window=None, samples=200)
    a = stage.fuse(features, saliency)
    assert np.array_equal(a, SelfTrainStage(window=None, samples=200).fuse(features, saliency))
    assert stage.window is None and SelfTrainStage().window == 64
