"""Objects pasted over real background clips (the paper's RBSF, on annotated videos): exact ground truth."""

import numpy as np
import pytest

from eponet.core.errors import InputError
from eponet.synth.paste import PasteSettings, _reflect, object_sprites, paste_clip, paste_path, write_pasted


def _square_sequence(frames=6, size=(64, 48), side=10, colour=(250, 10, 10)):
    """A sequence whose object is a ``side`` x ``side`` square of one colour moving right over a grey frame."""
    W, H = size
    rgb = np.full((frames, H, W, 3), 60, np.uint8)
    masks = np.zeros((frames, H, W), np.uint8)
    for t in range(frames):
        rgb[t, 5:5 + side, 5 + t:5 + t + side] = colour
        masks[t, 5:5 + side, 5 + t:5 + t + side] = 1
    return rgb, masks


def test_a_sprite_is_the_object_cropped_to_its_box_with_its_centroid():
    rgb, masks = _square_sequence(frames=2)
    masks[1] = 0  # no object in the second frame
    first, empty = object_sprites(rgb, masks)
    assert first.alpha.shape == (10, 10) and first.area == 100
    assert (first.rgb == (250, 10, 10)).all()
    assert first.anchor == pytest.approx((4.5, 4.5))
    assert empty.area == 0


def test_the_path_bounces_inside_the_frame_at_the_drawn_speed():
    assert _reflect(np.array([-3.0, 0.0, 5.0, 10.0, 13.0, 25.0]), 10.0).tolist() == [3.0, 0.0, 5.0, 10.0, 7.0, 5.0]
    settings = PasteSettings(speed=(2.0, 2.0), acceleration=0.0, scale_rate=0.0)
    anchor, scale = paste_path(np.random.default_rng(0), 200, (64, 48), settings)
    assert (anchor >= 0).all() and (anchor[:, 0] <= 63).all() and (anchor[:, 1] <= 47).all()
    step = np.linalg.norm(np.diff(anchor, axis=0), axis=1)
    assert np.median(step) == pytest.approx(2.0)  # away from the borders, 2 px per frame
    assert (step <= 2.0 + 1e-9).all()
    assert scale.tolist() == [1.0] * 200


def test_a_pasted_clip_keeps_the_background_object_and_adds_the_pasted_one():
    W, H, F = 96, 64, 8
    background = np.zeros((F, H, W, 3), np.uint8)
    own = np.zeros((F, H, W), np.uint8)
    own[:, 40:60, 70:90] = 1  # the background's own object, bottom right
    rgb, masks = _square_sequence(frames=F, side=12)
    settings = PasteSettings(object_area=(0.05, 0.05), speed=(1.0, 1.0), acceleration=0.0, scale_rate=0.0)
    frames, truth = paste_clip(np.random.default_rng(3), background, own, object_sprites(rgb, masks), settings)
    assert frames.shape == background.shape and truth.shape == own.shape and set(np.unique(truth)) <= {0, 1}
    pasted = (frames[..., 0] > 127)  # the red square over black
    assert ((truth == 1) == (pasted | (own == 1))).mean() > 0.99  # the truth is the union of both objects
    # its area is the drawn 5% of the frame, up to the soft edge and the part the background's object covers
    area = pasted.reshape(F, -1).sum(1) / (H * W)
    assert area == pytest.approx(np.full(F, 0.05), abs=0.008)
    # where alpha is 1 the pasted pixels are the sprite's, elsewhere the background's own
    assert (frames[pasted & (own == 0)][:, 0] >= 200).mean() > 0.8
    assert (frames[~pasted] <= 130).all()
    with pytest.raises(ValueError, match="empty in every frame"):
        paste_clip(np.random.default_rng(0), background, own, object_sprites(rgb, np.zeros_like(masks)))


def test_written_clips_are_deterministic_and_draw_from_the_given_sequences(tmp_path):
    sequences = {name: _square_sequence(frames=n, colour=c)
                 for name, n, c in (("a", 6, (250, 0, 0)), ("b", 9, (0, 250, 0)), ("c", 4, (0, 0, 250)))}
    loads = []

    def load(name):
        loads.append(name)
        return sequences[name]

    entries = write_pasted(tmp_path / "one", ["a", "b", "c"], load, clips=3, frames=8, seed=5)
    write_pasted(tmp_path / "two", ["a", "b", "c"], load, clips=2, frames=8, seed=5)
    for e in entries:
        assert e["background"] != e["object"] and {e["background"], e["object"]} <= {"a", "b", "c"}
        assert e["num_frames"] == 8
    for clip in ("paste-0000", "paste-0001"):  # clip i depends on the seed and i only
        for t in (0, 7):
            for folder, suffix in (("JPEGImages", "jpg"), ("Annotations", "png")):
                path = f"{folder}/48p/{clip}/{t:05d}.{suffix}"
                assert (tmp_path / "one" / path).read_bytes() == (tmp_path / "two" / path).read_bytes()
    assert (tmp_path / "one" / "ImageSets" / "train.txt").read_text().split() == ["paste-0000", "paste-0001",
                                                                                 "paste-0002"]
    with pytest.raises(ValueError, match="at least two sequences"):
        write_pasted(tmp_path / "three", ["a"], load, clips=1, frames=8, seed=0)
    sequences["d"] = (sequences["a"][0], np.zeros_like(sequences["a"][1]))  # never annotated
    with pytest.raises(InputError, match="d: no annotated object in 20 windows of 8 frames"):
        write_pasted(tmp_path / "four", ["a", "d"], load, clips=4, frames=8, seed=0)
    sequences["e"] = tuple(x[:, :40] for x in sequences["a"])
    with pytest.raises(InputError, match="pasting needs sequences of one size, got 64x48 and 64x40|64x40 and 64x48"):
        write_pasted(tmp_path / "five", ["a", "e"], load, clips=1, frames=8, seed=0)
