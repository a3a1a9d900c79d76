"""Per-triplet (and per-pair) rigid-background models: the static-camera test and GRIC model selection among
the robust fits of :mod:`eponet.geometry.fits`, whose per-point distances make up the epipolar-distance (ED) maps.

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
"""

from __future__ import annotations

import numpy as np

from .epipolar import static_fundamentals
from .fits import (
    MIN_POINTS,
    SIGMA_FLOOR_PX,
    FittedModel,
    RobustSettings,
    fit_fundamental,
    fit_homographies,
    fit_homography_pair,
    fit_trifocal,
)
from .homography import homography_triplet_error_sq, transfer_error_sq
from .parallax import is_parallax, rigid_second_plane
from .robust import gric, inlier_bound, robust_sigma2

#: The choices of ``degeneracy`` (see :func:`estimate_triplet`).
DEGENERACY = ("parallax", "gric", "none")

__all__ = [
    "DEGENERACY",
    "is_static",
    "estimate_triplet",
    "estimate_pair",
]


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
