"""The bilateral-grid CRF (``backend: grid``): its kernel's width, its mean field, and agreement with pydensecrf."""

import numpy as np
import pytest

from eponet.plugins.refiner.densecrf import DenseCrfRefiner, densecrf_mask
from eponet.plugins.refiner.gridcrf import CELL, _BilateralGrid, grid_crf_margin
from tests.plugins.refiner.test_refiners import _iou, _scene


def _step_width(profile: np.ndarray) -> float:
    """Half the distance between the 84% and 16% points of a falling step response: a Gaussian's std."""
    return (np.argmax(profile < 0.1587) - np.argmax(profile < 0.8413)) / 2.0


@pytest.mark.parametrize("cell", [0.5, CELL])
def test_grid_kernel_is_a_gaussian_of_the_designed_width(cell):
    """On a uniform image, the symmetric-normalised grid kernel applied to a step is the Gaussian's CDF: its
    16-84% width is the kernel's std, cell * sqrt(2/3) standard deviations (blur plus nearest splat and slice),
    up to the grid's quantisation (one cell)."""
    sxy, height, width = 8.0, 60, 400
    frame = np.full((height, width, 3), 128.0, np.float32)
    grid = _BilateralGrid(frame, sxy, 1000.0, cell)
    step = np.zeros((height, width))
    step[:, : width // 2] = 1.0
    norm = 1.0 / np.sqrt(grid.filter(np.ones(height * width)))
    response = (norm * grid.filter(norm * step.reshape(-1))).reshape(height, width)[height // 2]
    designed = cell * np.sqrt(2.0 / 3.0) * sxy
    # averaged over the step's position within a cell, the width is the designed one
    widths = []
    for shift in range(int(cell * sxy)):
        shifted = np.zeros((height, width))
        shifted[:, : width // 2 + shift] = 1.0
        r = (norm * grid.filter(norm * shifted.reshape(-1))).reshape(height, width)[height // 2]
        widths.append(_step_width(r[width // 4: 3 * width // 4]))
    assert np.mean(widths) == pytest.approx(designed, abs=0.25 * cell * sxy)
    # five widths from the step and from the image's sides (where the normalisation sees fewer cells): 1 and 0
    far = int(5 * designed)
    assert response[far: width // 2 - far].min() > 0.99 and response[width // 2 + far: width - far].max() < 0.01


def test_grid_kernel_does_not_cross_colour_edges():
    """Two halves of different colours (far beyond srgb): the bilateral kernel keeps each half's mass apart."""
    height, width = 40, 80
    frame = np.zeros((height, width, 3), np.float32)
    frame[:, width // 2:] = 200.0
    grid = _BilateralGrid(frame, 50.0, 5.0)
    left = np.zeros((height, width))
    left[:, : width // 2] = 1.0
    out = grid.filter(left.reshape(-1)).reshape(height, width)
    assert out[:, width // 2:].max() == 0.0 and out[:, : width // 2].min() > 0.0


def test_without_pairwise_terms_the_margin_is_the_unary():
    rng = np.random.default_rng(0)
    p = rng.uniform(0.0, 1.0, (30, 40)).astype(np.float32)
    frame = rng.integers(0, 255, (30, 40, 3), dtype=np.uint8)
    margin = grid_crf_margin(frame, p, 5, 3.0, 0.0, 50.0, 5.0, 0.0)
    np.testing.assert_array_equal(margin > 0, p > 0.5)
    np.testing.assert_allclose(margin, 2 * np.clip(p, 1e-5, 1 - 1e-5) - 1, atol=1e-5)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_grid_backend_cleans_a_noisy_probability_as_pydensecrf_does(seed):
    frame, prob, truth = _scene(seed)
    lattice = densecrf_mask(frame, prob)
    grid = densecrf_mask(frame, prob, backend="grid")
    assert grid.dtype == np.uint8 and set(np.unique(grid)) <= {0, 1}
    assert _iou(grid, truth) > 0.9 and _iou(grid, lattice) > 0.9
    assert _iou(grid, truth) > _iou(prob > 0.5, truth) + 0.1


def test_grid_refiner_runs_in_process_with_crop_and_cap():
    frame, prob, truth = _scene(1)
    refiner = DenseCrfRefiner(backend="grid", max_size=100, crop_margin=3.0, bilateral_srgb=5.0, bilateral_compat=8.0)
    masks = refiner.refine(np.stack([frame, frame]), np.stack([prob, np.full_like(prob, 0.2)]))
    assert masks.shape == (2,) + truth.shape
    assert _iou(masks[0], truth) > 0.88
    assert masks[1].sum() == 0


def test_a_grid_too_fine_to_index_is_a_clear_error():
    frame = np.random.default_rng(0).integers(0, 255, (200, 300, 3)).astype(np.float32)
    with pytest.raises(ValueError, match="too many cells"):
        _BilateralGrid(frame, 0.01, 0.01, 0.25)
