"""Seeded, batched robust estimation (RANSAC with LMedS or MSAC scoring) and Torr's GRIC model selection.

References
----------
.. [HZ] R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2003.
.. [R84] P. J. Rousseeuw, "Least median of squares regression", JASA 79, 1984.
.. [T98] P. H. S. Torr, "Geometric motion segmentation and model selection", Phil. Trans. R. Soc. A 356, 1998.
.. [TZ00] P. H. S. Torr and A. Zisserman, "MLESAC: a new robust estimator ...", CVIU 78, 2000.
.. [N03] D. Nister, "Preemptive RANSAC for live structure and motion estimation", ICCV 2003.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Callable

import numpy as np
from scipy.special import gammaincinv

__all__ = [
    "ransac_trial_count",
    "draw_samples",
    "finite_median",
    "robust_sigma2",
    "inlier_bound",
    "gric",
    "RobustSearch",
    "robust_search",
]


@lru_cache(maxsize=256)
def _chi2_ppf(q: float, dof: int) -> float:
    """The ``q`` quantile of the chi-square distribution with ``dof`` degrees of freedom: what
    ``scipy.stats.chi2.ppf`` computes, bit for bit, without importing ``scipy.stats`` (over a second at start-up)."""
    return float(2.0 * gammaincinv(dof / 2.0, q))


def ransac_trial_count(inlier_ratio: float, sample_size: int, confidence: float) -> int:
    """Trials needed so that at least one sample is all-inlier with probability ``confidence``:
    ``N = log(1 - p) / log(1 - w^s)`` ([HZ] eq. 4.18). Returns a large number for ``w -> 0``."""
    w = float(np.clip(inlier_ratio, 0.0, 1.0)) ** sample_size
    if w >= 1.0:
        return 1
    if w <= 0.0:
        return 1 << 30
    return int(math.ceil(math.log(1.0 - confidence) / math.log1p(-w)))


def draw_samples(rng: np.random.Generator, n: int, size: int, count: int) -> np.ndarray:
    """``count`` random subsets of ``size`` distinct indices in ``[0, n)``, int64 ``(count, size)``."""
    if n < size:
        raise ValueError(f"draw_samples: need at least {size} points, got {n}")
    if n < 8 * size:
        return np.argsort(rng.random((count, n)), axis=1)[:, :size]
    idx = rng.integers(0, n, (count, size))
    while True:
        s = np.sort(idx, axis=1)
        bad = (s[:, 1:] == s[:, :-1]).any(axis=1)
        if not bad.any():
            return idx
        idx[bad] = rng.integers(0, n, (int(bad.sum()), size))


def finite_median(values: np.ndarray) -> float:
    """Median of a 1-D array without NaN, as :func:`numpy.median` gives it (the mean of the two middle values
    for an even count), without its overhead: the robust fits take several medians of small arrays per
    triplet. Raises ``ValueError`` for an empty array."""
    values = np.asarray(values)
    n = values.size
    if n == 0:
        raise ValueError("finite_median: empty array")
    k = n // 2
    if n % 2:
        return float(np.partition(values, k)[k])
    p = np.partition(values, (k - 1, k))
    return float((p[k - 1] + p[k]) / 2)


def robust_sigma2(residuals_sq: np.ndarray, dof: int, num_params: int = 0, iterations: int = 3) -> float:
    """Noise variance from squared residuals distributed as ``sigma^2 chi^2_dof`` for inliers.

    Starts from the LMedS estimate ``median(e^2) / median(chi^2_dof)`` with Rousseeuw's small-sample factor
    ``(1 + 5 / (n - p))^2`` ([R84]), robust to up to half the points being outliers but biased upwards by
    them; then ``iterations`` times keeps the residuals inside the 95% bound and re-estimates from their
    median, corrected for the truncation (the median of a chi-square truncated at its 95% quantile is its
    47.5% quantile).
    """
    e2 = np.asarray(residuals_sq)
    e2 = e2[np.isfinite(e2)]
    if e2.size == 0:
        return float("nan")
    n = e2.size
    factor = (1.0 + 5.0 / max(n - num_params, 1)) ** 2
    sigma2 = finite_median(e2) / _chi2_ppf(0.5, dof) * factor
    bound, q = _chi2_ppf(0.95, dof), _chi2_ppf(0.475, dof)
    for _ in range(iterations):
        inside = e2[e2 <= bound * sigma2]
        if inside.size < max(10, num_params + 1) or sigma2 <= 0:
            break
        sigma2 = finite_median(inside) / q
    return sigma2


def inlier_bound(sigma2: float, dof: int, quantile: float = 0.95) -> float:
    """Squared-residual bound ``chi^2_dof(quantile) sigma^2`` of the inliers ([HZ] Table 4.1)."""
    return _chi2_ppf(float(quantile), int(dof)) * sigma2


def gric(residuals_sq: np.ndarray, sigma2: float, *, r: int, d: int, k: int, lambda3: float = 2.0) -> float:
    """Torr's Geometric Robust Information Criterion of a model ([T98] eq. 13); lower is better.

    ``GRIC = sum_i min(e_i^2 / sigma^2, lambda3 (r - d)) + lambda1 d n + lambda2 k`` with
    ``lambda1 = log r`` and ``lambda2 = log(r n)``.

    Parameters
    ----------
    residuals_sq : array (n,)
        Squared distances of the data from the model's manifold (pixels^2).
    sigma2 : float
        Noise variance (pixels^2); use one value, estimated from the most general model, for all models.
    r : int
        Dimension of one datum (4 for two views, 6 for three).
    d : int
        Dimension of the model's manifold (2 for homographies, 3 for the epipolar geometry).
    k : int
        Number of model parameters (8 for H, 7 for F, 16 for two homographies, 18 for a trifocal tensor).
    """
    e2 = np.asarray(residuals_sq, dtype=np.float64)
    n = e2.size
    cap = lambda3 * (r - d)
    rho = np.minimum(np.nan_to_num(e2 / sigma2, nan=cap, posinf=cap), cap)
    return float(rho.sum() + math.log(r) * d * n + math.log(r * n) * k)


@dataclass
class RobustSearch:
    """Result of :func:`robust_search`: the best hypothesis, its score, residuals and the work done."""

    model: Any
    score: float
    residuals: np.ndarray  # (m,) squared residuals of the best model on the evaluation points
    trials: int
    hypotheses: int


def robust_search(
    solve: Callable[[np.ndarray], tuple[Any, int]],
    residual: Callable[[Any, np.ndarray], np.ndarray],
    n: int,
    sample_size: int,
    rng: np.random.Generator,
    *,
    dof: int,
    confidence: float = 0.99,
    max_trials: int = 1000,
    threshold_sq: float | None = None,
    eval_points: int = 1000,
    batch: int = 64,
    min_sigma2: float = 0.0,
) -> RobustSearch | None:
    """Batched RANSAC hypothesise-and-verify over ``n`` data points.

    Each round draws ``batch`` minimal samples with ``rng``, solves them all at once and scores every
    hypothesis on one fixed random subset of at most ``eval_points`` data (the same subset for all, so scores
    are comparable). Scoring is LMedS, the median squared residual ([R84]), when ``threshold_sq`` is None: no
    threshold is needed and a model that fits more than half the data wins; otherwise MSAC, the sum of
    ``min(e^2, threshold_sq)`` ([TZ00]). The number of trials adapts to the inlier ratio of the best model
    so far (inliers: ``e^2`` below the threshold, or below ``chi^2_dof(0.95)`` times the LMedS variance) as
    in [HZ] Algorithm 4.5, capped at ``max_trials``; the LMedS variance is taken as at least ``min_sigma2``
    there, and the threshold as at least that variance's 95% bound (the count only, not the scores). Within a
    batch, hypotheses are first ranked on 100 of the evaluation points and only the best 12 are scored on all of
    them (preemptive scoring, [N03]).

    Parameters
    ----------
    solve : callable
        ``solve(samples)``, with ``samples`` int ``(B, sample_size)``, returns ``(models, count)``: ``count``
        hypotheses as an array with a leading axis of that length, or a tuple of such arrays (e.g.
        ``(F21, F31, F32)``); ``(None, 0)`` when no sample gave one.
    residual : callable
        ``residual(models, idx)`` returns the squared residuals ``(count, len(idx))`` of every hypothesis on
        the data points ``idx``.
    n : int
        Number of data points.
    sample_size : int
        Points per minimal sample (6 for the trifocal tensor, 4 for homographies).
    rng : numpy.random.Generator
        The only source of randomness.
    dof : int
        Degrees of freedom of an inlier's squared residual (``sigma^2 chi^2_dof``).
    min_sigma2 : float
        Pixels^2: the lowest noise variance the trial count assumes. Dense optical flow is smooth, so a model
        fits most trajectories to a few hundredths of a pixel while the flow's real error is tenths of a pixel
        with a heavy tail: the inliers within the 95% bound of the LMedS variance are then about 60% of the
        points, whatever the model, and a six-point search runs 100-300 trials where one batch finds a model
        as good. With the flow's noise level here (the rigidity stages pass their ``min_sigma``, GRIC's floor)
        the ratio reflects the points a minimal sample may be drawn from.

    Returns
    -------
    RobustSearch or None
        The best hypothesis (one element of ``models``), or None when no sample produced a hypothesis.
    """
    if n < sample_size:
        return None
    m = min(n, eval_points)
    eval_idx = np.sort(rng.choice(n, m, replace=False)) if m < n else np.arange(n)
    # the preemptive subset: evenly spaced through the (sorted) evaluation set, i.e. stratified over the data
    pre_idx = eval_idx[:: max(1, m // _PREEMPT_POINTS)][:_PREEMPT_POINTS]
    best_score, best_model, best_res = np.inf, None, None
    needed, trials, hyps = max_trials, 0, 0
    while trials < min(needed, max_trials):
        count = min(batch, max_trials - trials)
        samples = draw_samples(rng, n, sample_size, count)
        trials += count
        models, nh = solve(samples)
        if nh == 0:
            continue
        hyps += nh
        if nh > 2 * _PREEMPT_KEEP and m > 2 * _PREEMPT_POINTS:
            # preemptive scoring (Nister 2003): rank all hypotheses on the first points of the (random)
            # evaluation set, score only the best few on all of it
            pre = _scores(residual(models, pre_idx), threshold_sq)
            keep = np.sort(np.argpartition(pre, _PREEMPT_KEEP)[:_PREEMPT_KEEP])
            models = _take(models, keep)
        res = residual(models, eval_idx)  # (nh, m)
        res = np.where(np.isfinite(res), res, np.inf)
        scores = _scores(res, threshold_sq)
        k = int(np.argmin(scores))
        if scores[k] < best_score:
            best_score, best_res = float(scores[k]), res[k]
            best_model = _take(models, k)
            if threshold_sq is None:
                bound = inlier_bound(max(robust_sigma2(best_res, dof), min_sigma2), dof)
            else:
                bound = max(threshold_sq, inlier_bound(min_sigma2, dof))
            ratio = float(np.mean(best_res <= bound)) if np.isfinite(bound) else 0.0
            needed = ransac_trial_count(ratio, sample_size, confidence)
    if best_model is None:
        return None
    return RobustSearch(best_model, best_score, best_res, trials, hyps)


#: Preemptive scoring: hypotheses of a batch are ranked on this many evaluation points first ...
_PREEMPT_POINTS = 100
#: ... and this many of them are scored on all evaluation points.
_PREEMPT_KEEP = 12


def _scores(res: np.ndarray, threshold_sq: float | None) -> np.ndarray:
    """LMedS (median squared residual) or MSAC (truncated sum) score of each row."""
    res = np.where(np.isfinite(res), res, np.inf)
    if threshold_sq is None:
        half = res.shape[1] // 2
        return np.partition(res, half, axis=1)[:, half]
    return np.minimum(res, threshold_sq).sum(axis=1)


def _take(models: Any, k: int) -> Any:
    if isinstance(models, tuple):
        return tuple(m[k] for m in models)
    return models[k]
