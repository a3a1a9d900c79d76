import numpy as np
import pytest
import torch
import torch.nn.functional as F

from eponet.training.losses import segmentation_loss, soft_jaccard_loss


def test_soft_jaccard_is_one_minus_iou_on_saturated_logits():
    target = torch.zeros(2, 1, 4, 4)
    target[0, 0, :2] = 1  # 8 foreground pixels
    target[1, 0, :, :1] = 1  # 4 foreground pixels
    logits = torch.full_like(target, -50.0)
    logits[0, 0, :1] = 50.0  # predicts 4 of the 8: IoU 4/8
    logits[1, 0, :, :2] = 50.0  # predicts 8 covering the 4: IoU 4/8
    expected = np.mean([1 - (4 + 1) / (8 + 1), 1 - (4 + 1) / (8 + 1)])
    assert soft_jaccard_loss(logits, target).item() == pytest.approx(expected, abs=1e-6)
    assert soft_jaccard_loss(torch.where(target > 0, 50.0, -50.0), target).item() == pytest.approx(0.0, abs=1e-6)


def test_soft_jaccard_of_an_empty_frame_is_zero_when_nothing_is_predicted_and_scale_free():
    empty = torch.zeros(1, 1, 8, 8)
    assert soft_jaccard_loss(torch.full_like(empty, -50.0), empty).item() == pytest.approx(0.0, abs=1e-6)
    assert soft_jaccard_loss(torch.full_like(empty, 50.0), empty).item() == pytest.approx(64 / 65, abs=1e-6)
    # the same half-overlap on a 4x larger frame gives (nearly) the same loss
    small, big = torch.zeros(1, 1, 8, 8), torch.zeros(1, 1, 16, 16)
    small[..., :4, :] = 1
    big[..., :8, :] = 1
    a = soft_jaccard_loss(torch.zeros_like(small), small).item()
    b = soft_jaccard_loss(torch.zeros_like(big), big).item()
    assert a == pytest.approx(1 - 17 / 49) and b == pytest.approx(1 - 65 / 193) and abs(a - b) < 0.02


def test_segmentation_loss_adds_the_weighted_jaccard_term_to_bce_and_its_gradient_favours_the_object():
    torch.manual_seed(0)
    logits = torch.randn(3, 1, 6, 6, requires_grad=True)
    target = (torch.rand(3, 1, 6, 6) > 0.7).float()
    bce = F.binary_cross_entropy_with_logits(logits, target)
    assert segmentation_loss(logits, target, "bce").item() == pytest.approx(bce.item())
    combined = segmentation_loss(logits, target, "bce+iou", iou_weight=0.5)
    assert combined.item() == pytest.approx(bce.item() + 0.5 * soft_jaccard_loss(logits, target).item(), rel=1e-6)
    soft_jaccard_loss(logits, target).backward()
    grad = logits.grad
    assert (grad[target > 0] < 0).all() and (grad[target == 0] > 0).all()  # raise foreground, lower background
    with pytest.raises(ValueError, match="loss: expected one of bce, bce\\+iou, got 'dice'"):
        segmentation_loss(logits, target, "dice")
