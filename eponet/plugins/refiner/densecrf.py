"""Refiner ``densecrf``: fully connected CRF (Kraehenbuehl & Koltun, NIPS 2011) as in the EpO-Net code."""

from __future__ import annotations

import atexit
import inspect
import logging
import os
import pickle
import subprocess
import sys
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.params import Param
from eponet.core.progress import track
from eponet.plugins.refiner.gridcrf import CELL, grid_crf_margin

__all__ = ["DenseCrfRefiner", "densecrf_mask"]

log = logging.getLogger(__name__)


def densecrf_mask(
    frame: np.ndarray,
    probability: np.ndarray,
    *,
    iterations: int = 5,
    gaussian_sxy: float = 3.0,
    gaussian_compat: float = 3.0,
    bilateral_sxy: float = 50.0,
    bilateral_srgb: float = 10.0,
    bilateral_compat: float = 5.0,
    normalise: bool = True,
    scale: float = 1.0,
    max_size: int | None = None,
    crop_margin: float | None = None,
    backend: str = "pydensecrf",
    grid_cell: float = CELL,
) -> np.ndarray:
    """Binary mask uint8 ``(H, W)`` from an RGB ``frame`` uint8 ``(H, W, 3)`` and P(fg) float ``(H, W)``.

    As in the authors' ``crf_motion.py``: the probability is min-max normalised per frame (``normalise``),
    unary = -log(p) with p clipped at 1e-5, a Gaussian kernel (sxy 3, compat 3) and a bilateral kernel
    (sxy 50, srgb 10, compat 5), both DIAG_KERNEL / NORMALIZE_SYMMETRIC, 5 mean-field iterations, argmax.
    A constant probability map (max = min, where the original divides by zero) is used as it is.

    With ``scale < 1`` the CRF runs on a downscaled frame (spatial standard deviations scaled alike) and the
    marginals are upsampled bilinearly before the argmax: about 1/scale^2 times faster, slightly softer
    boundaries. ``max_size`` (px) caps the longer side the CRF runs at, so its cost per frame stays bounded
    whatever the input size: the effective scale is ``min(scale, max_size / max(H, W))``.

    ``crop_margin`` (in bilateral widths ``bilateral_sxy``): run the CRF only on the bounding box of the pixels
    whose (normalised) probability is above 0.5, grown by that margin on every side, and call every pixel outside
    it background; no pixel above 0.5: all background, as the CRF itself answers then (its Potts terms only pull
    labels together, so no pixel can leave the label its unary prefers when all prefer one). The bilateral
    kernel's weight at 3 widths is exp(-4.5) = 0.011, so a margin of 3 changes few pixels, and the cost falls
    with the box's area. ``None``: the whole frame, as the original code.

    ``backend``: ``pydensecrf`` (the permutohedral lattice, as the original code) or ``grid``, the same model with
    its bilateral kernel filtered on a sparse bilateral grid of cells of ``grid_cell`` standard deviations in
    numpy (:mod:`eponet.plugins.refiner.gridcrf`: several times faster, not the same masks).
    """
    job = _crf_job(frame, probability, iterations=iterations, gaussian_sxy=gaussian_sxy,
                   gaussian_compat=gaussian_compat, bilateral_sxy=bilateral_sxy, bilateral_srgb=bilateral_srgb,
                   bilateral_compat=bilateral_compat, normalise=normalise, scale=scale, max_size=max_size,
                   crop_margin=crop_margin)
    return _crf_mask(job, _margin_here(job, backend, grid_cell))


#: densecrf_mask's keyword arguments and their defaults (those of the CRF's preparation, :func:`_crf_job`)
_DEFAULTS = {name: parameter.default for name, parameter in inspect.signature(densecrf_mask).parameters.items()
             if parameter.kind is inspect.Parameter.KEYWORD_ONLY and name not in ("backend", "grid_cell")}


def _margin_here(job: "_CrfJob", backend: str, grid_cell: float) -> np.ndarray | None:
    """The CRF's margin on the job's box, computed in this process by ``backend`` (None: nothing to refine)."""
    if not job.args:
        return None
    return _crf_margin(*job.args) if backend == "pydensecrf" else grid_crf_margin(*job.args, grid_cell)


@dataclass
class _CrfJob:
    """One frame's CRF as :func:`densecrf_mask` prepares it: ``args`` of :func:`_crf_margin` (None: nothing
    above 0.5 in a crop, all background), the box it covers in the (resized) frame, the resized frame's size and the
    input's."""

    args: tuple | None
    box: tuple
    shape: tuple[int, int]
    full_size: tuple[int, int]


def _crf_job(frame, probability, *, iterations, gaussian_sxy, gaussian_compat, bilateral_sxy, bilateral_srgb,
             bilateral_compat, normalise, scale, max_size, crop_margin) -> _CrfJob:
    p = probability.astype(np.float32)
    if normalise:
        lo, hi = float(p.min()), float(p.max())
        if hi > lo:
            p = (p - lo) / (hi - lo)
    p = np.clip(p, 0.0, 1.0)
    full_size = p.shape
    if max_size is not None:
        scale = min(scale, max_size / max(full_size))
    if scale < 1.0:
        import cv2

        small = (max(8, int(round(full_size[1] * scale))), max(8, int(round(full_size[0] * scale))))
        frame = cv2.resize(frame, small, interpolation=cv2.INTER_AREA)
        p = cv2.resize(p, small, interpolation=cv2.INTER_LINEAR)
        gaussian_sxy, bilateral_sxy = gaussian_sxy * scale, bilateral_sxy * scale
    box = (slice(None), slice(None))
    if crop_margin is not None:
        rows, cols = np.flatnonzero((p > 0.5).any(axis=1)), np.flatnonzero((p > 0.5).any(axis=0))
        if not len(rows):
            return _CrfJob(None, box, p.shape, full_size)
        grow = int(np.ceil(crop_margin * bilateral_sxy))
        box = (slice(max(0, rows[0] - grow), rows[-1] + 1 + grow), slice(max(0, cols[0] - grow), cols[-1] + 1 + grow))
    args = (np.ascontiguousarray(frame[box]), np.ascontiguousarray(p[box]), iterations, gaussian_sxy, gaussian_compat,
            bilateral_sxy, bilateral_srgb, bilateral_compat)
    return _CrfJob(args, box, p.shape, full_size)


def _crf_mask(job: _CrfJob, margin_in_box: np.ndarray | None) -> np.ndarray:
    """The mask uint8 at the input size from the CRF's margin on the job's box (None: all background)."""
    if margin_in_box is None:
        return np.zeros(job.full_size, np.uint8)
    margin = np.full(job.shape, -1.0, np.float32)
    margin[job.box] = margin_in_box
    if margin.shape != job.full_size:
        import cv2

        margin = cv2.resize(margin, (job.full_size[1], job.full_size[0]), interpolation=cv2.INTER_LINEAR)
    return (margin > 0).astype(np.uint8)


def _crf_margin(frame: np.ndarray, p: np.ndarray, iterations: int, gaussian_sxy: float, gaussian_compat: float,
                bilateral_sxy: float, bilateral_srgb: float, bilateral_compat: float) -> np.ndarray:
    """Q(fg) - Q(bg) float32 ``(H, W)`` after the mean-field iterations of pydensecrf on ``frame`` and P(fg) ``p``."""
    import pydensecrf.densecrf as dcrf
    from pydensecrf.utils import unary_from_softmax

    height, width = p.shape
    crf = dcrf.DenseCRF2D(width, height, 2)
    crf.setUnaryEnergy(np.ascontiguousarray(unary_from_softmax(np.stack([1.0 - p, p]))))
    # kernel and normalisation: pydensecrf's defaults, DIAG_KERNEL and NORMALIZE_SYMMETRIC (the authors'). They are
    # not named here: built with Cython 3 (not the 0.29 that pydensecrf2 pins), its enums leave the module's namespace
    crf.addPairwiseGaussian(sxy=gaussian_sxy, compat=gaussian_compat)
    crf.addPairwiseBilateral(sxy=bilateral_sxy, srgb=bilateral_srgb, rgbim=np.ascontiguousarray(frame, dtype=np.uint8),
                             compat=bilateral_compat)
    q = np.asarray(crf.inference(iterations)).reshape(2, height, width)
    return q[1] - q[0]


class _Helper:
    """One child process running :func:`_crf_margin` (``python -m eponet.plugins.refiner._crf_helper``): the
    arguments go to it pickled through a pipe, the answer comes back the same way, one frame at a time. A child
    started as a module, not by ``multiprocessing``, so a user's script is never imported again."""

    def __init__(self):
        package_root = str(Path(__file__).resolve().parents[3])
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [package_root, os.environ.get("PYTHONPATH")])),
               "OMP_NUM_THREADS": "1"}
        self.process = subprocess.Popen([sys.executable, "-m", "eponet.plugins.refiner._crf_helper"],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        self.lock = threading.Lock()

    def margin(self, args: tuple) -> np.ndarray:
        with self.lock:  # one request in flight: no pipe can fill both ways
            pickle.dump(args, self.process.stdin, protocol=pickle.HIGHEST_PROTOCOL)
            self.process.stdin.flush()
            status, value = pickle.load(self.process.stdout)
        if status != "ok":
            raise RuntimeError(value)
        return value

    def close(self) -> None:
        try:
            self.process.stdin.close()
            self.process.wait(timeout=5)
        except (OSError, subprocess.TimeoutExpired):
            self.process.kill()


_HELPER: _Helper | None = None
_HELPER_LOCK = threading.Lock()


def _helper() -> _Helper:
    """This process's one helper process for pydensecrf (started on first use, closed at exit)."""
    global _HELPER
    with _HELPER_LOCK:
        if _HELPER is None or _HELPER.process.poll() is not None:
            _HELPER = _Helper()
            atexit.register(_HELPER.close)
        return _HELPER


def _forget_helper() -> None:
    global _HELPER
    with _HELPER_LOCK:
        if _HELPER is not None:
            _HELPER.close()
        _HELPER = None


class DenseCrfRefiner:
    """Dense CRF per frame on the min-max normalised probability (defaults from the original code).

    pydensecrf holds Python's GIL through its C++ work, so in the run loop, whose stages of one video overlap in
    threads, a CRF in this process would stall the flow and geometry threads for its whole duration. With
    ``helper_process`` (the default) the CRF itself runs in one helper process (started on first use, shared by
    every refiner of this process); the resizing and cropping stay here, and the masks are the same bit for bit.
    ``backend: grid`` (:mod:`eponet.plugins.refiner.gridcrf`) runs in this process: numpy, no helper.

    ``temporal`` (0 or 1): with 1 the run loop hands the CRF each frame's probability averaged with its two
    neighbours' warped into it along the flow (:mod:`eponet.core.temporal`; the protocol's ``temporal``).
    """

    def __init__(self, *, helper_process: bool = True, backend: str = "pydensecrf", grid_cell: float = CELL,
                 temporal: int = 0, **params):
        self.temporal = int(temporal)
        self.helper_process = helper_process
        self.backend, self.grid_cell = backend, grid_cell
        self.params = params

    def refine(self, frames: np.ndarray, probability: np.ndarray) -> np.ndarray:
        jobs = [_crf_job(frames[t], probability[t], **{**_DEFAULTS, **self.params}) for t in range(len(frames))]
        masks = np.empty(probability.shape, np.uint8)
        for t, margin in enumerate(self._margins(jobs)):
            masks[t] = _crf_mask(jobs[t], margin)
        return masks

    def _margins(self, jobs: list[_CrfJob]) -> list[np.ndarray | None]:
        desc = "refiner (densecrf)"
        if self.helper_process and self.backend == "pydensecrf":  # (the grid is numpy: no GIL held for long)
            try:
                helper = _helper()
                return [helper.margin(job.args) if job.args else None for job in track(jobs, desc=desc, total=len(jobs))]
            except (OSError, EOFError, pickle.UnpicklingError) as exc:  # no helper here: the CRF runs in this process
                _forget_helper()
                log.warning("densecrf: no helper process (%s); the CRF runs in this process", exc)
                self.helper_process = False
        return [_margin_here(job, self.backend, self.grid_cell) for job in track(jobs, desc=desc, total=len(jobs))]


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="refiner",
            name="densecrf",
            factory=DenseCrfRefiner,
            params=(
                Param("iterations", "int", 5, "mean-field iterations", minimum=1),
                Param("gaussian_sxy", "float", 3.0, "spatial std of the Gaussian kernel (px)", minimum=0.0, exclusive_min=True),
                Param("gaussian_compat", "float", 3.0, "weight of the Gaussian kernel", minimum=0.0),
                Param("bilateral_sxy", "float", 50.0, "spatial std of the bilateral kernel (px)", minimum=0.0, exclusive_min=True),
                Param("bilateral_srgb", "float", 10.0, "colour std of the bilateral kernel (0-255)", minimum=0.0, exclusive_min=True),
                Param("bilateral_compat", "float", 5.0, "weight of the bilateral kernel", minimum=0.0),
                Param("normalise", "bool", True, "min-max normalise the probability per frame first (original code)"),
                Param("scale", "float", 1.0, "run at this fraction of the frame size (1 = as the original code)",
                      minimum=0.1, maximum=1.0),
                Param("max_size", "int", None, "run at most at this longer side in px (null = no cap)",
                      minimum=16, nullable=True),
                Param("helper_process", "bool", True, "run pydensecrf in a helper process: it holds Python's GIL, "
                      "which would stall the other stages of the run loop's threads (false: in this process)"),
                Param("backend", "choice", "pydensecrf", "pydensecrf: the permutohedral lattice (original code); grid: "
                      "the same CRF with its bilateral kernel on a sparse bilateral grid in numpy, several times faster",
                      choices=("pydensecrf", "grid")),
                Param("grid_cell", "float", CELL, "backend grid: the grid's cell side in kernel standard deviations",
                      minimum=0.25, maximum=4.0),
                Param("crop_margin", "float", None, "run only on the box around the pixels above 0.5, grown by this "
                      "many bilateral widths (background outside; null = the whole frame)", minimum=0.0, nullable=True),
                Param("temporal", "int", 0, "1: refine each frame's probability averaged with its two neighbours' "
                      "warped into it along the flow, where the flow is forward-backward consistent (a frame that loses "
                      "the object between two that hold it); 0: each frame alone", minimum=0, maximum=1),
            ),
            doc="dense CRF with the EpO-Net defaults (pydensecrf's lattice, or a numpy bilateral grid: backend)",
        )
    ]
