"""One small protocol per stage kind: what goes in, what comes out, with shapes and units.

Conventions (flow direction, x/y order, dtypes) are in :mod:`eponet.core.types`. Every stage is built by its
plugin's factory from validated keyword parameters; stochastic stages take a seeded
``numpy.random.Generator`` so that a run is reproducible. What each method returns is checked against the shapes,
dtypes and ranges stated here as it returns (:func:`eponet.core.graph.check_output`).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from .types import FlowPair, RigidityResult, TrackFrame, Trajectories, Video

__all__ = [
    "FlowEstimator",
    "TrajectoryBuilder",
    "TrajectoryStream",
    "RigidityModel",
    "MotionNet",
    "AppearanceBackbone",
    "Fusion",
    "Refiner",
]

# The kinds, their order, what each consumes and produces and its method: eponet.core.graph.GRAPH.


@runtime_checkable
class FlowEstimator(Protocol):
    def estimate(self, video: Video) -> FlowPair:
        """Forward and backward flow between consecutive frames of ``video.frames``.

        Returns float32 ``(F-1, H, W, 2)`` fields in pixels of the processing resolution.
        """


@runtime_checkable
class TrajectoryBuilder(Protocol):
    def build(self, flow: FlowPair) -> Trajectories:
        """Dense trajectories covering every pixel of every frame (``labels`` is ``(F, H, W)``).

        A builder may also offer ``stream(shape) -> TrajectoryStream`` (shape ``(H, W)``): then the run loop
        carries its live state from chunk to chunk and never holds the whole video's trajectories; without
        it the loop calls ``build`` on the whole video's flow (memory grows with the video). A stream whose
        attributes are numpy arrays and plain values (as the built-in one's are) is checkpointed, so that a killed
        run resumes the video (:mod:`eponet.core.rigidity_stream`)."""


@runtime_checkable
class TrajectoryStream(Protocol):
    """The live state of a trajectory builder over a stream of flow pairs (see
    :class:`eponet.core.types.TrackFrame`); ids are numbered in birth order over the whole stream."""

    def first(self) -> TrackFrame:
        """Frame 0's trajectories."""

    def push(self, forward: np.ndarray, backward: np.ndarray) -> TrackFrame:
        """Frame t+1's trajectories, given the pair ``forward[t]``, ``backward[t]`` ``(H, W, 2)``."""


@runtime_checkable
class RigidityModel(Protocol):
    def score(self, trajectories: Trajectories, flow: FlowPair, rng: np.random.Generator) -> RigidityResult:
        """Per-pixel epipolar distance (or model residual) maps, float32 ``(F, H, W)`` in pixels.

        The run loop calls it on windows of a stream (``trajectories`` and ``flow`` of a few dozen frames,
        consecutive windows sharing ``(views - 1) * stride`` frames, the stage's optional attributes, default
        3 and 1) with one generator drawn in order over the windows. When ``per_trajectory`` is given and each
        ``triplets`` record has ``frames`` (window-local) and ``model`` (``"failed"``: not scored), a
        trajectory's mean is accumulated over all of its groups across windows (and shrunk toward the median
        of the means in flight by the stage's optional ``prior_groups``, default 0:
        :func:`eponet.core.motion.shrunk_means`); otherwise each window's ``ed`` is used as it is.

        A stage that learns from earlier groups (guided sampling) may also have ``new_history()``: the loop
        then calls it once per video and passes the object to every window as ``score(..., history=h,
        track_ids=ids)`` (``ids``: int64 ``(T,)``, the window's trajectories' global ids, ascending), and calls
        ``h.keep(alive_ids)`` when trajectories end, so that windows see what a whole-video call would. The
        history is checkpointed with the trajectories' state when its attributes are arrays and plain values.

        A stage may also have ``score_groups(window, rng, **same keywords)`` returning ``(sums, counts,
        triplets)``: each of the window's trajectories' summed distance (pixels) and number of scored groups over
        its groups, and the records. ``window`` is the stream's frames as they are, a
        :class:`~eponet.core.types.TrackWindow` (``ids``, ``count``, ``num_frames``, ``frame_shape`` and
        ``group(frames)``: the trajectories present in every frame of a group and their positions). The loop
        then calls it instead of ``score`` and accumulates the totals directly: no trajectories are assembled,
        no flow is stacked and no maps are painted for a window. The built-in stages have it."""


@runtime_checkable
class MotionNet(Protocol):
    def predict(self, motion_images: np.ndarray) -> np.ndarray:
        """Foreground probability float32 ``(F, H, W)`` in [0, 1] from motion images float32 ``(F, 3, H, W)``
        holding normalised (dx, dy, ED): flow / ``FLOW_SCALE`` and ED scaled so that the 95th percentile of the
        frames around each frame is 250/255, not clipped above (``eponet.core.motion.normalise_ed(...,
        saturate=False)``); the network saturates ED itself (``eponet.core.motion.encode_ed``)."""


@runtime_checkable
class AppearanceBackbone(Protocol):
    def features(self, video: Video) -> np.ndarray:
        """Appearance features float32 ``(F, C, h, w)`` of ``video.frames`` on a grid ``h x w`` of the stage's
        choosing (e.g. stride 8); ``C`` may be 0 (no appearance: the shape still gives the fusion its grid)."""


@runtime_checkable
class Fusion(Protocol):
    def fuse(self, features: np.ndarray, saliency: np.ndarray) -> np.ndarray:
        """Foreground probability float32 ``(F, H, W)`` from appearance ``features`` ``(F, C, h, w)`` and the
        motion ``saliency`` ``(F, H, W)``; the output has the saliency's size."""


@runtime_checkable
class Refiner(Protocol):
    def refine(self, frames: np.ndarray, probability: np.ndarray) -> np.ndarray:
        """Binary masks uint8 ``(F, H, W)`` in {0, 1} from RGB ``frames`` uint8 ``(F, H, W, 3)`` and the
        foreground ``probability`` float32 ``(F, H, W)``, both at the input frame size.

        A refiner may have an attribute ``temporal`` (default 0): when it is 1 the run loop averages each frame's
        probability with its neighbours' warped into it along the flow before resizing it and handing it over
        (:func:`eponet.core.temporal.temporal_mean`), one frame of look-ahead."""
