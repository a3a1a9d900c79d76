"""Robust fits of the rigid-background models of a triplet (or pair) of frames, and the fitted model's record.

Each fit is a robust search over minimal samples (:func:`eponet.geometry.robust.robust_search`: LMedS, or MSAC
at a noise floor) followed by a guarded linear refit on the inliers. Which model explains a triplet is decided in
:mod:`eponet.geometry.triplets`.

References
----------
.. [HZ] R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2003.
.. [CWM05] O. Chum, T. Werner and J. Matas, "Two-view geometry estimation unaffected by a dominant plane",
   CVPR 2005.
.. [TZ00] P. H. S. Torr and A. Zisserman, "MLESAC: a new robust estimator with application to estimating image
   geometry", CVIU 78, 2000.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .epipolar import sampson_error, symmetric_epipolar_distance
from .homography import (
    homography_dlt,
    homography_four_point,
    homography_triplet_distance,
    homography_triplet_error_sq,
    transfer_error_sq,
)
from .normalise import hartley_normalisation
from .robust import finite_median, inlier_bound, robust_search, robust_sigma2
from .trifocal import (
    fundamentals_from_trifocal,
    trifocal_linear,
    trifocal_six_point,
    triplet_epipolar_distance,
    triplet_sampson_error,
)

__all__ = [
    "MIN_POINTS",
    "SIGMA_FLOOR_PX",
    "RobustSettings",
    "FittedModel",
    "fit_trifocal",
    "fit_homographies",
    "fit_fundamental",
    "fit_homography_pair",
]

#: Fewest point triplets (pairs) a fit is attempted with; fewer gives the "too few points" fallback.
MIN_POINTS = 20
#: Lower bound of the noise estimate in pixels (exact synthetic flow would otherwise give sigma = 0).
SIGMA_FLOOR_PX = 0.01


@dataclass(frozen=True)
class RobustSettings:
    """Knobs of the robust fits.

    ``threshold`` (pixels) is the inlier bound on the RMS first-order residual of one point (the Sampson
    distance for epipolar models, the transfer distance for homographies); None means "adaptive": LMedS
    scoring (the trifocal search: see ``epipolar_msac``) and inliers within the 95% chi-square bound of the
    LMedS noise estimate ([HZ] Sec. 4.7).

    ``min_sigma`` (pixels) is the lowest noise level GRIC assumes. The robust estimate from the residuals of
    estimated flow is often far below the flow's real error (DIS: ~0.2-0.6 px, spatially correlated, which
    the more flexible epipolar model partly absorbs), and GRIC with it rejects a homography for deviations of
    a few hundredths of a pixel. With the floor, motion that two homographies explain to within about
    ``min_sigma`` counts as degenerate for the epipolar model. With ``trial_floor`` (the default) the searches'
    trial counts assume the same floor (``min_sigma2`` of :func:`eponet.geometry.robust.robust_search`): one batch
    of 64 samples where the data allow instead of two to four; off, the count follows the LMedS noise estimate
    alone (eponet before 2026-12-05).

    ``epipolar_msac`` (the default; with ``threshold`` None): the six-point search of the trifocal fit scores its
    hypotheses by MSAC ([TZ00]) truncated at ``min_sigma`` (RMS per point) instead of by their median residual
    (LMedS). When one plane holds more than half of the points (a far background behind near rigid
    structure), every tensor compatible with that plane has the same near-zero median, whether or not it
    explains the rest of the rigid scene ([CWM05]: the dominant-plane degeneracy), and LMedS picks among them
    by chance; MSAC counts the points each tensor explains. The homography searches keep LMedS (a plane is
    their model); the refits and the inlier bounds stay adaptive. Off, or with ``min_sigma`` 0: LMedS, as before
    2026-12-05.

    ``refit_points``: the linear refits after the search use an evenly spaced subset of about this many
    inliers (fewer than twice as many); 27 (trifocal) or 9 (homography) unknowns are determined far beyond
    the flow's noise by 1000 points, and the refits' cost grows with the points (3000 before 2026-12-05).
    """

    confidence: float = 0.99
    max_trials: int = 1000
    threshold: float | None = None
    eval_points: int = 1000
    refine_iterations: int = 2
    refit_points: int = 1000
    epipolar_msac: bool = True
    min_sigma: float = 0.5
    trial_floor: bool = True


@dataclass
class FittedModel:
    """A rigid-background model of a triplet (or pair) and how it was obtained.

    ``kind`` is ``"trifocal"``, ``"fundamental"``, ``"homography"``, ``"static"`` or ``"failed"``;
    ``matrices`` holds ``(F21, F31, F32)``, ``(F21,)``, ``(H21, H31)`` or ``(H21,)`` in pixel coordinates.
    """

    kind: str
    matrices: tuple = ()
    sigma: float = float("nan")
    inlier_ratio: float = float("nan")
    trials: int = 0
    gric: dict = field(default_factory=dict)
    fallback: str | None = None
    #: Which of the fitted points are inliers of the chosen model (bool (n,)), when known.
    inliers: np.ndarray | None = field(default=None, repr=False)
    #: The most general rigid model that was fitted (the epipolar one when it exists), whose distances tell
    #: how likely a point belongs to the static scene whatever model was chosen (see guided sampling).
    general: "FittedModel | None" = field(default=None, repr=False)
    #: ``degeneracy="parallax"``: the rigid second plane's fraction of the points and border ratio.
    parallax: dict | None = None

    def distance(self, *points: np.ndarray) -> np.ndarray:
        """Per-point distance in pixels (N,) of point pairs/triplets from the model (float32 for float32
        triplets, as stored in trajectories, else float64).

        Triplets: the sum of six point-to-epipolar-line distances (trifocal, static) or six transfer
        distances (homography). Pairs: the two point-to-epipolar-line distances, or the two transfer
        distances.
        """
        if self.kind in ("trifocal", "static") and len(points) == 3:
            return triplet_epipolar_distance(*self.matrices, *points)
        if self.kind == "homography" and len(points) == 3:
            return homography_triplet_distance(*self.matrices, *points)
        if self.kind == "fundamental" and len(points) == 2:
            return symmetric_epipolar_distance(points[0], points[1], self.matrices[0])
        if self.kind in ("homography", "static") and len(points) == 2:
            h = self.matrices[0]
            back = transfer_error_sq(np.linalg.inv(h), points[1], points[0])
            return np.sqrt(transfer_error_sq(h, *points)) + np.sqrt(back)
        raise ValueError(f"cannot score {len(points)} views with a {self.kind!r} model")

    def info(self) -> dict:
        """JSON-serialisable diagnostics."""
        out = {"model": self.kind, "trials": int(self.trials)}
        if np.isfinite(self.sigma):
            out["sigma_px"] = round(float(self.sigma), 4)
        if np.isfinite(self.inlier_ratio):
            out["inlier_ratio"] = round(float(self.inlier_ratio), 4)
        if self.gric:
            out["gric"] = {k: round(float(v), 1) for k, v in self.gric.items()}
        if self.parallax:
            out["parallax"] = dict(self.parallax)
        if self.fallback:
            out["fallback"] = self.fallback
        return out


def _trial_sigma2(settings: RobustSettings) -> float:
    """The noise variance (pixels^2) the searches' trial counts assume at least."""
    return settings.min_sigma**2 if settings.trial_floor else 0.0


def _bound(e2: np.ndarray, dof: int, settings: RobustSettings) -> float:
    if settings.threshold is not None:
        return settings.threshold**2 * dof  # RMS threshold per point -> bound on the summed squares
    return inlier_bound(max(robust_sigma2(e2, dof), SIGMA_FLOOR_PX**2), dof)


def _median(e2: np.ndarray) -> float:
    return finite_median(np.where(np.isfinite(e2), e2, np.inf))


def _refine(fit_fn, resid_fn, model, e2, dof, settings: RobustSettings):
    """Refit on the inliers while that lowers the median (or MSAC) residual: a guarded local optimisation."""
    def cost(r):
        if settings.threshold is None:
            return _median(r)
        return float(np.minimum(r, _bound(r, dof, settings)).sum())

    best_cost = cost(e2)
    for _ in range(settings.refine_iterations):
        inl = np.flatnonzero(e2 <= _bound(e2, dof, settings))
        if len(inl) < MIN_POINTS:
            break
        # an evenly spaced subset of the inliers suffices for the linear refit (no randomness needed)
        inl = inl[:: max(1, len(inl) // settings.refit_points)]
        try:
            cand = fit_fn(inl)
        except (ValueError, np.linalg.LinAlgError):
            break
        r = resid_fn(cand)
        c = cost(r)
        if not np.isfinite(c) or c > best_cost:
            break
        model, e2, best_cost = cand, r, c
    return model, e2


def _search_and_refine(solve, residual, fit_fn, n: int, sample_size: int, dof: int, rng,
                       settings: RobustSettings, threshold_sq: float | None):
    """The robust search over minimal samples, then :func:`_refine` on all ``n`` points.

    ``residual(model, idx)`` scores a hypothesis on the points ``idx`` (``slice(None)``: all of them) and
    ``fit_fn(inliers)`` refits linearly. Returns ``(model, e2, trials)``, or None when no hypothesis could be formed.
    """

    def all_residuals(model):
        return residual(model, slice(None))

    found = robust_search(
        solve, residual, n, sample_size, rng, dof=dof, confidence=settings.confidence,
        max_trials=settings.max_trials, threshold_sq=threshold_sq,
        eval_points=settings.eval_points, min_sigma2=_trial_sigma2(settings),
    )
    if found is None:
        return None
    model, e2 = _refine(fit_fn, all_residuals, found.model, all_residuals(found.model), dof, settings)
    return model, e2, found.trials


def fit_trifocal(x1, x2, x3, rng: np.random.Generator, settings: RobustSettings = RobustSettings()):
    """Robust three-view epipolar geometry: six-point RANSAC ([HZ] Algorithm 20.1 inside Algorithm 4.5 /
    16.4) scored by the summed Sampson error of the derived ``F21, F31, F32`` in pixels, then the linear
    algorithm ([HZ] Algorithm 16.1/16.2) on the inliers.

    Parameters
    ----------
    x1, x2, x3 : arrays (N, 2) float64
        Pixel coordinates of the same N trajectories in the three frames.

    Returns
    -------
    (F21, F31, F32), e2, trials
        Pixel fundamental matrices, squared residuals (N,) (~ sigma^2 chi^2_3 for inliers), trials run;
        or None when no hypothesis could be formed.
    """
    (n1, t1), (n2, t2), (n3, t3) = (hartley_normalisation(x) for x in (x1, x2, x3))

    def denorm(f21, f31, f32):
        return (
            np.swapaxes(t2, -1, -2) @ f21 @ t1,
            np.swapaxes(t3, -1, -2) @ f31 @ t1,
            np.swapaxes(t3, -1, -2) @ f32 @ t2,
        )

    def solve(samples):
        t, ok = trifocal_six_point(n1[samples], n2[samples], n3[samples])
        t = t[ok]
        if len(t) == 0:
            return None, 0
        fs = denorm(*fundamentals_from_trifocal(t, exact=True))
        good = np.all([np.isfinite(f).all(axis=(-2, -1)) for f in fs], axis=0)
        return tuple(f[good] for f in fs), int(good.sum())

    def residual(fs, idx):
        return triplet_sampson_error(*fs, x1[idx], x2[idx], x3[idx])

    if settings.threshold is not None:
        threshold_sq = 3 * settings.threshold**2
    else:  # MSAC at the noise floor (see RobustSettings.epipolar_msac), or LMedS without a floor
        threshold_sq = 3 * settings.min_sigma**2 if settings.epipolar_msac and settings.min_sigma > 0 else None
    def fit_fn(inl):
        return fundamentals_from_trifocal(trifocal_linear(x1[inl], x2[inl], x3[inl]))

    return _search_and_refine(solve, residual, fit_fn, len(x1), 6, 3, rng, settings, threshold_sq)


def fit_homographies(x1, x2, x3, rng: np.random.Generator, settings: RobustSettings = RobustSettings()):
    """Robust pair of homographies ``H21, H31`` of a triplet: 4-point RANSAC ([HZ] Algorithm 4.6) scored by
    :func:`eponet.geometry.homography.homography_triplet_error_sq`, then DLT ([HZ] Algorithm 4.2) on the
    inliers.

    Returns
    -------
    (H21, H31), e2, trials
        Or None when no hypothesis could be formed.
    """
    (n1, t1), (n2, t2), (n3, t3) = (hartley_normalisation(x) for x in (x1, x2, x3))
    it2, it3 = np.linalg.inv(t2), np.linalg.inv(t3)

    def solve(samples):
        h21, ok2 = homography_four_point(n1[samples], n2[samples])
        h31, ok3 = homography_four_point(n1[samples], n3[samples])
        ok = ok2 & ok3
        if not ok.any():
            return None, 0
        return (it2 @ h21[ok] @ t1, it3 @ h31[ok] @ t1), int(ok.sum())

    def residual(hs, idx):
        return homography_triplet_error_sq(*hs, x1[idx], x2[idx], x3[idx])

    def fit_fn(inl):
        return homography_dlt(x1[inl], x2[inl]), homography_dlt(x1[inl], x3[inl])

    return _search_and_refine(solve, residual, fit_fn, len(x1), 4, 4, rng, settings,
                              None if settings.threshold is None else 4 * settings.threshold**2)


def _fundamental_opencv(x1, x2, rng, threshold):
    import cv2

    params = cv2.UsacParams()
    params.confidence = 0.99
    params.maxIterations = 1000
    params.sampler = cv2.SAMPLING_UNIFORM
    params.score = cv2.SCORE_METHOD_MAGSAC
    params.loMethod = cv2.LOCAL_OPTIM_SIGMA
    params.loIterations = 10
    params.loSampleSize = 14
    params.final_polisher = cv2.MAGSAC
    params.final_polisher_iterations = 10
    params.threshold = float(threshold)
    params.randomGeneratorState = int(rng.integers(0, 2**31 - 1))
    params.isParallel = False
    f, _ = cv2.findFundamentalMat(x1.astype(np.float64), x2.astype(np.float64), params)
    if f is None or f.shape != (3, 3) or not np.isfinite(f).all():
        return None
    return f / np.linalg.norm(f)


def fit_fundamental(x1, x2, rng: np.random.Generator, *, threshold: float = 1.0):
    """Fundamental matrix of a pair by OpenCV's USAC with MAGSAC++ scoring (8-point minimal solver variant
    of [HZ] Algorithm 11.4), seeded from ``rng``.

    Returns
    -------
    (F21,), e2
        ``e2`` is the Sampson error (pixels^2, ~ sigma^2 chi^2_1 for inliers); or None on failure.
    """
    f = _fundamental_opencv(x1, x2, rng, threshold)
    if f is None:
        return None
    return (f,), sampson_error(x1, x2, f)


def fit_homography_pair(x1, x2, rng: np.random.Generator, settings: RobustSettings = RobustSettings()):
    """Robust homography of a pair (4-point RANSAC with LMedS/MSAC, then DLT on the inliers).

    Returns
    -------
    (H21,), e2
        ``e2 = |x2 - H x1|^2 / 2`` (~ sigma^2 chi^2_2 for inliers); or None.
    """
    (n1, t1), (n2, t2) = hartley_normalisation(x1), hartley_normalisation(x2)
    it2 = np.linalg.inv(t2)

    def solve(samples):
        h, ok = homography_four_point(n1[samples], n2[samples])
        if not ok.any():
            return None, 0
        return it2 @ h[ok] @ t1, int(ok.sum())

    def resid(h, idx):
        return transfer_error_sq(h, x1[idx], x2[idx]) / 2.0

    found = _search_and_refine(solve, resid, lambda inl: homography_dlt(x1[inl], x2[inl]), len(x1), 4, 2, rng,
                               settings, None if settings.threshold is None else 2 * settings.threshold**2)
    if found is None:
        return None
    h, e2, _ = found
    return (h,), e2
