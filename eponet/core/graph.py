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

from .protocols import (
    AppearanceBackbone,
    FlowEstimator,
    Fusion,
    MotionNet,
    Refiner,
    RigidityModel,
    TrajectoryBuilder,
)

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
