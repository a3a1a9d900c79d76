"""The stage graph, declared once: per stage kind its protocol and method, what it consumes and produces, whether
its results are cached, and the temporal context it needs.

Spec validation (:mod:`eponet.core.spec`), the registry, the run loop (:mod:`eponet.core.pipeline`,
:mod:`eponet.core.stream`), the cache keys and ``eponet plugins`` all read :data:`GRAPH`; nothing else lists the
kinds or their order.

Data items that flow between stages (per frame ``t`` unless stated):

- ``frames``: uint8 RGB at the processing size (from the input; ``full_frames`` at the input size),
- ``flow``: forward ``t -> t+1`` and backward ``t+1 -> t`` fields (:mod:`eponet.core.types`),
- ``trajectories``: dense point trajectories (live state carried from chunk to chunk),
- ``ed``: epipolar distance maps in pixels,
- ``saliency``: the motion net's foreground probability,
- ``features``: appearance features,
- ``fused``: the fusion's foreground probability,
- ``masks``: uint8 {0, 1}.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .protocols import (
    AppearanceBackbone,
    FlowEstimator,
    Fusion,
    MotionNet,
    Refiner,
    RigidityModel,
    TrajectoryBuilder,
)
from .types import FLOW_DTYPE, FlowPair, RigidityResult, TrackFrame, Trajectories, check_shape

__all__ = [
    "CONTEXTS",
    "StageKind",
    "GRAPH",
    "KINDS",
    "OUTPUTS",
    "INPUT_ITEMS",
    "stage_kind",
    "producers",
    "producer_of",
    "missing_needs",
    "check_stage",
    "check_output",
]

#: Temporal contexts a stage can need, and what the run loop does for them:
#:
#: ``pairs``: consecutive frame pairs; the loop hands it chunks of frames overlapping by one frame.
#: ``state``: carries live state from chunk to chunk (trajectories: the points alive at the chunk's end).
#: ``groups``: frame groups ``(t, t+k, ..)`` of ``views`` frames (the stage's ``views`` and ``stride``
#:     attributes, default 3 and 1); the loop hands it windows overlapping by ``(views - 1) * stride`` frames,
#:     each group in exactly one window, and a per-trajectory mean is final when the trajectory ends or, for
#:     painting, once it has run ``run.lag`` frames past the frame painted.
#: ``frame``: one frame at a time (batched by the loop).
#: ``window``: overlapping windows of frames (the stage's ``window`` and ``overlap`` attributes); the loop
#:     hands it each window as soon as its frames exist.
CONTEXTS = ("pairs", "state", "groups", "frame", "window")

#: Items the input provides.
INPUT_ITEMS = ("frames", "full_frames")


@dataclass(frozen=True)
class StageKind:
    """One node of the stage graph.

    ``consumes`` lists the items the stage reads; an entry ``"a|b"`` is satisfied by either (the first present
    wins). ``optional`` items are read when some stage produces them and skipped otherwise (``needed_unless``
    names a parameter value that drops a consumed item, e.g. a motion net on flow alone needs no ED)."""

    kind: str
    protocol: type
    method: str
    consumes: tuple[str, ...]
    produces: str
    cached: bool
    context: str
    doc: str
    #: ``{item: (param, value)}``: the item is not needed when the stage's parameter ``param`` equals ``value``.
    needed_unless: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.context not in CONTEXTS:
            raise ValueError(f"stage kind {self.kind}: unknown context {self.context!r}; contexts: {CONTEXTS}")


#: Stage kinds in pipeline order.
GRAPH: tuple[StageKind, ...] = (
    StageKind("flow", FlowEstimator, "estimate", ("frames",), "flow", cached=True, context="pairs",
              doc="forward and backward optical flow of consecutive frames"),
    StageKind("trajectories", TrajectoryBuilder, "build", ("flow",), "trajectories", cached=False, context="state",
              doc="dense point trajectories covering every pixel of every frame"),
    StageKind("rigidity", RigidityModel, "score", ("trajectories", "flow"), "ed", cached=True, context="groups",
              doc="epipolar distance (ED) maps: each trajectory's mean distance from the rigid background model"),
    StageKind("motion_net", MotionNet, "predict", ("flow", "ed"), "saliency", cached=False, context="frame",
              doc="foreground probability from (dx, dy, ED) motion images", needed_unless={"ed": ("inputs", "flow")}),
    StageKind("appearance", AppearanceBackbone, "features", ("frames",), "features", cached=True, context="frame",
              doc="appearance features of the frames"),
    StageKind("fusion", Fusion, "fuse", ("features", "saliency"), "fused", cached=False, context="window",
              doc="foreground probability from appearance features and the motion saliency"),
    StageKind("refiner", Refiner, "refine", ("full_frames", "fused|saliency"), "masks", cached=False, context="frame",
              doc="binary masks from the frames and the foreground probability"),
)

KINDS: tuple[str, ...] = tuple(node.kind for node in GRAPH)
_BY_KIND = {node.kind: node for node in GRAPH}

#: What each ``output.save`` item needs (a data item some stage produces).
OUTPUTS: dict[str, str] = {
    "masks": "masks",
    "saliency": "saliency",
    "ed": "ed",
    "flow": "flow",
    "motion_images": "ed",
    "overlay": "masks",
    "panels": "flow",
    "report": "frames",  # index.html of the whole run (eponet.core.html_report); shows what the others saved
}


def stage_kind(kind: str) -> StageKind:
    """The node of ``kind`` (``KeyError`` for an unknown kind)."""
    return _BY_KIND[kind]


def producers(kinds) -> dict[str, str]:
    """``{item: kind}`` of what the stages ``kinds`` (and the input) produce."""
    made = {item: "input" for item in INPUT_ITEMS}
    made.update({_BY_KIND[k].produces: k for k in kinds if k in _BY_KIND})
    return made


def missing_needs(stages: dict[str, dict]) -> list[str]:
    """Problems of a composition ``{kind: params}``: every consumed item must be produced upstream.

    Returns one ``stages.<kind>: ...`` line per unmet need, in pipeline order."""
    problems = []
    made = producers(stages)
    for node in GRAPH:
        if node.kind not in stages:
            continue
        params = stages[node.kind] or {}
        for need in node.consumes:
            unless = node.needed_unless.get(need)
            if unless is not None and params.get(unless[0]) == unless[1]:
                continue
            options = need.split("|")
            if not any(option in made for option in options):
                problems.append(f"stages.{node.kind}: needs {_describe(options)}, which the spec does not have")
    return problems


def producer_of(item: str) -> str | None:
    """The kind that produces ``item`` (``None`` for an input item or an unknown one)."""
    return next((node.kind for node in GRAPH if node.produces == item), None)


def _describe(items: list[str]) -> str:
    kinds = sorted((producer_of(item) or item for item in items), key=lambda k: KINDS.index(k) if k in KINDS else -1)
    return f"a {' or '.join(kinds)} stage"


def check_stage(kind: str, plugin: str, stage) -> str | None:
    """Why the built ``stage`` does not implement its kind's protocol (one line naming the plugin and the
    method), or ``None``."""
    node = _BY_KIND[kind]
    if not callable(getattr(stage, node.method, None)):
        return (f"stages.{kind}: plugin {plugin!r} does not implement the {kind} protocol: it has no method "
                f"{node.method}() ({node.protocol.__name__})")
    return None


# -- what each stage returns ----------------------------------------------------------------------
def check_output(kind: str, plugin: str, value, *, frames: int | None, shape: tuple[int, int],
                 trajectories: int | None = None) -> str | None:
    """Why what a ``kind`` stage returned breaks its protocol (one line naming the kind, the plugin and what was
    expected), or ``None``.

    ``frames`` is the leading size the run loop expects (frames, or flow pairs), ``shape`` the ``(H, W)`` of the
    maps, ``trajectories`` the rigidity's trajectory count. Cheap: shapes and dtypes, and a min/max only where the
    protocol bounds the values (no copy of an array).

    >>> check_output("refiner", "floaty", np.full((2, 4, 5), 0.99), frames=2, shape=(4, 5))
    "stage refiner (plugin 'floaty') returned masks: expected dtype uint8, got float64"
    """
    problem = _OUTPUT_CHECKS[kind](value, frames, tuple(shape), trajectories)
    return f"stage {kind} (plugin {plugin!r}) returned {problem}" if problem else None


def _array(name: str, value, dims: list, dtype, *, low: float | None = None, high: float | None = None,
           finite: bool = False) -> str | None:
    """Why ``value`` is not a ``dtype`` array of layout ``dims`` (:func:`~eponet.core.types.check_shape`) with
    values in ``[low, high]`` (and finite when ``finite``), or ``None``."""
    if not isinstance(value, np.ndarray):
        return f"{name} as a {type(value).__name__}, expected a numpy {np.dtype(dtype).name} array {dims}"
    try:
        check_shape(name, value, dims, dtype)
    except ValueError as exc:
        return str(exc)
    if value.size == 0 or (low is None and high is None and not finite):
        return None
    lo, hi = value.min(), value.max()  # a NaN anywhere makes both NaN
    if np.isnan(lo) or np.isnan(hi) or (finite and not (np.isfinite(lo) and np.isfinite(hi))):
        return f"{name} with NaN or infinite values, expected finite values"
    if (low is not None and lo < low) or (high is not None and hi > high):
        bounds = f"[{low:g}, {high:g}]" if low is not None and high is not None else \
            f">= {low:g}" if low is not None else f"<= {high:g}"
        return f"{name} with values in [{lo:g}, {hi:g}], expected {bounds}"
    return None


def _type(value, expected: str) -> str:
    return f"a {type(value).__name__}, expected {expected}"


def _flow(value, frames, shape, _):
    if not isinstance(value, FlowPair):
        return _type(value, "a FlowPair")
    return (_array("forward flow", value.forward, [frames, *shape, 2], FLOW_DTYPE, finite=True)
            or _array("backward flow", value.backward, [frames, *shape, 2], FLOW_DTYPE, finite=True))


def _trajectories(value, frames, shape, _):
    if isinstance(value, TrackFrame):  # one frame of a TrajectoryStream
        return (_array("ids", value.ids, ["N"], np.int32)
                or _array("positions", value.positions, [len(value.ids), 2], np.float32)
                or _array("labels", value.labels, list(shape), np.int32, low=0))
    if not isinstance(value, Trajectories):
        return _type(value, "Trajectories (build) or a TrackFrame (a stream's first / push)")
    return (_array("start", value.start, ["T"], np.int32)
            or _array("length", value.length, [len(value.start)], np.int32)
            or _array("offsets", value.offsets, [len(value.start) + 1], np.int64)
            or _array("positions", value.positions, ["N", 2], np.float32)
            or _array("labels", value.labels, [frames, *shape], np.int32, low=0, high=len(value.start) - 1))


def _rigidity(value, frames, shape, trajectories):
    if isinstance(value, tuple):  # score_groups: (sums, counts, records) of a window's trajectories
        if len(value) != 3:
            return _type(value, "(sums, counts, records) from score_groups")
        sums, counts, records = value
        if not isinstance(records, list) or not all(isinstance(r, dict) and isinstance(r.get("frames"), list)
                                                    for r in records):
            return "records that are not a list of dicts with frames, expected one per frame group"
        return (_array("sums", sums, [trajectories], np.float64, low=0.0, finite=True)
                or _array("counts", counts, [trajectories], np.int32, low=0))
    if not isinstance(value, RigidityResult):
        return _type(value, "a RigidityResult")
    if value.per_trajectory is not None:
        problem = _array("per_trajectory", value.per_trajectory, [trajectories], np.float32)
        if problem:
            return problem
    return _array("ed", value.ed, [frames, *shape], np.float32, low=0.0, finite=True)


def _maps(name: str, dtype, low, high):
    """The check of a per-frame map output: ``dtype`` ``(F, H, W)`` with values in ``[low, high]``."""
    return lambda value, frames, shape, _: _array(name, value, [frames, *shape], dtype, low=low, high=high)


_OUTPUT_CHECKS = {
    "flow": _flow,
    "trajectories": _trajectories,
    "rigidity": _rigidity,
    "motion_net": _maps("saliency", np.float32, 0.0, 1.0),
    "appearance": lambda value, frames, shape, _: _array("features", value, [frames, "C", "h", "w"], np.float32),
    "fusion": _maps("fused", np.float32, 0.0, 1.0),
    "refiner": _maps("masks", np.uint8, None, 1),
}
assert set(_OUTPUT_CHECKS) == set(KINDS), "every stage kind has an output check"
