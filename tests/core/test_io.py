import numpy as np
import pytest
from PIL import Image

from eponet.core.errors import InputError
from eponet.core.io import DAVIS_PALETTE, natural_key, read_flo, read_image, read_mask, write_flo, write_mask_png


def test_flo_round_trip_is_exact(tmp_path):
    flow = np.random.default_rng(0).normal(0, 5, (7, 11, 2)).astype(np.float32)
    write_flo(tmp_path / "a.flo", flow)
    raw = (tmp_path / "a.flo").read_bytes()
    assert np.frombuffer(raw[:4], "<f4")[0] == np.float32(202021.25)
    assert tuple(np.frombuffer(raw[4:12], "<i4")) == (11, 7)
    assert len(raw) == 12 + 7 * 11 * 8
    np.testing.assert_array_equal(read_flo(tmp_path / "a.flo"), flow)


def test_flo_reads_middlebury_ground_truth(shared_data):
    flow = read_flo(shared_data / "flow-gt" / "middlebury" / "RubberWhale" / "flow10.flo")
    assert flow.shape == (388, 584, 2)
    known = np.isfinite(flow).all(axis=2)
    assert 0.5 < known.mean() < 1.0  # occluded pixels carry the 'unknown' value
    assert np.abs(flow[known]).max() < 20


def test_flo_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.flo"
    bad.write_bytes(b"PIEH" + b"\0" * 20)
    with pytest.raises(InputError, match="bad.flo"):
        read_flo(bad)
    write_flo(tmp_path / "ok.flo", np.zeros((4, 5, 2), np.float32))
    with pytest.raises(InputError, match=r"ok.flo: flow is 5x4, expected 6x4"):
        read_flo(tmp_path / "ok.flo", expected_shape=(4, 6))
    (tmp_path / "short.flo").write_bytes((tmp_path / "ok.flo").read_bytes()[:-8])
    with pytest.raises(InputError, match="truncated"):
        read_flo(tmp_path / "short.flo")


def test_palette_png_round_trip(tmp_path):
    mask = np.zeros((9, 13), np.uint8)
    mask[2:6, 3:9] = 1
    write_mask_png(tmp_path / "m.png", mask)
    with Image.open(tmp_path / "m.png") as image:
        assert image.mode == "P"
        palette = np.array(image.getpalette()[:6]).reshape(2, 3)
        np.testing.assert_array_equal(np.asarray(image), mask)
    np.testing.assert_array_equal(palette, [[0, 0, 0], [128, 0, 0]])
    np.testing.assert_array_equal(read_mask(tmp_path / "m.png"), mask)


@pytest.mark.parametrize("flavour", ["grey255", "grey1", "rgb", "grey_alpha", "palette"])
def test_masks_of_every_flavour_read_as_binary(tmp_path, flavour):
    mask = np.zeros((6, 8), np.uint8)
    mask[1:4, 2:6] = 1
    path = tmp_path / f"{flavour}.png"
    if flavour == "grey255":
        Image.fromarray(mask * 255).save(path)
    elif flavour == "grey1":
        Image.fromarray(mask).save(path)
    elif flavour == "rgb":
        Image.fromarray(np.stack([mask * 200, mask * 10, mask * 0], axis=2)).save(path)
    elif flavour == "grey_alpha":
        Image.fromarray(np.stack([mask * 255, np.full_like(mask, 255)], axis=2), mode="LA").save(path)
    else:
        write_mask_png(path, mask)
    np.testing.assert_array_equal(read_mask(path), mask)


def test_davis_grey_alpha_annotation(shared_data):
    path = shared_data / "davis2016-train" / "DAVIS" / "Annotations" / "480p" / "bear" / "00077.png"
    with Image.open(path) as image:
        assert image.mode in ("L", "LA")  # grey (the original DAVIS file is grey with alpha)
    mask = read_mask(path)
    assert mask.shape == (480, 854) and set(np.unique(mask)) == {0, 1}
    assert 0.05 < mask.mean() < 0.5


def test_palette_matches_davis(shared_data):
    expected = np.loadtxt(shared_data / "davis2016-train" / "DAVIS" / "palette.txt", dtype=np.uint8)
    np.testing.assert_array_equal(DAVIS_PALETTE, expected)


def test_corrupt_image_names_the_file(tmp_path):
    (tmp_path / "x.jpg").write_bytes(b"\xff\xd8 not really a jpeg")
    with pytest.raises(InputError, match=r"x.jpg: cannot read image"):
        read_image(tmp_path / "x.jpg")


def test_natural_sort():
    names = ["frame10.png", "frame2.png", "frame1.png"]
    assert sorted(names, key=natural_key) == ["frame1.png", "frame2.png", "frame10.png"]
