import numpy as np

from eponet.training.augment import InputDropout, apply_crop_flip, draw_crop_flip, random_crop_flip, shift_flow


def _batch(n=200):
    rng = np.random.default_rng(0)
    return rng.uniform(0.1, 1.0, (n, 3, 6, 8)).astype(np.float32)


def test_input_dropout_changes_only_the_ed_channel_of_chosen_samples():
    batch = _batch()
    dropout = InputDropout(probability=0.2, zero_epochs=2, then="noise", noise_std=0.05)
    out, chosen = dropout.apply(batch, epoch=0, rng=np.random.default_rng(1))
    assert 0.12 < chosen.mean() < 0.28
    np.testing.assert_array_equal(out[:, :2], batch[:, :2])  # flow untouched everywhere
    np.testing.assert_array_equal(out[~chosen], batch[~chosen])  # other samples untouched
    assert (out[chosen, 2] == 0).all()  # early epochs: zeros
    later, chosen = dropout.apply(batch, epoch=2, rng=np.random.default_rng(1))
    ed = later[chosen, 2]
    assert (ed >= 0).all() and 0 < ed.std() < 0.05 and ed.mean() < 0.05  # zeros plus small noise
    np.testing.assert_array_equal(batch[:, 2], _batch()[:, 2])  # the input is not modified in place


def test_input_dropout_random_mode_and_zero_probability():
    batch = _batch()
    out, chosen = InputDropout(probability=1.0, zero_epochs=0, then="random").apply(batch, 5, np.random.default_rng(2))
    assert chosen.all() and 0.45 < out[:, 2].mean() < 0.55 and out[:, 2].min() >= 0 and out[:, 2].max() <= 1
    out, chosen = InputDropout(probability=0.0).apply(batch, 0, np.random.default_rng(3))
    assert not chosen.any()
    np.testing.assert_array_equal(out, batch)


def test_flip_negates_horizontal_flow_and_mirrors_everything():
    images = np.random.default_rng(0).normal(size=(3, 4, 5)).astype(np.float32)
    mask = (np.arange(20).reshape(4, 5) % 3 == 0).astype(np.uint8)
    for seed in range(10):
        rng = np.random.default_rng(seed)
        out, m = random_crop_flip(images, mask, None, True, rng)
        if not np.array_equal(m, mask):
            np.testing.assert_array_equal(m, mask[:, ::-1])
            np.testing.assert_array_equal(out[0], -images[0, :, ::-1])
            np.testing.assert_array_equal(out[1:], images[1:, :, ::-1])
            return
    raise AssertionError("no flip in 10 draws")


def test_crop_keeps_images_and_mask_aligned():
    images = np.stack([np.arange(48.0).reshape(6, 8)] * 3).astype(np.float32)
    mask = np.arange(48).reshape(6, 8)
    out, m = random_crop_flip(images, mask, (4, 5), False, np.random.default_rng(4))
    assert out.shape == (3, 4, 5) and m.shape == (4, 5)
    np.testing.assert_array_equal(out[2], m.astype(np.float32))


def test_flow_shift_adds_one_constant_per_sample_to_dx_and_dy_only():
    batch = _batch(400)
    out = shift_flow(batch, 0.5, np.random.default_rng(5))
    np.testing.assert_array_equal(out[:, 2], batch[:, 2])  # ED untouched
    shift = out[:, :2] - batch[:, :2]
    np.testing.assert_allclose(shift, shift[:, :, :1, :1] * np.ones_like(shift), atol=1e-6)  # constant per map
    assert abs(shift[:, :, 0, 0].std() - 0.5) < 0.05 and abs(shift[:, :, 0, 0].mean()) < 0.06
    assert abs(np.corrcoef(shift[:, 0, 0, 0], shift[:, 1, 0, 0])[0, 1]) < 0.15  # dx and dy drawn independently
    np.testing.assert_array_equal(batch, _batch(400))  # not in place
    assert shift_flow(batch, 0.0, np.random.default_rng(5)) is batch


def _zoom_scene(height=60, width=90):
    """A camera's motion images with known geometry: dx grows linearly across the frame (0.01 per pixel, as a
    zoom or a rotation about the optical axis gives), dy is a constant 0.2, ED is 1 on a 20 x 30 object."""
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    mask = ((yy >= 20) & (yy < 40) & (xx >= 30) & (xx < 60)).astype(np.uint8)
    return np.stack([0.01 * xx, np.full_like(xx, 0.2), mask.astype(np.float32)]), mask


def test_zoom_magnifies_the_scene_and_its_flow_together():
    images, mask = _zoom_scene()
    for factor in (2.0, 0.8):
        box = draw_crop_flip(mask.shape, (40, 60), False, np.random.default_rng(0), (factor, factor))
        assert box.source == (round(40 / factor), round(60 / factor)) and (box.height, box.width) == (40, 60)
        out, m = apply_crop_flip(images, mask, box)
        assert out.shape == (3, 40, 60) and m.shape == (40, 60) and m.dtype == np.uint8
        # the window's object, magnified: its area times factor squared, and the ED channel still on it
        assert abs(m.sum() / (factor**2 * mask[box.y : box.y + box.source[0], box.x : box.x + box.source[1]].sum())
                   - 1) < 0.08
        assert np.mean(np.abs(out[2] - m)) < 0.03
        # flow scaled with the image: a constant flow times the factor, a linear field's gradient per output
        # pixel unchanged (u'(x') = factor * u(x' / factor))
        np.testing.assert_allclose(np.median(out[1]), 0.2 * box.width / box.source[1], rtol=1e-5)
        np.testing.assert_allclose(np.median(np.diff(out[0], axis=1)), 0.01, rtol=1e-3)


def test_zoom_draws_log_uniformly_within_the_frame_and_leaves_unzoomed_draws_as_they_were():
    shape = (240, 427)
    factors = []
    for seed in range(400):
        box = draw_crop_flip(shape, (160, 288), True, np.random.default_rng(seed), (0.7, 1.4))
        window = box.source or (box.height, box.width)
        assert box.y + window[0] <= shape[0] and box.x + window[1] <= shape[1]
        factors.append(box.width / window[1])
    factors = np.array(factors)
    assert factors.min() >= 288 / 427 - 0.01 and factors.max() <= 1.4 + 0.01
    assert abs(np.median(np.log(factors)) - np.log(np.sqrt(0.7 * 1.4))) < 0.06  # log-uniform: the geometric mean
    # a factor too small for the frame is raised to the largest window of the crop's shape that fits, so both
    # axes are magnified alike
    box = draw_crop_flip(shape, (160, 288), False, np.random.default_rng(0), (0.5, 0.5))
    assert box.source == (round(160 * 427 / 288), 427) and box.x == 0
    for seed in range(20):  # without a zoom, the same random numbers give the same boxes as before the option
        rng_a, rng_b = np.random.default_rng(seed), np.random.default_rng(seed)
        a = draw_crop_flip(shape, (160, 288), True, rng_a)
        b = draw_crop_flip(shape, (160, 288), True, rng_b, None)
        assert a == b and a.source is None and rng_a.random() == rng_b.random()
