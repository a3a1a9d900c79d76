import pytest
import torch

from eponet.nets import EpoUNet, InferenceUNet
from eponet.core.motion import FLOW_SCALE, mirror_motion_images
from eponet.nets.unet import HEAD_BLOCK, flow_spread


@pytest.mark.parametrize("inputs, channels", [("ed+flow", 3), ("flow", 2), ("ed", 1)])
@pytest.mark.parametrize("depth", [2, 3, 4])
def test_output_shape_at_odd_sizes(inputs, channels, depth):
    model = EpoUNet(inputs=inputs, depth=depth, widths=(4, 8, 8, 16), head_channels=8).eval()
    for height, width in [(37, 53), (232, 424), (17, 16)]:
        x = torch.randn(2, channels, height, width)
        with torch.no_grad():
            assert model(x).shape == (2, 1, height, width)


def test_select_inputs_picks_the_modality_channels():
    images = torch.tensor([3.0, -2.0, 0.5]).view(1, 3, 1, 1).expand(1, 3, 4, 4)
    assert EpoUNet(inputs="ed").select_inputs(images)[0, :, 0, 0].tolist() == [0.5]
    assert EpoUNet(inputs="flow").select_inputs(images)[0, :, 0, 0].tolist() == [3.0, -2.0]
    assert EpoUNet(inputs="ed+flow").select_inputs(images)[0, :, 0, 0].tolist() == [3.0, -2.0, 0.5]


@pytest.mark.parametrize("inputs", ["ed+flow", "ed"])
def test_ed_encoding_saturates_only_the_ed_channel(inputs):
    ed = torch.tensor([0.0, 0.25, 1.0, 2.0, 20.0])
    images = torch.stack([torch.full((5,), 7.0), torch.full((5,), -3.0), ed]).view(1, 3, 1, 5)
    before = images.clone()
    clip = EpoUNet(inputs=inputs).select_inputs(images)
    log = EpoUNet(inputs=inputs, ed_encoding="log").select_inputs(images)
    assert torch.equal(images, before)  # the caller's motion images are not touched
    # the paper's encoding clips at 1; log is the identity up to 1 and 1 + ln(ED) above (1 + ln 20 = 3.996)
    assert clip[0, -1, 0].tolist() == [0.0, 0.25, 1.0, 1.0, 1.0]
    assert log[0, -1, 0].tolist() == pytest.approx([0.0, 0.25, 1.0, 1.6931472, 3.9957323])
    if inputs == "ed+flow":  # flow passes through unchanged
        assert log[0, :2].tolist() == clip[0, :2].tolist() == [[[7.0] * 5], [[-3.0] * 5]]
    assert EpoUNet(ed_encoding="log").config["ed_encoding"] == "log"


def test_rigid_flow_centring_removes_the_flow_of_the_low_ed_part_of_each_frame():
    # frame 0: a camera pan of (3, -1) px/20 over the background (ED 0.1-0.3), an object at rest in the image (a
    # camera following it, ED 2.0) on 30% of the frame; frame 1: the same with a zeroed ED channel
    images = torch.zeros(2, 3, 10, 10)
    images[:, 0], images[:, 1] = 3.0, -1.0
    images[:, :2, :3] = 0.0
    images[0, 2] = torch.linspace(0.1, 0.3, 100).view(10, 10)
    images[0, 2, :3] = 2.0
    before = images.clone()
    x = EpoUNet(flow_centring="rigid").select_inputs(images)
    assert torch.equal(images, before)
    assert x[0, :2, 3:].abs().max() == 0 and x[0, :2, :3].flatten(1).tolist() == [[-3.0] * 30, [1.0] * 30]
    assert torch.equal(x[:, 2], EpoUNet().select_inputs(images)[:, 2])  # ED as without the centring
    assert x[1, :2, 3:].abs().max() == 0  # without ED: the frame's median flow, the background's here
    # a constant pan added to a frame does not change what the network reads
    shifted = images.clone()
    shifted[:, 0] += 5.0
    assert torch.allclose(EpoUNet(flow_centring="rigid").select_inputs(shifted), x)
    assert EpoUNet().select_inputs(images)[:, :2].equal(images[:, :2])  # the paper's: unchanged
    with pytest.raises(ValueError, match="flow_centring: expected one of none, rigid, affine"):
        EpoUNet(flow_centring="mean")


def test_affine_flow_centring_removes_a_zoom_and_roll_of_the_camera_but_keeps_the_objects_motion():
    # a camera that zooms, rolls and pans over a rigid scene moves pixel (x, y) in [-1, 1]^2 by an affine field;
    # an object on 20% of the frame (high ED) moves by (4, 2) relative to it; 10% of the scene's pixels are near
    # rigid objects with parallax (ED at the median, flow off the field by 6 px): the trimmed refit drops them
    h, w = 20, 30
    gy, gx = torch.meshgrid(torch.linspace(-1, 1, h), torch.linspace(-1, 1, w), indexing="ij")
    field = torch.stack([0.8 * gx - 0.3 * gy + 2.0, 0.3 * gx + 0.8 * gy - 1.0])
    images = torch.zeros(1, 3, h, w)
    images[0, :2] = field
    images[0, 2] = 0.1 + 0.01 * torch.rand(h, w, generator=torch.Generator().manual_seed(0))
    images[0, :2, :4] += torch.tensor([4.0, 2.0])[:, None, None]  # the object: rows 0-3
    images[0, 2, :4] = 3.0
    images[0, 0, 10:12] += 6.0  # parallax of a near rigid object, rows 10-11, low ED
    images[0, 2, 10:12] = 0.05
    x = EpoUNet(flow_centring="affine").select_inputs(images)
    residual = x[0, :2]
    assert residual[:, 4:10].abs().max() < 1e-4 and residual[:, 12:].abs().max() < 1e-4  # the scene: zero
    assert torch.allclose(residual[:, :4].mean(dim=(1, 2)), torch.tensor([4.0, 2.0]), atol=1e-4)
    assert torch.allclose(residual[0, 10:12], torch.full((2, w), 6.0), atol=1e-4)
    assert torch.equal(x[:, 2], EpoUNet().select_inputs(images)[:, 2])  # ED as without the centring
    # the translation-only centring cannot remove the zoom and roll: the scene keeps up to 1.1 px of flow
    assert EpoUNet(flow_centring="rigid").select_inputs(images)[0, :2, 12:].abs().max() > 1.0
    # without ED (a zeroed channel) the fit is over the whole frame and still removes a pure affine field
    flat = torch.zeros(1, 3, h, w)
    flat[0, :2] = field
    assert EpoUNet(flow_centring="affine").select_inputs(flat)[0, :2].abs().max() < 1e-4
    assert InferenceUNet(EpoUNet(flow_centring="affine")).select_inputs(images).equal(x)


def test_flow_spread_is_the_local_std_of_the_flow_in_pixels_zero_where_it_moves_as_one_piece():
    # a smooth pan (dx 3 px) with a 12 x 12 patch of chaotic flow (water); ED random
    generator = torch.Generator().manual_seed(0)
    images = torch.zeros(2, 3, 40, 48)
    images[:, 0] = 3.0 / FLOW_SCALE
    images[:, :2, 10:22, 20:32] = torch.randn(2, 2, 12, 12, generator=generator) * 4.0 / FLOW_SCALE
    images[:, 2] = torch.rand(2, 40, 48, generator=generator)
    spread = flow_spread(images, 5)
    assert spread.shape == (2, 1, 40, 48)
    assert spread[:, 0, 30:, :].abs().max() < 1e-4  # a constant flow, however fast, has none
    patch = images[0, :2, 12:17, 22:27] * FLOW_SCALE  # a window wholly inside the patch: its std, exactly
    expected = torch.log1p(patch.flatten(1).var(dim=1, unbiased=False).sum().sqrt())
    assert spread[0, 0, 14, 24].item() == pytest.approx(expected.item(), rel=1e-4)
    assert spread[:, 0, 12:20, 22:30].min() > 1.0  # ln(1 + ~5.6 px)
    shifted = images.clone()
    shifted[:, :2] += torch.tensor([0.7, -0.3]).view(1, 2, 1, 1)  # another pan: the same spread
    assert torch.allclose(flow_spread(shifted, 5), spread, atol=1e-4)
    mirrored = torch.from_numpy(mirror_motion_images(images.numpy()))
    assert torch.allclose(flow_spread(mirrored, 5), spread.flip(-1), atol=1e-5)


def test_a_network_with_flow_spread_reads_it_as_a_last_channel_of_the_uncentred_flow():
    images = torch.randn(2, 3, 24, 32)
    model = EpoUNet(flow_centring="rigid", flow_spread=7, depth=2, widths=(4, 8), head_channels=8).eval()
    x = model.select_inputs(images)
    assert model.input_channels == 4 and x.shape == (2, 4, 24, 32) and model.config["flow_spread"] == 7
    assert torch.equal(x[:, :3], EpoUNet(flow_centring="rigid").select_inputs(images))
    assert torch.equal(x[:, 3:], flow_spread(images, 7))
    assert EpoUNet(inputs="ed", flow_spread=3).select_inputs(images).shape[1] == 2
    with torch.no_grad():
        assert model(x).shape == (2, 1, 24, 32)
        assert torch.allclose(InferenceUNet(model)(InferenceUNet(model).select_inputs(images)), model(x), atol=1e-4)
    for bad in (1, 4):
        with pytest.raises(ValueError, match="flow_spread: expected 0 \\(off\\) or an odd window"):
            EpoUNet(flow_spread=bad)


def test_head_has_the_papers_128_channels():
    model = EpoUNet()
    assert model.classifier.in_channels == 128
    assert len(model.encoder) == 4 and len(model.decoder) == 4


def test_bad_configuration_is_a_clear_error():
    with pytest.raises(ValueError, match="inputs: expected one of"):
        EpoUNet(inputs="rgb")
    with pytest.raises(ValueError, match="widths: need at least 4 values"):
        EpoUNet(widths=(8, 16))
    with pytest.raises(ValueError, match="ed_encoding: expected one of clip, log"):
        EpoUNet(ed_encoding="sqrt")


def _trained_like(model: EpoUNet) -> EpoUNet:
    """``model`` with BatchNorm affine parameters and running statistics far from their initial values (a
    folded BatchNorm that ignored any of them would show)."""
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        for module in model.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                c = module.num_features
                module.weight.copy_(torch.rand(c, generator=generator) * 2 + 0.2)
                module.bias.copy_(torch.randn(c, generator=generator))
                module.running_mean.copy_(torch.randn(c, generator=generator))
                module.running_var.copy_(torch.rand(c, generator=generator) * 3 + 0.1)
        model.classifier.weight.normal_(0.0, 1.0, generator=generator)  # (initialised at 0.01: a flat output)
        model.classifier.bias.fill_(0.3)
    return model.eval()


@pytest.mark.parametrize("depth, size, channels_last", [(2, (37, 53), True), (4, (60, 107), True), (3, (41, 70), False)])
def test_the_inference_network_computes_what_the_network_computes_in_eval_mode(depth, size, channels_last):
    torch.manual_seed(1)
    model = _trained_like(EpoUNet(depth=depth, widths=(4, 8, 8, 16), head_channels=8, ed_encoding="log"))
    fast = InferenceUNet(model)
    x = torch.randn(3, 3, *size) * 2
    with torch.inference_mode():
        expected = model(model.select_inputs(x))
        inputs = fast.select_inputs(x).contiguous(memory_format=torch.channels_last if channels_last else
                                                  torch.contiguous_format)
        got = fast(inputs)
    assert got.shape == expected.shape == (3, 1, *size) and 3 * size[0] * size[1] > HEAD_BLOCK  # several head blocks
    assert float((got - expected).abs().max()) < 1e-4 * float(expected.abs().max())
    assert float(expected.std()) > 0.1  # not a trivially constant output
    assert fast.config == model.config and not any(p.requires_grad for p in fast.parameters())
    with torch.no_grad():  # a copy: the network it came from may change afterwards
        model.classifier.bias.add_(5.0)
        assert torch.equal(fast(inputs), got)
