"""Per-triplet (and per-pair) rigid-background models: robust fits, static-camera test, GRIC model selection,
and the per-point distances that make up the epipolar-distance (ED) maps.

A triplet of frames (t, t+k, t+2k) is explained by one of

- ``"trifocal"``: the three-view epipolar geometry (a trifocal tensor from the six-point algorithm in
  RANSAC, refined by the linear algorithm on the inliers); a point scores the paper's sum of six
  point-to-epipolar-line distances;
- ``"homography"``: two homographies ``H21, H31`` (camera rotation, a distant or planar scene); a point scores
  the sum of its six transfer distances;
- ``"static"``: a static camera; fixed skew-symmetric fundamental matrices (the paper's rule), so that a
  point that did not move scores 0.

With ``degeneracy="gric"`` (and ``"parallax"``, which adds a plane + parallax test, see
:func:`estimate_triplet`) the trifocal and homography fits compete through Torr's GRIC: when the
background's motion is explained by a homography within the noise (most consecutive video frames), the
epipolar model is degenerate, can absorb an independently moving object, and the homography is chosen. The
homography side of the comparison may use a second homography for the dominant one's outliers ("two
independent planar motions"), so that an object the epipolar model absorbs as apparent parallax does not count
in its favour.

References
----------
.. [HZ] R. Hartley and A. Zisserman, *Multiple View Geometry in Computer Vision*, 2nd ed., 2003.
.. [T98] P. H. S. Torr, "Geometric motion segmentation and model selection", Phil. Trans. R. Soc. A, 1998.
.. [IA98] M. Irani and P. Anandan, "A unified approach to moving object detection in 2D and 3D scenes", IEEE
   TPAMI 20(6), 1998.
.. [CWM05] O. Chum, T. Werner and J. Matas, "Two-view geometry estimation unaffected by a dominant plane",
   CVPR 2005.
.. [TZ00] P. H. S. Torr and A. Zisserman, "MLESAC: a new robust estimator with application to estimating image
   geometry", CVIU 78, 2000.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .epipolar import symmetric_epipolar_distance, sampson_error, static_fundamentals
from .homography import (
    homography_dlt,
    homography_four_point,
    homography_triplet_distance,
    homography_triplet_error_sq,
    transfer_error_sq,
)
from .normalise import hartley_normalisation
from .parallax import is_parallax, rigid_second_plane
from .robust import finite_median, gric, inlier_bound, robust_search, robust_sigma2
from .trifocal import (
    fundamentals_from_trifocal,
    trifocal_linear,
    trifocal_six_point,
    triplet_epipolar_distance,
    triplet_sampson_error,
)

#: The choices of ``degeneracy`` (see :func:`estimate_triplet`).
DEGENERACY = ("parallax", "gric", "none")

__all__ = [
    "DEGENERACY",
    "MIN_POINTS",
    "SIGMA_FLOOR_PX",
    "RobustSettings",
    "FittedModel",
    "is_static",
    "fit_trifocal",
    "fit_homographies",
    "fit_fundamental",
    "fit_homography_pair",
    "estimate_triplet",
    "estimate_pair",
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


def is_static(*points: np.ndarray, threshold: float, fraction: float = 0.5) -> bool:
    """The paper's static-camera test: at least ``fraction`` of the points have no motion, i.e. move less
    than ``threshold`` pixels between every two of the frames.

    Parameters
    ----------
    *points : arrays (N, 2)
        The same N trajectories in two or three frames.
    threshold : float
        Displacement in pixels below which a point "did not move" (estimated flow is never exactly 0).
    """
    return bool(np.mean(_unmoved(threshold, *points)) >= fraction)


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
    found = robust_search(
        solve, residual, len(x1), 6, rng, dof=3, confidence=settings.confidence,
        max_trials=settings.max_trials, threshold_sq=threshold_sq,
        eval_points=settings.eval_points, min_sigma2=_trial_sigma2(settings),
    )
    if found is None:
        return None
    fs = found.model
    e2 = triplet_sampson_error(*fs, x1, x2, x3)

    def fit_fn(inl):
        return fundamentals_from_trifocal(trifocal_linear(x1[inl], x2[inl], x3[inl]))

    fs, e2 = _refine(fit_fn, lambda f: triplet_sampson_error(*f, x1, x2, x3), fs, e2, 3, settings)
    return fs, e2, found.trials


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

    found = robust_search(
        solve, residual, len(x1), 4, rng, dof=4, confidence=settings.confidence,
        max_trials=settings.max_trials, threshold_sq=None if settings.threshold is None else 4 * settings.threshold**2,
        eval_points=settings.eval_points, min_sigma2=_trial_sigma2(settings),
    )
    if found is None:
        return None
    hs = found.model
    e2 = homography_triplet_error_sq(*hs, x1, x2, x3)

    def fit_fn(inl):
        return homography_dlt(x1[inl], x2[inl]), homography_dlt(x1[inl], x3[inl])

    hs, e2 = _refine(fit_fn, lambda h: homography_triplet_error_sq(*h, x1, x2, x3), hs, e2, 4, settings)
    return hs, e2, found.trials


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

    found = robust_search(
        solve, resid, len(x1), 4, rng, dof=2, confidence=settings.confidence, max_trials=settings.max_trials,
        threshold_sq=None if settings.threshold is None else 2 * settings.threshold**2,
        eval_points=settings.eval_points, min_sigma2=_trial_sigma2(settings),
    )
    if found is None:
        return None
    h = found.model
    e2 = transfer_error_sq(h, x1, x2) / 2.0
    h, e2 = _refine(lambda inl: homography_dlt(x1[inl], x2[inl]), lambda hh: transfer_error_sq(hh, x1, x2) / 2.0,
                    h, e2, 2, settings)
    return (h,), e2


def _two_homographies_gric(e2h, points, sigma2, rng, settings: RobustSettings):
    """GRIC of "the dominant homography plus a second, independent one fitted to its outliers".

    Each point takes the smaller of its two residuals (r = 2 * views; d = 2; k = 16 per homography pair for
    triplets, 8 per homography for pairs). This is the degenerate alternative to the epipolar model when an
    independently moving, roughly planar (or distant) object is present: the more flexible epipolar model can
    absorb such an object as apparent parallax and then wins against a single homography, which counts the object
    as outliers. Returns ``(gric, e2 of the second homography)``, or None when too few outliers remain or no
    second homography can be fitted.
    """
    views = len(points)
    dof = 2 * (views - 1)
    out = e2h > inlier_bound(sigma2, dof)
    if out.sum() < MIN_POINTS:
        return None
    sub = [p[out] for p in points]
    try:
        if views == 3:
            second = fit_homographies(*sub, rng, settings)
            e2 = None if second is None else homography_triplet_error_sq(*second[0], *points)
        else:
            second = fit_homography_pair(*sub, rng, settings)
            e2 = None if second is None else transfer_error_sq(second[0][0], *points) / 2.0
    except (ValueError, np.linalg.LinAlgError):
        return None
    if e2 is None:
        return None
    k = 16 if views == 3 else 8
    return gric(np.minimum(e2h, e2), sigma2, r=2 * views, d=2, k=2 * k), e2


def _unmoved(threshold: float, *points: np.ndarray) -> np.ndarray:
    """Points that moved less than ``threshold`` pixels between every two frames (bool (n,))."""
    moved = np.zeros(len(points[0]))
    for a in range(len(points)):
        for b in range(a + 1, len(points)):
            d = points[b] - points[a]
            moved = np.maximum(moved, np.hypot(d[:, 0], d[:, 1]))
    return moved < threshold


def estimate_triplet(
    x1: np.ndarray,
    x2: np.ndarray,
    x3: np.ndarray,
    rng: np.random.Generator,
    *,
    degeneracy: str = "gric",
    static_threshold: float = 0.25,
    models: tuple[str, ...] = ("trifocal", "homography"),
    settings: RobustSettings = RobustSettings(),
    frame_size: tuple[int, int] | None = None,
) -> FittedModel:
    """The rigid-background model of one triplet of frames, from sampled point triplets.

    Steps: (1) the static-camera test (:func:`is_static`; skew-symmetric F's when static); (2) robust fits
    of the candidate ``models``; (3) with ``degeneracy="gric"`` and both candidates, the one with the lower
    GRIC ([T98]: r = 6, trifocal d = 3, k = 18; homographies d = 2, k = 16; one noise level for both: the
    robust estimate from the trifocal fit, at least ``settings.min_sigma``) is chosen; the homography side
    is the better of one homography pair and two (the dominant plane plus an independently moving one, see
    :func:`_two_homographies_gric`), and the dominant one scores the points. With ``"none"`` the trifocal
    fit is used whenever it exists (the paper). A failed fit falls back to the other candidate; if none can
    be fitted the model is ``"failed"`` with a reason, and the caller skips the triplet.

    ``"parallax"`` (plane + parallax, [IA98]) corrects GRIC's one blind spot for dense trajectories. Near
    rigid structure in front of a far background (the paper's Fig. 1: rocks passed by a translating camera)
    is, to GRIC, a second plane: "two homographies" then costs less than the trifocal model, by ``log r``
    per point for the manifold's extra dimension, however large the parallax, and the rigid rocks get the
    largest distances. Two planes of one rigid scene and a second, independently moving plane whose motion
    mimics parallax (a tracked object under a panning camera) are the same data for any one triplet ([HZ]
    Sec. 13.2: both planes' homographies agree with one epipolar geometry), so the decision needs priors. The
    second plane (:func:`_rigid_second_plane`: points the trifocal model and a second homography explain but
    the dominant one does not) is taken as near rigid structure, and the trifocal model kept, when it holds at
    least ``PARALLAX_MIN_FRACTION`` of the points, moves at least ``PARALLAX_MIN_SPEED_RATIO`` times as far in
    the image as the dominant plane (parallax grows as depth shrinks, so structure in front of the far
    background moves faster; a tracked object moves slower than the background it is followed across) and
    reaches the frame border at least half as often as the points do (``PARALLAX_MIN_BORDER_RATIO``; near
    structure fills the image up to its edges, and a fast background patch framed inside it is more likely an
    object). Otherwise GRIC's choice stands. Needs ``frame_size`` (without it ``"parallax"`` is ``"gric"``).
    The thresholds were set on the synthetic scenes of ``tests/geometry/scenes.py`` (exact ground truth:
    ``parallax_scene`` must keep the trifocal model, ``rotation_scene`` the homography); on the 30 DAVIS-2016
    train sequences the rule changes the ED ROC AUC by less than 0.001 on average
    (``benchmarks/kfold.py --what ed``). Known limit: a rigid second plane that is slower than the dominant
    one (far structure seen through a gap in a near dominant plane) still gets the homography.

    Parameters
    ----------
    x1, x2, x3 : arrays (N, 2)
        Pixel positions of N trajectories (a seeded sample) in the triplet's frames.
    rng : numpy.random.Generator
    degeneracy : {"parallax", "gric", "none"}
    static_threshold : float
        Pixels; see :func:`is_static`.
    models : tuple of {"trifocal", "homography"}
        Candidate models (``("homography",)`` gives the homography baseline).
    frame_size : (height, width), optional
        Pixels; the frame the points lie in (for ``"parallax"``).

    Returns
    -------
    FittedModel
    """
    x1, x2, x3 = (np.asarray(x, dtype=np.float64) for x in (x1, x2, x3))
    n = len(x1)
    if n < MIN_POINTS:
        return FittedModel("failed", fallback=f"too few points ({n} < {MIN_POINTS})")
    if static_threshold > 0 and "trifocal" in models and is_static(x1, x2, x3, threshold=static_threshold):
        return FittedModel("static", static_fundamentals(), inliers=_unmoved(static_threshold, x1, x2, x3))
    fits = {}
    reasons = []
    for name in models:
        fn = fit_trifocal if name == "trifocal" else fit_homographies
        try:
            res = fn(x1, x2, x3, rng, settings)
        except (ValueError, np.linalg.LinAlgError) as exc:  # degenerate data, e.g. all points collinear
            res = None
            reasons.append(f"{name}: {exc}")
        if res is None:
            reasons.append(f"{name}: no non-degenerate sample")
        else:
            fits[name] = res
    if not fits:
        return FittedModel("failed", fallback="; ".join(reasons) or "no model")
    dof = {"trifocal": 3, "homography": 4}
    ref = "trifocal" if "trifocal" in fits else next(iter(fits))
    sigma2 = max(robust_sigma2(fits[ref][1], dof[ref]), SIGMA_FLOOR_PX**2)
    gric_sigma2 = max(sigma2, settings.min_sigma**2)
    scores = {}
    if len(fits) == 2:
        scores = {
            "trifocal": gric(fits["trifocal"][1], gric_sigma2, r=6, d=3, k=18),
            "homography": gric(fits["homography"][1], gric_sigma2, r=6, d=2, k=16),
        }
        two = _two_homographies_gric(fits["homography"][1], (x1, x2, x3), gric_sigma2, rng, settings)
        if two is not None:
            scores["two homographies"] = two[0]
    parallax = None
    if degeneracy in ("gric", "parallax") and len(fits) == 2:
        degenerate = min(scores["homography"], scores.get("two homographies", np.inf))
        kind = "trifocal" if scores["trifocal"] < degenerate else "homography"
        if degeneracy == "parallax" and kind == "homography" and two is not None and frame_size is not None:
            parallax = rigid_second_plane(fits["trifocal"][1], fits["homography"][1], two[1], x1, x3,
                                           gric_sigma2, frame_size)
            if is_parallax(parallax):
                kind = "trifocal"
    elif degeneracy in DEGENERACY:
        kind = "trifocal" if "trifocal" in fits else next(iter(fits))
    else:
        raise ValueError(f"degeneracy must be one of {', '.join(DEGENERACY)}, got {degeneracy!r}")
    mats, e2, _ = fits[kind]
    inliers = e2 <= inlier_bound(gric_sigma2, dof[kind])
    general = None
    if kind != "trifocal" and "trifocal" in fits:
        t_e2 = fits["trifocal"][1]
        general = FittedModel("trifocal", tuple(fits["trifocal"][0]), inliers=t_e2 <= inlier_bound(gric_sigma2, 3))
    return FittedModel(
        kind, tuple(mats), sigma=float(np.sqrt(sigma2)), inlier_ratio=float(inliers.mean()),
        trials=sum(f[2] for f in fits.values()), gric=scores, fallback="; ".join(reasons) or None, inliers=inliers,
        general=general, parallax=parallax,
    )


def estimate_pair(
    x1: np.ndarray,
    x2: np.ndarray,
    rng: np.random.Generator,
    *,
    degeneracy: str = "gric",
    static_threshold: float = 0.25,
    threshold: float = 1.0,
    settings: RobustSettings = RobustSettings(),
) -> FittedModel:
    """The rigid-background model of a pair of frames: a fundamental matrix (USAC/MAGSAC++ with
    ``threshold`` pixels) or, with ``degeneracy="gric"``, a homography when GRIC prefers it ([T98]: r = 4;
    F: d = 3, k = 7; H: d = 2, k = 8). Static pairs get a fixed skew-symmetric F (the paper's rule)."""
    x1, x2 = (np.asarray(x, dtype=np.float64) for x in (x1, x2))
    n = len(x1)
    if n < MIN_POINTS:
        return FittedModel("failed", fallback=f"too few points ({n} < {MIN_POINTS})")
    if static_threshold > 0 and is_static(x1, x2, threshold=static_threshold):
        # one skew-symmetric F is blind to motion along one direction, so a static pair uses the identity
        # homography: the score is twice the displacement
        return FittedModel("static", (np.eye(3),), inliers=_unmoved(static_threshold, x1, x2))
    fit_f = fit_fundamental(x1, x2, rng, threshold=threshold)
    if degeneracy not in ("gric", "none"):
        raise ValueError(f"degeneracy must be 'gric' or 'none', got {degeneracy!r}")
    fit_h = fit_homography_pair(x1, x2, rng, settings) if (degeneracy == "gric" or fit_f is None) else None
    if fit_f is None and fit_h is None:
        return FittedModel("failed", fallback="no fundamental matrix or homography could be fitted")
    ref = fit_f if fit_f is not None else fit_h
    sigma2 = max(robust_sigma2(ref[1], 1 if fit_f is not None else 2), SIGMA_FLOOR_PX**2)
    gric_sigma2 = max(sigma2, settings.min_sigma**2)
    scores = {}
    if fit_f is not None and fit_h is not None:
        scores = {
            "fundamental": gric(fit_f[1], gric_sigma2, r=4, d=3, k=7),
            "homography": gric(fit_h[1], gric_sigma2, r=4, d=2, k=8),
        }
        two = _two_homographies_gric(fit_h[1], (x1, x2), gric_sigma2, rng, settings)
        if two is not None:
            scores["two homographies"] = two[0]
    degenerate = min(scores.get("homography", np.inf), scores.get("two homographies", np.inf))
    if fit_f is None:
        kind, (mats, e2), fallback = "homography", fit_h, "fundamental matrix fit failed"
    elif degeneracy == "gric" and scores and degenerate <= scores["fundamental"]:
        kind, (mats, e2), fallback = "homography", fit_h, None
    else:
        kind, (mats, e2), fallback = "fundamental", fit_f, None
    inliers = e2 <= inlier_bound(gric_sigma2, 1 if kind == "fundamental" else 2)
    general = None
    if kind != "fundamental" and fit_f is not None:
        general = FittedModel("fundamental", tuple(fit_f[0]), inliers=fit_f[1] <= inlier_bound(gric_sigma2, 1))
    return FittedModel(kind, tuple(mats), sigma=float(np.sqrt(sigma2)), inlier_ratio=float(inliers.mean()),
                       gric=scores, fallback=fallback, inliers=inliers, general=general)
