"""Per-sequence statistics of per-frame scores (Mean, Recall, Decay) and data-set aggregates, as DAVIS.

See ``shared/docs/metrics.md``: DAVIS-2016 scores frames ``1 .. n-2`` (first and last dropped); Recall is the
fraction of frames scoring strictly above 0.5; Decay is the mean of the first of four overlapping bins minus
the mean of the last.
"""

from __future__ import annotations

import warnings
from typing import Iterable, Sequence

import numpy as np

__all__ = [
    "RECALL_THRESHOLD",
    "DECAY_BINS",
    "davis2016_scored",
    "mean",
    "recall",
    "decay_bins",
    "decay",
    "sequence_statistics",
    "nanmean",
]

RECALL_THRESHOLD = 0.5
DECAY_BINS = 4


def davis2016_scored(n_frames: int) -> slice:
    """The frames DAVIS-2016 scores in a sequence of ``n_frames``: all but the first and the last."""
    return slice(1, max(1, n_frames - 1))


def nanmean(values: Iterable[float]) -> float:
    """Mean ignoring NaN; NaN (without a warning) when nothing is left."""
    arr = np.asarray(list(values) if not isinstance(values, np.ndarray) else values, dtype=np.float64)
    arr = arr[~np.isnan(arr)]
    return float(arr.mean()) if arr.size else float("nan")


def mean(values: Sequence[float]) -> float:
    """M: the mean of the per-frame values, ignoring NaN (as ``np.nanmean`` in the DAVIS code)."""
    return nanmean(values)


def recall(values: Sequence[float], threshold: float = RECALL_THRESHOLD) -> float:
    """O: the fraction of frames whose value is strictly above ``threshold`` (NaN counts as not above)."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0:
        return float("nan")
    with np.errstate(invalid="ignore"):
        return float(np.mean(arr > threshold))


def decay_bins(n: int, n_bins: int = DECAY_BINS) -> list[slice]:
    """The DAVIS decay bins over ``n`` values: ``ids = round(linspace(1, n, n_bins + 1)) - 1`` and bin ``i``
    is ``[ids[i], ids[i+1]]`` inclusive, so neighbouring bins share their boundary value.

    >>> decay_bins(10)
    [slice(0, 3, None), slice(2, 6, None), slice(5, 8, None), slice(7, 10, None)]
    """
    # linspace(1, n, 5) is exact in binary for integer n (steps are multiples of (n-1)/4), so floor(x + 0.5)
    # is MATLAB's round (half away from zero) here.
    ids = np.floor(np.linspace(1, n, n_bins + 1) + 0.5).astype(np.int64) - 1
    return [slice(int(ids[i]), int(ids[i + 1]) + 1) for i in range(n_bins)]


def decay(values: Sequence[float], n_bins: int = DECAY_BINS) -> float:
    """D: mean of the first decay bin minus the mean of the last (NaN ignored inside a bin)."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.size == 0:
        return float("nan")
    bins = decay_bins(arr.size, n_bins)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return float(nanmean(arr[bins[0]]) - nanmean(arr[bins[-1]]))


def sequence_statistics(values: Sequence[float]) -> dict[str, float]:
    """``{"mean": M, "recall": O, "decay": D}`` of the per-frame values of one sequence (already restricted to
    the scored frames)."""
    return {"mean": mean(values), "recall": recall(values), "decay": decay(values)}
