"""A two-label dense CRF whose bilateral kernel is filtered on a sparse bilateral grid, in numpy.

The model is Krähenbühl & Koltun's fully connected CRF (NIPS 2011) as pydensecrf runs it for the EpO-Net masks:
unary ``-log p``, a Gaussian kernel on position (``gaussian_sxy`` px) and a bilateral kernel on position and
colour (``bilateral_sxy`` px, ``bilateral_srgb`` in 0-255 units), both normalised symmetrically
(``D^-1/2 K D^-1/2``), Potts compatibilities, mean-field updates. Only the filtering differs: pydensecrf
splats onto a permutohedral lattice (Adams et al., Eurographics 2010) in C++; here

- the Gaussian kernel is a separable Gaussian blur of the image (OpenCV);
- the bilateral kernel is a bilateral grid (Chen, Paris & Durand, SIGGRAPH 2007) in the 5-D space
  ``(x / sxy, y / sxy, r / srgb, g / srgb, b / srgb)``: every pixel falls into one cell of side :data:`CELL`
  standard deviations, only the occupied cells are stored (a sorted key per cell), the grid is blurred with
  ``[1, 2, 1] / 4`` along each of the five axes (neighbours found once by binary search), and each pixel reads
  its cell back. Nearest-cell splatting and slicing each add a box of one cell to the blur, so the kernel's
  standard deviation is ``CELL * sqrt(1/2 + 2/12)``, 1 for the default cell.

With two labels only the foreground's marginal is filtered (the background's is the filtered constant minus it),
and a natural image at 427x240 occupies a few thousand cells, so one iteration costs a few passes over the
pixels. The result approximates pydensecrf's (both filters are approximations of the same Gaussians): the
held-out J of both is in ``eponet/weights/epo-davis.md``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["CELL", "grid_crf_margin"]

#: Side of a bilateral grid cell in kernel standard deviations: the blur's variance (1/2 cell^2) plus nearest
#: splatting and slicing (1/12 cell^2 each) make a kernel of std 1 with cells of 1 / sqrt(2/3) = 1.22.
CELL = float(1.0 / np.sqrt(2.0 / 3.0))


class _BilateralGrid:
    """The occupied cells of one frame's 5-D grid: each pixel's cell and each cell's neighbours per axis."""

    def __init__(self, frame: np.ndarray, sxy: float, srgb: float, cell: float = CELL):
        height, width = frame.shape[:2]
        yy, xx = np.mgrid[:height, :width]
        coords = [xx / (sxy * cell), yy / (sxy * cell)] + [frame[..., c] / (srgb * cell) for c in range(3)]
        cells = [np.floor(c).astype(np.int64).reshape(-1) + 1 for c in coords]  # >= 1: room for the -1 neighbour
        extent = [int(c.max()) + 2 for c in cells]
        if np.prod(np.array(extent, float)) >= 2.0 ** 62:  # one int64 key per cell would overflow
            raise ValueError(f"densecrf backend grid: a {' x '.join(map(str, extent))} grid has too many cells to "
                             f"index (bilateral_sxy {sxy}, bilateral_srgb {srgb}, grid_cell {cell}); use wider "
                             "kernels, a larger grid_cell or backend pydensecrf")
        strides = np.cumprod([1] + extent[:-1])
        keys = sum(c * s for c, s in zip(cells, strides))
        self.keys, self.cell_of = np.unique(keys, return_inverse=True)
        self.cell_of = self.cell_of.reshape(-1)
        self.neighbours = []
        for stride in strides:
            pair = []
            for step in (-stride, stride):
                wanted = self.keys + step
                at = np.minimum(np.searchsorted(self.keys, wanted), len(self.keys) - 1)
                pair.append(np.where(self.keys[at] == wanted, at, len(self.keys)))  # len: an empty cell (0)
            self.neighbours.append(pair)

    def filter(self, values: np.ndarray) -> np.ndarray:
        """Sum over the grid's Gaussian of ``values`` float ``(N,)`` (one per pixel), read back per pixel."""
        grid = np.bincount(self.cell_of, weights=values, minlength=len(self.keys) + 1)
        grid[-1] = 0.0
        for below, above in self.neighbours:
            blurred = 0.5 * grid
            blurred[:-1] += 0.25 * (grid[below] + grid[above])
            blurred[-1] = 0.0
            grid = blurred
        return grid[self.cell_of]


def grid_crf_margin(frame: np.ndarray, p: np.ndarray, iterations: int, gaussian_sxy: float, gaussian_compat: float,
                    bilateral_sxy: float, bilateral_srgb: float, bilateral_compat: float,
                    cell: float = CELL) -> np.ndarray:
    """Q(fg) - Q(bg) float32 ``(H, W)`` after ``iterations`` mean-field updates of the dense CRF on ``frame``
    uint8 ``(H, W, 3)`` and P(fg) ``p`` float ``(H, W)`` (clipped to [1e-5, 1] as pydensecrf's unary is); the
    arguments of pydensecrf's ``_crf_margin`` in ``densecrf.py``, which this function replaces."""
    import cv2

    height, width = p.shape
    p = np.clip(p.astype(np.float32), 1e-5, 1.0)
    unary = np.log(p) - np.log(np.clip(1.0 - p, 1e-5, 1.0))  # -U(fg) + U(bg), float32 (H, W)

    def gaussian(image):
        return cv2.GaussianBlur(image, (0, 0), gaussian_sxy, borderType=cv2.BORDER_CONSTANT)

    grid = _BilateralGrid(frame.astype(np.float32), bilateral_sxy, bilateral_srgb, cell)
    g_norm = 1.0 / np.sqrt(gaussian(np.ones((height, width), np.float32)) + 1e-20)
    b_norm = (1.0 / np.sqrt(grid.filter(np.ones(height * width)) + 1e-20)).astype(np.float32).reshape(height, width)
    # With Q(bg) = 1 - Q(fg) the Potts messages' difference is K(Q(fg)) - K(Q(bg)) = 2 K(Q(fg)) - K(1): only
    # Q(fg) is filtered; the constant part joins the unary
    g_one = g_norm * gaussian(g_norm)
    b_one = b_norm * grid.filter(b_norm.reshape(-1)).astype(np.float32).reshape(height, width)
    base = unary - gaussian_compat * g_one - bilateral_compat * b_one
    g_weight, b_weight = np.float32(2.0 * gaussian_compat) * g_norm, np.float32(2.0 * bilateral_compat) * b_norm
    margin = unary
    for _ in range(iterations):
        q = 1.0 / (1.0 + np.exp(-margin))  # Q(fg): the softmax of the two labels' scores
        g = gaussian(g_norm * q)
        b = grid.filter((b_norm * q).reshape(-1)).astype(np.float32).reshape(height, width)
        margin = base + g_weight * g + b_weight * b
    return np.tanh(0.5 * margin)  # Q(fg) - Q(bg) = 2 sigmoid(margin) - 1
