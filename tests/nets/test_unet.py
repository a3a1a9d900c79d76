import pytest
import torch

from eponet.nets import EpoUNet


@pytest.mark.parametrize("inputs, channels", [("ed+flow", 3), ("flow", 2), ("ed", 1)])
@pytest.mark.parametrize("depth", [2, 3, 4])
def test_output_shape_at_odd_sizes(inputs, channels, depth):
    model = EpoUNet(inputs=inputs, depth=depth, widths=(4, 8, 8, 16), head_channels=8).eval()
    for height, width in [(37, 53), (232, 424), (17, 16)]:
        x = torch.randn(2, channels, height, width)
        with torch.no_grad():
            assert model(x).shape == (2, 1, height, width)


def test_select_inputs_picks_the_modality_channels():
    images = torch.arange(3.0).view(1, 3, 1, 1).expand(1, 3, 4, 4)
    assert EpoUNet(inputs="ed").select_inputs(images)[0, :, 0, 0].tolist() == [2.0]
    assert EpoUNet(inputs="flow").select_inputs(images)[0, :, 0, 0].tolist() == [0.0, 1.0]


def test_head_has_the_papers_128_channels():
    model = EpoUNet()
    assert model.classifier.in_channels == 128
    assert len(model.encoder) == 4 and len(model.decoder) == 4


def test_bad_configuration_is_a_clear_error():
    with pytest.raises(ValueError, match="inputs: expected one of"):
        EpoUNet(inputs="rgb")
    with pytest.raises(ValueError, match="widths: need at least 4 values"):
        EpoUNet(widths=(8, 16))
