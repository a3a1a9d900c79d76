"""The common skeleton of the rigidity stages (trifocal, homography, fundamental) and their shared parameters."""

from __future__ import annotations

from abc import ABC, abstractmethod
import logging

import numpy as np

from ..core.params import Param
from ..core.types import FlowPair, RigidityResult, TrackWindow, Trajectories
from .scoring import SAMPLING, SamplingHistory, check_rigidity_inputs, ed_maps_from_scores, frame_groups, score_frame_groups
from .fits import FittedModel, RobustSettings

__all__ = ["RigidityStage", "GROUP_PARAMS", "STATIC_PARAMS", "ROBUST_PARAMS", "GRIC_PARAMS"]

log = logging.getLogger(__name__)

#: Parameters every rigidity stage has (schema defaults equal the constructors' defaults).
GROUP_PARAMS = (
    Param("max_points", "int", 10000, "trajectories sampled per frame group to fit its model", minimum=20),
    Param("stride", "int", 1, "frame gap k of the groups (t, t+k, t+2k): wider groups see more parallax", minimum=1),
    Param(
        "sampling",
        "choice",
        "guided",
        "how the fitted sample is drawn: 'guided' down-weights trajectories that earlier groups found moving "
        "(so a large or absorbed object cannot capture the background model); 'area' also weights each by the "
        "inverse of the trajectories around it, so the sample covers the frame evenly where trajectories "
        "survive unevenly; 'uniform' (the paper)",
        choices=SAMPLING,
    ),
    Param(
        "border_prior",
        "float",
        0.15,
        "with guided sampling: width of the frame-border band (fraction of the shorter side) whose points are "
        "sampled up to 10 times as often as interior ones, the frame's edges being mostly background (so a "
        "large object does not capture the background model); 0 disables it",
        minimum=0.0,
        maximum=0.5,
    ),
    Param(
        "prior_groups",
        "float",
        0.0,
        "how many frame groups' worth of the typical distance a trajectory's mean starts from: the maps paint "
        "(sum + k * median) / (groups + k), the video's median of the trajectories' means (a stream's: of those "
        "in flight), so that a trajectory scored in few groups (spray, blur, an occlusion edge) is pulled toward "
        "the typical distance and a long one keeps its own; 0: the plain mean (the paper)",
        minimum=0.0,
    ),
)

#: The static-camera test (stages with an epipolar model).
STATIC_PARAMS = (
    Param(
        "static_threshold",
        "float",
        0.25,
        "pixels: a point moving less than this between every two frames of a group 'did not move'; a group "
        "where at least half the points did not move is a static camera (0 disables the test)",
        minimum=0.0,
    ),
)

#: Model selection (stages that can choose a homography for degenerate motion).
GRIC_PARAMS = (
    Param(
        "min_sigma",
        "float",
        0.5,
        "pixels: the lowest noise level GRIC and the RANSAC trial counts assume, and the trifocal search's MSAC "
        "threshold (RMS per point); motion that homographies explain to within about this counts as degenerate "
        "for the epipolar model",
        minimum=0.0,
    ),
)

#: Parameters of the seeded RANSAC fits.
ROBUST_PARAMS = (
    Param(
        "confidence", "float", 0.99, "RANSAC confidence of drawing one all-inlier sample", minimum=0.5, maximum=0.999999
    ),
    Param("max_trials", "int", 1000, "RANSAC trial cap per fit", minimum=1),
    Param(
        "threshold",
        "float",
        None,
        "inlier threshold in pixels (RMS first-order residual per point); null: adaptive, LMedS scoring (the "
        "trifocal stage's six-point search: MSAC at min_sigma, robust to a dominant plane) with the 95% chi-square "
        "bound of the robust noise estimate",
        minimum=0.0,
        exclusive_min=True,
        nullable=True,
    ),
)


class RigidityStage(ABC):
    """Template of a rigidity stage: groups of ``views`` frames, one model per group, per-trajectory means,
    ED maps. Subclasses set ``views`` and implement :meth:`estimate`. The run loop calls :meth:`score_groups`
    (the totals of a window of its frames), a whole-video call :meth:`score`: a subclass that changes what is
    scored overrides both."""

    views = 3

    def __init__(
        self,
        *,
        max_points: int = 10000,
        stride: int = 1,
        sampling: str = "guided",
        border_prior: float = 0.15,
        prior_groups: float = 0.0,
        static_threshold: float = 0.25,
        confidence: float = 0.99,
        max_trials: int = 1000,
        threshold: float | None = None,
        min_sigma: float = 0.5,
    ):
        if max_points < 20:
            raise ValueError(f"max_points must be >= 20, got {max_points}")
        if stride < 1:
            raise ValueError(f"stride must be >= 1, got {stride}")
        if sampling not in SAMPLING:
            raise ValueError(f"sampling must be one of {', '.join(SAMPLING)}, got {sampling!r}")
        if not 0.0 <= border_prior <= 0.5:
            raise ValueError(f"border_prior must be in [0, 0.5], got {border_prior}")
        if not prior_groups >= 0:
            raise ValueError(f"prior_groups must be >= 0, got {prior_groups}")
        self.prior_groups = float(prior_groups)
        self.sampling = sampling
        self.border_prior = float(border_prior)
        self.max_points = int(max_points)
        self.stride = int(stride)
        self.static_threshold = float(static_threshold)
        self.settings = RobustSettings(
            confidence=float(confidence),
            max_trials=int(max_trials),
            threshold=None if threshold is None else float(threshold),
            min_sigma=float(min_sigma),
        )

    @abstractmethod
    def estimate(self, points: list[np.ndarray], rng: np.random.Generator,
                 frame_size: tuple[int, int] | None = None) -> FittedModel:
        """The fitted model of one frame group's point tracks (a subclass's estimator); ``frame_size`` is the
        frames' ``(height, width)`` in pixels."""

    def new_history(self) -> SamplingHistory:
        """An empty memory of guided sampling, for a stream to pass to every window of one video."""
        return SamplingHistory()

    def score(self, trajectories: Trajectories, flow: FlowPair | None, rng: np.random.Generator, *,
              history: SamplingHistory | None = None, track_ids: np.ndarray | None = None) -> RigidityResult:
        """Per-pixel distance maps float32 ``(F, H, W)`` in pixels, per-trajectory means and per-group records.

        A stream passes ``history`` and ``track_ids`` (the trajectories' global ids) to carry guided
        sampling's memory across its windows (:func:`~eponet.geometry.scoring.score_frame_groups`).

        Raises :class:`~eponet.core.errors.InputError` for fewer than 3 frames or flow that does not match
        the trajectories.
        """
        check_rigidity_inputs(trajectories, flow, self.views)
        sums, counts, infos = self._score_groups(trajectories, rng, history, track_ids)
        per_trajectory, ed = ed_maps_from_scores(trajectories, sums, counts, prior_groups=self.prior_groups)
        return RigidityResult(ed=ed, per_trajectory=per_trajectory, triplets=infos)

    def score_groups(self, window: TrackWindow, rng: np.random.Generator, *,
                     history: SamplingHistory | None = None,
                     track_ids: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, list[dict]]:
        """What :meth:`score` computes before painting, on a stream's window of frames read as they are: every
        trajectory's summed distance float64 ``(T,)`` in pixels, its number of scored groups int32 ``(T,)``
        (``T``: the window's trajectories, ``window.ids``) and one record per group (``frames`` window-local,
        ``model``, diagnostics). The run loop accumulates these across its windows and paints each frame once
        from the totals, so it calls this instead of :meth:`score`: no trajectories assembled, no flow, no maps."""
        check_rigidity_inputs(window, None, self.views)
        return self._score_groups(window, rng, history, track_ids)

    def _score_groups(self, trajectories, rng, history, track_ids):
        groups = frame_groups(trajectories.num_frames, self.views, self.stride)
        if groups and groups[0][1] - groups[0][0] != self.stride:
            log.warning("video of %d frames is too short for stride %d; using %d",
                        trajectories.num_frames, self.stride, groups[0][1] - groups[0][0])
        # tracks without a pixel grid (labels of 1 x 1, e.g. Hopkins155's feature tracks) have no frame border
        frame_size = tuple(trajectories.frame_shape) if min(trajectories.frame_shape) > 1 else None

        def estimate(points, generator):
            return self.estimate(points, generator, frame_size)

        return score_frame_groups(
            trajectories, groups, estimate, rng, max_points=self.max_points, sampling=self.sampling,
            border=self.border_prior, history=history, track_ids=track_ids,
        )
