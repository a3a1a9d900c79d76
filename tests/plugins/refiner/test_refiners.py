import numpy as np
import pytest

from eponet.plugins.refiner.densecrf import DenseCrfRefiner, densecrf_mask
from eponet.plugins.refiner.threshold import ThresholdRefiner


def _scene(seed=0):
    """A blue disc on a textured orange background, and a noisy, blurry probability of it."""
    rng = np.random.default_rng(seed)
    height, width = 96, 128
    yy, xx = np.mgrid[:height, :width]
    truth = ((xx - 60) ** 2 + (yy - 50) ** 2 < 28 ** 2).astype(np.uint8)
    frame = np.where(truth[..., None], [40, 60, 200], [210, 140, 60]).astype(np.float64)
    frame = np.clip(frame + rng.normal(0, 12, frame.shape), 0, 255).astype(np.uint8)
    import cv2

    soft = cv2.GaussianBlur(truth.astype(np.float32), (0, 0), 6)
    prob = np.clip(0.15 + 0.5 * soft + rng.normal(0, 0.25, truth.shape), 0, 1).astype(np.float32)
    return frame, prob, truth


def _iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


def test_densecrf_cleans_a_noisy_probability():
    frame, prob, truth = _scene()
    thresholded = ThresholdRefiner(threshold=0.5).refine(frame[None], prob[None])[0]
    refined = densecrf_mask(frame, prob)
    assert refined.dtype == np.uint8 and set(np.unique(refined)) <= {0, 1}
    assert _iou(refined, truth) > 0.9
    assert _iou(refined, truth) > _iou(thresholded, truth) + 0.1


def test_densecrf_refiner_batches_frames_and_handles_constant_maps():
    frame, prob, truth = _scene(1)
    masks = DenseCrfRefiner(iterations=5, gaussian_sxy=3.0, gaussian_compat=3.0, bilateral_sxy=50.0,
                            bilateral_srgb=10.0, bilateral_compat=5.0, normalise=True, scale=1.0).refine(
        np.stack([frame, frame]), np.stack([prob, np.full_like(prob, 0.2)]))
    assert masks.shape == (2,) + truth.shape
    assert _iou(masks[0], truth) > 0.9
    assert masks[1].sum() == 0  # a constant low probability stays background (no division by zero)


def test_threshold_known_answer():
    prob = np.array([[[0.2, 0.5, 0.8]]], np.float32)
    np.testing.assert_array_equal(ThresholdRefiner(threshold=0.5).refine(None, prob), [[[0, 1, 1]]])


def test_downscaled_crf_agrees_with_full_resolution():
    frame, prob, truth = _scene(2)
    full = densecrf_mask(frame, prob)
    half = densecrf_mask(frame, prob, scale=0.5)
    assert half.shape == truth.shape
    assert _iou(half, truth) > 0.88 and _iou(half, full) > 0.9


def test_max_size_caps_the_crf_resolution():
    frame, prob, _ = _scene(2)
    longer = max(prob.shape)
    # a cap at half the longer side is the same computation as scale 0.5; a cap above it changes nothing
    np.testing.assert_array_equal(densecrf_mask(frame, prob, max_size=longer // 2),
                                  densecrf_mask(frame, prob, scale=(longer // 2) / longer))
    np.testing.assert_array_equal(densecrf_mask(frame, prob, max_size=longer * 2), densecrf_mask(frame, prob))


def _small_object_scene(seed=3):
    """A 30x40 px green patch on a wide textured frame (the box around it is a fifth of the frame) and a noisy
    probability of it: low everywhere else, and one pixel in a far corner above 0.5 nowhere (only the patch)."""
    import cv2

    rng = np.random.default_rng(seed)
    height, width = 120, 200
    truth = np.zeros((height, width), np.uint8)
    truth[40:70, 120:160] = 1
    frame = np.where(truth[..., None], [60, 190, 70], [150, 120, 110]).astype(np.float64)
    frame = np.clip(frame + rng.normal(0, 10, frame.shape), 0, 255).astype(np.uint8)
    soft = cv2.GaussianBlur(truth.astype(np.float32), (0, 0), 4)
    prob = np.clip(0.1 + 0.7 * soft + rng.normal(0, 0.12, truth.shape), 0, 1).astype(np.float32)
    prob[soft < 0.02] = np.minimum(prob[soft < 0.02], 0.45)  # far from the patch nothing passes 0.5
    return frame, prob, truth


def test_the_crf_on_the_box_around_the_object_agrees_with_the_whole_frame():
    frame, prob, truth = _small_object_scene()
    params = dict(gaussian_sxy=3.0, bilateral_sxy=6.0)  # a bilateral width small against the frame
    whole = densecrf_mask(frame, prob, **params)
    boxed = densecrf_mask(frame, prob, crop_margin=3.0, **params)
    assert boxed.shape == truth.shape and boxed.dtype == np.uint8
    assert _iou(whole, truth) > 0.85
    assert np.mean(boxed != whole) < 0.002  # at most a few boundary pixels differ
    assert boxed[:, :100].sum() == 0  # outside the box (columns < 120 - 18): background
    # a margin of 0 is the box of the pixels above 0.5 itself: still the object
    assert _iou(densecrf_mask(frame, prob, crop_margin=0.0, **params), truth) > 0.8


def test_the_boxed_crf_of_a_map_with_nothing_above_one_half_is_background_as_the_crf_says():
    frame, prob, _ = _small_object_scene()
    low = np.clip(prob, 0.0, 0.45)  # not normalised (min-max normalising would stretch it back to 1)
    assert densecrf_mask(frame, low, normalise=False).sum() == 0
    assert densecrf_mask(frame, low, normalise=False, crop_margin=3.0).sum() == 0


def test_the_helper_process_gives_the_same_masks_and_runs_elsewhere():
    """pydensecrf holds the GIL, so the refiner runs it in a helper process: same masks bit for bit."""
    import os

    from eponet.plugins.refiner import densecrf

    frames, probs = zip(*[_scene(seed)[:2] for seed in range(3)])
    frames, probs = np.stack(frames), np.stack(probs)
    probs[2] = 0.2  # nothing above 0.5: cropped away, no CRF
    params = {"max_size": 100, "crop_margin": 1.0}
    inline = DenseCrfRefiner(helper_process=False, **params).refine(frames, probs)
    helped = DenseCrfRefiner(**params).refine(frames, probs)
    np.testing.assert_array_equal(helped, inline)
    assert inline[:2].sum() > 0 and inline[2].sum() == 0
    helper = densecrf._helper()
    assert helper.process.poll() is None and helper.process.pid != os.getpid()


def test_an_error_in_the_helper_process_is_raised_here():
    from eponet.plugins.refiner import densecrf

    with pytest.raises(RuntimeError, match="Error"):
        densecrf._helper().margin((np.zeros((4, 4, 3), np.uint8), np.zeros((5, 5), np.float32), 5, 3.0, 3.0, 50.0,
                                   10.0, 5.0))
    frame, prob, truth = _scene()
    assert _iou(DenseCrfRefiner().refine(frame[None], prob[None])[0], truth) > 0.9  # and it goes on


def test_the_helper_process_ends_quietly_when_its_parent_goes_mid_request():
    """The parent ends (killed) with a request in flight or cut off: the helper ends with status 0 and prints no
    traceback into the run's stderr."""
    import os
    import pickle
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")]))}
    command = [sys.executable, "-m", "eponet.plugins.refiner._crf_helper"]
    frame, prob, _ = _scene()
    request = pickle.dumps((frame, prob, 5, 3.0, 3.0, 50.0, 10.0, 5.0), protocol=pickle.HIGHEST_PROTOCOL)
    answered_to_nobody = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                          stderr=subprocess.PIPE, env=env)
    answered_to_nobody.stdout.close()  # nobody reads the answer any more
    answered_to_nobody.stdin.write(request)
    answered_to_nobody.stdin.close()
    assert answered_to_nobody.wait(timeout=60) == 0 and answered_to_nobody.stderr.read() == b""
    cut_off = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                               env=env)
    cut_off.stdin.write(request[: len(request) // 2])
    cut_off.stdin.close()
    assert cut_off.wait(timeout=60) == 0 and cut_off.stderr.read() == b""


def test_without_a_helper_process_the_crf_runs_here_with_a_warning(monkeypatch, caplog):
    from eponet.plugins.refiner import densecrf

    def no_helper():
        raise OSError("no processes here")

    monkeypatch.setattr(densecrf, "_helper", no_helper)
    frame, prob, truth = _scene()
    refiner = DenseCrfRefiner()
    assert _iou(refiner.refine(frame[None], prob[None])[0], truth) > 0.9
    assert "densecrf: no helper process (no processes here)" in caplog.text and refiner.helper_process is False
