"""Geometry as pure, vectorised functions: flow consistency, dense trajectories, epipolar / trifocal /
homography estimation, robust fitting and model selection, and ED maps.

Every function documents its array shapes and units (pixels, ``(x, y)`` order, see
:mod:`eponet.core.types`) and cites Hartley & Zisserman, *Multiple View Geometry*, 2nd ed. ([HZ]) by
algorithm number where one applies.
"""

from .consistency import (
    exact_round_trip,
    fb_consistent_points,
    forward_backward_consistency,
    round_half_up,
    sample_bilinear,
)
from .epipolar import (
    epipolar_line_distances,
    fundamental_from_cameras,
    homogeneous,
    camera_centre,
    null_vector,
    point_line_distance,
    rank2_null_vector,
    sampson_error,
    skew,
    static_fundamentals,
    symmetric_epipolar_distance,
)
from .homography import (
    homography_dlt,
    homography_four_point,
    homography_triplet_distance,
    homography_triplet_error_sq,
    transfer,
    transfer_error_sq,
)
from .normalise import hartley_normalisation
from .rigidity import GRIC_PARAMS, GROUP_PARAMS, ROBUST_PARAMS, STATIC_PARAMS, RigidityStage
from .robust import draw_samples, gric, inlier_bound, ransac_trial_count, robust_search, robust_sigma2
from .scoring import SamplingHistory, check_rigidity_inputs, ed_maps_from_scores, frame_groups, score_frame_groups
from .trajectories import (
    alive_in_frames,
    build_dense_trajectories,
    fill_from_neighbourhood,
    paint_trajectory_values,
    trajectory_ends,
    trajectory_positions,
)
from .trifocal import (
    cameras_from_trifocal,
    epipoles_from_trifocal,
    fundamentals_from_trifocal,
    normalise_cameras,
    transform_trifocal,
    trifocal_from_cameras,
    trifocal_linear,
    trifocal_residual,
    trifocal_six_point,
    trifocal_transfer,
    triplet_epipolar_distance,
    triplet_sampson_error,
)
from .fits import (
    FittedModel,
    RobustSettings,
    fit_fundamental,
    fit_homographies,
    fit_homography_pair,
    fit_trifocal,
)
from .triplets import estimate_pair, estimate_triplet, is_static

__all__ = [
    # consistency
    "sample_bilinear",
    "round_half_up",
    "fb_consistent_points",
    "exact_round_trip",
    "forward_backward_consistency",
    # trajectories
    "build_dense_trajectories",
    "trajectory_ends",
    "alive_in_frames",
    "trajectory_positions",
    "paint_trajectory_values",
    "fill_from_neighbourhood",
    # epipolar
    "homogeneous",
    "skew",
    "null_vector",
    "rank2_null_vector",
    "camera_centre",
    "fundamental_from_cameras",
    "point_line_distance",
    "epipolar_line_distances",
    "symmetric_epipolar_distance",
    "sampson_error",
    "static_fundamentals",
    # trifocal
    "trifocal_from_cameras",
    "normalise_cameras",
    "trifocal_six_point",
    "trifocal_linear",
    "transform_trifocal",
    "epipoles_from_trifocal",
    "fundamentals_from_trifocal",
    "cameras_from_trifocal",
    "trifocal_transfer",
    "trifocal_residual",
    "triplet_epipolar_distance",
    "triplet_sampson_error",
    # homography
    "homography_four_point",
    "homography_dlt",
    "transfer",
    "transfer_error_sq",
    "homography_triplet_error_sq",
    "homography_triplet_distance",
    # robust estimation and model selection
    "ransac_trial_count",
    "draw_samples",
    "robust_sigma2",
    "inlier_bound",
    "gric",
    "robust_search",
    "RobustSettings",
    "FittedModel",
    "is_static",
    "fit_trifocal",
    "fit_homographies",
    "fit_fundamental",
    "fit_homography_pair",
    "estimate_triplet",
    "estimate_pair",
    # scoring and ED maps
    "check_rigidity_inputs",
    "frame_groups",
    "score_frame_groups",
    "SamplingHistory",
    "ed_maps_from_scores",
    # the rigidity stages' common skeleton
    "RigidityStage",
    "GROUP_PARAMS",
    "STATIC_PARAMS",
    "GRIC_PARAMS",
    "ROBUST_PARAMS",
    # normalisation
    "hartley_normalisation",
]
