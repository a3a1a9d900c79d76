"""A test kit for stage plugins: :func:`check_stage` builds a stage, runs it on generated inputs of its kind and
asserts the kind's protocol, as scikit-learn's ``check_estimator`` does for estimators.

A plugin's test suite needs one line per stage (README, "Writing a plugin")::

    from eponet.testing import check_stage

    def test_myflow_keeps_the_flow_protocol():
        check_stage("flow", "myflow")               # by its registry name, once installed
        check_stage("flow", "myflow", window=21)    # with parameters, as a spec gives them

What is checked (:class:`StageReport` lists what ran): the parameter schema against the factory's signature,
the kind's method (:func:`eponet.core.graph.check_stage`), the attributes the run loop reads, every output against
the protocol as the run loop checks it (:func:`eponet.core.graph.check_output`: shapes, dtypes, value ranges),
that the stage leaves its inputs unchanged, that two builds give identical outputs on the same inputs (with the
same seed), and that an unknown parameter and a wrongly typed one are one-line :class:`~eponet.core.errors.SpecError`
lines naming the parameter. The inputs (:func:`sample_inputs`) are a small synthetic scene with exact flow
(:func:`eponet.synth.generate_clip`): 5 frames of 64x48 px by default, so that a check takes about a second
(plus the stage's own start-up, e.g. loading a network).

>>> report = check_stage("refiner", "threshold", threshold=0.4)
>>> report.checks
('schema', 'protocol', 'outputs', 'inputs', 'determinism', 'unknown parameter', 'parameter types')
"""

from __future__ import annotations

import copy
import functools
import inspect
import json
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any, Callable

import numpy as np

from .core.errors import EponetError, SpecError
from .core.graph import KINDS, check_output
from .core.graph import check_stage as _protocol_problem
from .core.hookspecs import StageSpec
from .core.motion import motion_images, normalise_ed
from .core.params import validate_params
from .core.types import MIN_FRAMES, MIN_SIDE, FlowPair, Trajectories, Video, assemble_trajectories

__all__ = ["check_stage", "sample_inputs", "StageInputs", "StageReport", "StageCheckError"]

#: ED of the synthetic inputs in pixels: the background's (flow noise) and the moving objects'.
SAMPLE_ED_PX = (0.25, 4.0)


class StageCheckError(AssertionError):
    """A stage broke its kind's protocol. The message is one line naming the kind, the plugin and what was wrong;
    ``check`` names the check that failed (one of :attr:`StageReport.checks`' names, or ``build`` / ``run``)."""

    def __init__(self, message: str, *, kind: str, plugin: str, check: str):
        super().__init__(message)
        self.kind, self.plugin, self.check = kind, plugin, check


@dataclass(frozen=True)
class StageReport:
    """What :func:`check_stage` checked: the ``checks`` that passed, in order, and the ``skipped`` ones with why."""

    kind: str
    plugin: str
    checks: tuple[str, ...]
    skipped: dict[str, str] = field(default_factory=dict)


# -- the generated inputs -------------------------------------------------------------------------
@dataclass
class StageInputs:
    """Inputs of every stage kind, made from one synthetic scene (:func:`sample_inputs`); conventions are
    :mod:`eponet.core.types`'.

    ``video`` (frames uint8 ``(F, H, W, 3)``, also as ``full_frames``: processing and input size are equal),
    ``flow`` the scene's exact forward and backward flow float32 ``(F-1, H, W, 2)``, ``trajectories`` the dense
    trajectories of that flow, ``ed`` float32 ``(F, H, W)`` px (:data:`SAMPLE_ED_PX`: background and the moving
    objects), ``motion_images`` float32 ``(F, 3, H, W)`` as the run loop makes them (flow / 20, ED scaled
    unsaturated), ``saliency`` float32 ``(F, H, W)`` in [0, 1] (0.9 on the objects, 0.1 elsewhere), and
    :attr:`features`, computed on first use by the ``appearance`` stage (a spec's ``{plugin: NAME, ...}``;
    default: the ``epo+`` preset's, whose features the built-in fusion was trained on). ``seed`` seeds the
    generator a rigidity stage is given."""

    video: Video
    flow: FlowPair
    trajectories: Trajectories
    ed: np.ndarray
    motion_images: np.ndarray
    saliency: np.ndarray
    seed: int = 0
    appearance: dict | None = None
    _features: np.ndarray | None = field(default=None, repr=False)

    @property
    def frames(self) -> int:
        return self.video.num_frames

    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the frames and maps."""
        return self.video.shape

    @property
    def features(self) -> np.ndarray:
        """Appearance features float32 ``(F, C, h, w)`` of the frames, at the float16 precision the run loop
        passes on (README, "Cache")."""
        if self._features is None:
            config = json.dumps(self.appearance, sort_keys=True) if self.appearance is not None else None
            self._features = _appearance_features(self.frames, self.shape, self.seed, config)
        return self._features.copy()


def sample_inputs(*, frames: int = 5, shape: tuple[int, int] = (48, 64), seed: int = 0,
                  appearance: dict | None = None) -> StageInputs:
    """The inputs :func:`check_stage` runs a stage on: a synthetic scene of ``frames`` frames of ``shape``
    ``(H, W)`` drawn with ``seed`` (:func:`eponet.synth.generate_clip`; the same arguments give the same
    inputs), see :class:`StageInputs`.

    >>> inputs = sample_inputs()
    >>> inputs.video.frames.shape, inputs.flow.forward.dtype.name, inputs.motion_images.shape
    ((5, 48, 64, 3), 'float32', (5, 3, 48, 64))
    """
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < MIN_FRAMES:
        raise ValueError(f"frames: expected an integer >= {MIN_FRAMES}, got {frames!r}")
    if len(tuple(shape)) != 2 or min(shape) < MIN_SIDE:
        raise ValueError(f"shape: expected (H, W) with sides of at least {MIN_SIDE} px, got {shape!r}")
    clip, tracks = _scene(frames, (int(shape[0]), int(shape[1])), int(seed))
    video = Video("synthetic", clip.frames.copy(), [f"{t:05d}" for t in range(frames)], tuple(shape),
                  full_frames=clip.frames.copy())
    flow = FlowPair(clip.forward.copy(), clip.backward.copy())
    moving = clip.masks.astype(bool)
    ed = np.where(moving, SAMPLE_ED_PX[1], SAMPLE_ED_PX[0]).astype(np.float32)
    return StageInputs(
        video=video, flow=flow, trajectories=copy.deepcopy(tracks), ed=ed,
        motion_images=motion_images(flow, normalise_ed(ed, saturate=False)),
        saliency=np.where(moving, 0.9, 0.1).astype(np.float32), seed=int(seed),
        appearance=dict(appearance) if appearance is not None else None,
    )


@functools.lru_cache(maxsize=4)
def _scene(frames: int, shape: tuple[int, int], seed: int):
    from .geometry.trajectories import build_dense_trajectories
    from .synth import generate_clip

    clip = generate_clip(seed, frames, (shape[1], shape[0]))
    return clip, build_dense_trajectories(clip.forward, clip.backward)


@functools.lru_cache(maxsize=4)
def _appearance_features(frames: int, shape: tuple[int, int], seed: int, config: str | None) -> np.ndarray:
    from .core.registry import get_registry

    registry = get_registry()
    stage = dict(json.loads(config)) if config is not None else dict(registry.resolve_preset("epo+")["appearance"])
    name = stage.pop("plugin", None)
    spec = registry.get("appearance", name, path="appearance.plugin")
    video = sample_inputs(frames=frames, shape=shape, seed=seed).video
    features = _build(spec, stage, "appearance").features(video)
    problem = check_output("appearance", name, features, frames=frames, shape=shape)
    if problem:
        raise EponetError(f"the appearance stage that makes the kit's features: {problem}")
    return features.astype(np.float16).astype(np.float32)


# -- how the run loop calls each kind -------------------------------------------------------------
@dataclass
class _Result:
    """One value a stage returned: the call that gave it and the ``check_output`` sizes it must have."""

    call: str
    value: Any
    frames: int | None
    shape: tuple[int, int]
    trajectories: int | None = None


class _Caller:
    """Calls a stage's methods, naming the call in any failure; watches the inputs for changes when ``watch``."""

    def __init__(self, kind: str, plugin: str, inputs: StageInputs, watch: bool):
        self.kind, self.plugin, self.inputs, self.watch = kind, plugin, inputs, watch

    def __call__(self, call: str, method: Callable, *args, data: dict | None = None, **kwargs):
        """``method(*args, **kwargs)``; ``data`` names the inputs among them that must come back unchanged."""
        data = data or {}
        before = copy.deepcopy(data) if self.watch else {}
        try:
            value = method(*args, **kwargs)
        except Exception as exc:
            frames, (height, width) = self.inputs.frames, self.inputs.shape
            raise StageCheckError(
                f"stage {self.kind} (plugin {self.plugin!r}) raised {type(exc).__name__} in {call} on the kit's "
                f"inputs ({frames} frames of {width}x{height}): {_first_line(exc)}",
                kind=self.kind, plugin=self.plugin, check="run") from exc
        for name, old in before.items():
            changed = _difference(old, data[name], name)
            if changed:
                raise StageCheckError(
                    f"stage {self.kind} (plugin {self.plugin!r}) modified its input in {call} ({changed}); "
                    "stages share their inputs, so copy an array before changing it",
                    kind=self.kind, plugin=self.plugin, check="inputs")
        return value

    def result(self, call: str, method: Callable, data: dict, frames: int | None, shape) -> _Result:
        """The :class:`_Result` of ``method(*data.values())``, the ``data`` watched."""
        return _Result(call, self(call, method, *data.values(), data=data), frames, shape)


def _flow(stage, x: StageInputs, call: _Caller) -> list[_Result]:
    return [call.result("estimate(video)", stage.estimate, {"video": x.video}, x.frames - 1, x.shape)]


def _trajectories(stage, x: StageInputs, call: _Caller) -> list[_Result]:
    results = [call.result("build(flow)", stage.build, {"flow": x.flow}, x.frames, x.shape)]
    if callable(getattr(stage, "stream", None)):  # optional (TrajectoryBuilder): the run loop prefers it
        state = call("stream(shape)", stage.stream, x.shape)
        results.append(call.result("stream(shape).first()", state.first, {}, None, x.shape))
        for t in range(x.frames - 1):
            results.append(call.result(f"stream(shape).push(forward[{t}], backward[{t}])", state.push,
                                       {"forward": x.flow.forward[t], "backward": x.flow.backward[t]}, None, x.shape))
    return results


def _rigidity(stage, x: StageInputs, call: _Caller) -> list[_Result]:
    data, count = {"trajectories": x.trajectories, "flow": x.flow}, x.trajectories.count
    label = "score(trajectories, flow, rng)"
    value = call(label, stage.score, *data.values(), np.random.default_rng(x.seed), data=data)
    results = [_Result(label, value, x.frames, x.shape, count)]
    if callable(getattr(stage, "new_history", None)):  # optional (RigidityModel): a stream's memory
        label = "score(trajectories, flow, rng, history=new_history(), track_ids=ids)"
        value = call(label, stage.score, *data.values(), np.random.default_rng(x.seed), data=data,
                     history=call("new_history()", stage.new_history), track_ids=np.arange(count, dtype=np.int64))
        results.append(_Result(label, value, x.frames, x.shape, count))
    return results


def _motion_net(stage, x: StageInputs, call: _Caller) -> list[_Result]:
    return [call.result("predict(motion_images)", stage.predict, {"motion_images": x.motion_images}, x.frames,
                        x.shape)]


def _appearance(stage, x: StageInputs, call: _Caller) -> list[_Result]:
    return [call.result("features(video)", stage.features, {"video": x.video}, x.frames, x.shape)]


def _fusion(stage, x: StageInputs, call: _Caller) -> list[_Result]:
    return [call.result("fuse(features, saliency)", stage.fuse, {"features": x.features, "saliency": x.saliency},
                        x.frames, x.shape)]


def _refiner(stage, x: StageInputs, call: _Caller) -> list[_Result]:
    return [call.result("refine(frames, probability)", stage.refine,
                        {"frames": x.video.full_frames, "probability": x.saliency}, x.frames, x.shape)]


_CALLS = {"flow": _flow, "trajectories": _trajectories, "rigidity": _rigidity, "motion_net": _motion_net,
          "appearance": _appearance, "fusion": _fusion, "refiner": _refiner}
assert set(_CALLS) == set(KINDS), "the kit calls every stage kind"


def _integer(value, low: int) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= low


def _attributes(kind: str, stage) -> str | None:
    """Why the optional attributes the run loop reads (:data:`eponet.core.graph.CONTEXTS`) are unusable, or ``None``."""
    if kind == "rigidity":
        for name, default, low in (("views", 3, 2), ("stride", 1, 1)):
            value = getattr(stage, name, default)
            if not _integer(value, low):
                return f"has {name} = {value!r}, expected an integer >= {low} (frames per group, group spacing)"
    if kind == "fusion":
        window, overlap = getattr(stage, "window", None), getattr(stage, "overlap", 0) or 0
        if window is not None and not _integer(window, 1):
            return f"has window = {window!r}, expected None (the whole video) or a positive integer"
        if not _integer(overlap, 0) or (window is not None and overlap >= window):
            return f"has overlap = {overlap!r}, expected an integer in [0, window) (window {window!r})"
    return None


def _consistency(kind: str, results: list[_Result]) -> str | None:
    """Why the results of one build disagree where the protocol says they agree, or ``None``."""
    if kind == "trajectories" and len(results) > 1:
        try:
            streamed, _ = assemble_trajectories([r.value for r in results[1:]])
        except ValueError as exc:
            return f"returned stream frames that do not follow each other ({exc})"
        differs = _difference(results[0].value, streamed, "trajectories")
        if differs:
            return f"gives other trajectories through stream(shape) than through build(flow) ({differs})"
    if kind == "rigidity" and len(results) > 1:
        differs = _difference(results[0].value.ed, results[1].value.ed, "ed")
        if differs:
            return ("gives other ED maps with a fresh new_history() than without one on the same whole video "
                    f"({differs})")
    return None


# -- the check ----------------------------------------------------------------------------------------
def check_stage(kind: str, name_or_factory, inputs: StageInputs | None = None, /, **params) -> StageReport:
    """Build a stage, run it on generated inputs of its kind and assert the kind's protocol.

    Parameters
    ----------
    kind : str
        The stage kind (:data:`eponet.core.graph.KINDS`).
    name_or_factory : str, StageSpec or callable
        A registered plugin's name (built-in or installed through the ``eponet.plugins`` entry points), a
        :class:`~eponet.core.hookspecs.StageSpec` (e.g. from the plugin module's ``eponet_stages()``, before it
        is installed), or a factory / class called with ``params`` (no parameter schema: its types go unchecked).
    inputs : StageInputs, optional
        What to run it on (default :func:`sample_inputs`: 5 frames of 64x48 px); positional, so that no plugin
        parameter name is taken.
    **params
        The stage's parameters, as a spec gives them (validated against a StageSpec's ``Param`` schema and its
        ``check=`` first).

    Returns
    -------
    StageReport
        The checks that passed and those skipped (with why).

    Raises
    ------
    StageCheckError
        (an ``AssertionError``) on the first violation: one line naming the kind, the plugin and what was wrong.
    SpecError
        ``params`` the schema or ``check=`` rejects (:class:`~eponet.core.errors.PluginNotFound` for an unknown
        name); the factory's own typed errors (e.g. :class:`~eponet.core.errors.MissingWeights`) pass through.
    """
    if kind not in KINDS:
        raise ValueError(f"unknown stage kind {kind!r}; kinds: {', '.join(KINDS)}")
    spec, plugin = _resolve(kind, name_or_factory)
    inputs = inputs if inputs is not None else sample_inputs()
    passed: list[str] = []
    skipped: dict[str, str] = {}

    def fail(check: str, problem: str) -> StageCheckError:
        return StageCheckError(f"stage {kind} (plugin {plugin!r}) {problem}", kind=kind, plugin=plugin, check=check)

    if spec is not None:
        problem = _schema_problem(spec)
        if problem:
            raise fail("schema", problem)
        passed.append("schema")
    else:
        skipped["schema"] = "a bare factory has no Param schema (give its StageSpec to check the parameters)"

    build = _builder(kind, plugin, spec, name_or_factory, params)
    stage = build()
    problem = _protocol_problem(kind, plugin, stage)
    if problem:
        raise StageCheckError(problem, kind=kind, plugin=plugin, check="protocol")
    passed.append("protocol")
    if kind in ("rigidity", "fusion"):
        problem = _attributes(kind, stage)
        if problem:
            raise fail("attributes", problem)
        passed.append("attributes")

    results = _CALLS[kind](stage, inputs, _Caller(kind, plugin, inputs, watch=True))
    for result in results:
        problem = check_output(kind, plugin, result.value, frames=result.frames, shape=result.shape,
                               trajectories=result.trajectories)
        if problem:
            raise StageCheckError(f"{problem} (from {result.call})", kind=kind, plugin=plugin, check="outputs")
    passed += ["outputs", "inputs"]
    if kind in ("trajectories", "rigidity"):
        problem = _consistency(kind, results)
        if problem:
            raise fail("consistency", problem)
        if len(results) > 1:
            passed.append("consistency")
        else:
            skipped["consistency"] = "no stream()" if kind == "trajectories" else "no new_history()"

    again = _CALLS[kind](build(), inputs, _Caller(kind, plugin, inputs, watch=False))
    for first, second in zip(results, again):
        differs = _difference(first.value, second.value, first.call)
        if differs:
            raise fail("determinism", f"is not deterministic: two builds with the same parameters gave different "
                                      f"outputs on the same inputs and seed ({differs})")
    passed.append("determinism")

    problem = _unknown_parameter_problem(kind, spec, name_or_factory, params)
    if problem:
        raise fail("unknown parameter", problem)
    passed.append("unknown parameter")
    if spec is None:
        skipped["parameter types"] = "a bare factory has no Param schema"
    elif spec.params:
        problem = _parameter_type_problem(kind, spec, params)
        if problem:
            raise fail("parameter types", problem)
        passed.append("parameter types")
    else:
        skipped["parameter types"] = "the stage has no parameters"
    return StageReport(kind, plugin, tuple(passed), skipped)


def _resolve(kind: str, name_or_factory) -> tuple[StageSpec | None, str]:
    """The stage's StageSpec (``None`` for a bare factory) and the plugin name the messages use."""
    if isinstance(name_or_factory, str):
        from .core.registry import get_registry

        spec = get_registry().get(kind, name_or_factory, path=f"stages.{kind}.plugin")
        return spec, spec.name
    if isinstance(name_or_factory, StageSpec):
        if name_or_factory.kind != kind:
            raise ValueError(f"plugin {name_or_factory.name!r} is a {name_or_factory.kind} stage, not a {kind} stage")
        return name_or_factory, name_or_factory.name
    if not callable(name_or_factory):
        raise TypeError(f"name_or_factory: expected a plugin name, a StageSpec or a factory, got "
                        f"{type(name_or_factory).__name__}")
    return None, getattr(name_or_factory, "__qualname__", None) or repr(name_or_factory)


def _builder(kind: str, plugin: str, spec: StageSpec | None, factory, params: dict) -> Callable[[], Any]:
    """A function that builds the stage as the pipeline does (validated parameters, then the factory)."""

    def build():
        try:
            return _build(spec, params, f"stages.{kind}") if spec is not None else factory(**params)
        except (EponetError, StageCheckError):
            raise
        except Exception as exc:
            raise StageCheckError(f"stage {kind} (plugin {plugin!r}) failed to build with parameters {params!r}: "
                                  f"{type(exc).__name__}: {_first_line(exc)}", kind=kind, plugin=plugin,
                                  check="build") from exc

    return build


def _build(spec: StageSpec, params: dict, path: str):
    """``spec``'s stage from ``params`` as a spec's ``stages:`` entry gives them (:class:`SpecError` listing every
    problem of the schema and of ``check=``)."""
    resolved, problems = validate_params(params, spec.params, path)
    if not problems and spec.check is not None:
        problems = [f"{path}.{problem}" for problem in _check_problems(spec, resolved)]
    if problems:
        raise SpecError(problems)
    return spec.factory(**resolved)


def _check_problems(spec: StageSpec, params: dict) -> list[str]:
    """What ``spec.check`` says of validated ``params``; a check that raises, or returns anything but one-line
    strings, is a :class:`StageCheckError` (its problems become a spec's one-line messages)."""

    def fail(problem: str) -> StageCheckError:
        return StageCheckError(f"stage {spec.kind} (plugin {spec.name!r}) has a check= that {problem}; it must return "
                               "a list of '<param>: <what is wrong>' lines", kind=spec.kind, plugin=spec.name,
                               check="schema")

    try:
        problems = spec.check(params)
    except Exception as exc:
        raise fail(f"raised {type(exc).__name__}: {_first_line(exc)}") from exc
    if not isinstance(problems, (list, tuple)):
        raise fail(f"returned a {type(problems).__name__}")
    for problem in problems:
        if not isinstance(problem, str) or not problem.strip() or "\n" in problem:
            raise fail(f"returned {problem!r}")
    return list(problems)


def _schema_problem(spec: StageSpec) -> str | None:
    """Why the ``Param`` schema and the factory's signature disagree (a parameter the factory does not take, a
    required keyword no ``Param`` declares, two defaults), or ``None``."""
    names = [param.name for param in spec.params]
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        return f"declares the parameter {twice[0]!r} twice"
    factory = getattr(spec.factory, "func", spec.factory)  # a functools.partial
    try:
        signature = inspect.signature(spec.factory)
    except (TypeError, ValueError):  # a builtin or C callable: nothing to compare
        return None
    title = f"{getattr(factory, '__qualname__', repr(factory))}()"
    keywords = {name: p for name, p in signature.parameters.items()
                if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
    takes_any = any(p.kind is p.VAR_KEYWORD for p in signature.parameters.values())
    for param in spec.params:
        if param.name not in keywords:
            if not takes_any:
                return f"declares the parameter {param.name!r}, which its factory {title} does not take"
            continue
        default = keywords[param.name].default
        if default is not inspect.Parameter.empty and not param.required and not _equal(default, param.default):
            return (f"declares {param.name!r} with the default {param.default!r}, but its factory {title} has "
                    f"{default!r}; declare it once (e.g. derive the Param from the factory)")
    for name, p in keywords.items():
        if p.default is inspect.Parameter.empty and name not in names:
            return f"has a factory {title} that requires {name!r}, which no Param declares"
    return None


def _unknown_parameter_problem(kind: str, spec: StageSpec | None, factory, params: dict) -> str | None:
    """Why building with one parameter more, unknown, is not a one-line typed error, or ``None``."""
    name = "no_such_parameter"
    while spec is not None and name in {p.name for p in spec.params}:
        name += "_"
    bad = {**params, name: 1}
    try:
        _build(spec, bad, f"stages.{kind}") if spec is not None else factory(**bad)
    except StageCheckError:
        raise
    except Exception as exc:
        expected = f"stages.{kind}.{name}: unknown parameter"
        if spec is not None and not (isinstance(exc, SpecError) and expected in str(exc)):
            return f"answered an unknown parameter {name!r} with {type(exc).__name__}: {_first_line(exc)}"
        return _one_line(exc, f"an unknown parameter {name!r}")
    if spec is not None:
        return f"accepted an unknown parameter {name!r} (the schema must reject it as a one-line SpecError)"
    return (f"accepted an unknown parameter {name!r}; a factory without a Param schema must reject it "
            "(keyword-only arguments do), or declare the parameters in a StageSpec")


#: A value of another type than each ``Param`` type's, for the wrong-type check.
_WRONG_VALUES = {"int": "three", "float": "three", "bool": "yes", "str": 3, "path": 3, "weights": 3,
                 "choice": "<not one of the choices>", "list": "three"}


def _parameter_type_problem(kind: str, spec: StageSpec, params: dict) -> str | None:
    """Why a wrongly typed value of some parameter is not one :class:`SpecError` line naming it, or ``None``."""
    for param in spec.params:
        value = _WRONG_VALUES[param.type]
        where = f"stages.{kind}.{param.name}"
        try:
            _build(spec, {**params, param.name: value}, f"stages.{kind}")
        except SpecError as exc:
            if where not in str(exc):
                return f"answered {param.name}={value!r} with a SpecError that does not name {where}: {exc}"
            problem = _one_line(exc, f"{param.name}={value!r}")
            if problem:
                return problem
            continue
        except StageCheckError:
            raise
        except Exception as exc:
            return (f"answered {param.name}={value!r} with {type(exc).__name__} instead of a SpecError: "
                    f"{_first_line(exc)}")
        return f"accepted {param.name}={value!r}, which is not {param.describe()}"
    return None


def _one_line(exc: Exception, what: str) -> str | None:
    text = str(exc)
    if not text.strip() or "\n" in text:
        return f"answered {what} with a {type(exc).__name__} that is not one line: {text!r}"
    return None


# -- comparing outputs ----------------------------------------------------------------------------
def _difference(a, b, where: str) -> str | None:
    """Where and how ``a`` and ``b`` differ (arrays, dataclasses, lists, dicts, scalars), or ``None``."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)):
            return f"{where}: {type(a).__name__} vs {type(b).__name__}"
        if a.dtype != b.dtype or a.shape != b.shape:
            return f"{where}: {a.dtype.name} {a.shape} vs {b.dtype.name} {b.shape}"
        if np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"):
            return None
        same = (a == b) | ((a != a) & (b != b))  # NaN == NaN here
        detail = f"{int(same.size - same.sum())} of {a.size} values differ"
        if a.dtype.kind in "iufc":
            gap = np.abs(a.astype(np.float64) - b.astype(np.float64))
            detail += f", by up to {float(np.nanmax(gap)):.3g}"
        return f"{where}: {detail}"
    if is_dataclass(a) and not isinstance(a, type) and type(a) is type(b):
        for item in fields(a):
            differs = _difference(getattr(a, item.name), getattr(b, item.name), f"{where}.{item.name}")
            if differs:
                return differs
        return None
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return f"{where}: {len(a)} vs {len(b)} items"
        return next((d for k, (x, y) in enumerate(zip(a, b)) if (d := _difference(x, y, f"{where}[{k}]"))), None)
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return f"{where}: keys {sorted(map(str, a))} vs {sorted(map(str, b))}"
        return next((d for key in a if (d := _difference(a[key], b[key], f"{where}[{key!r}]"))), None)
    return None if _equal(a, b) else f"{where}: {a!r} vs {b!r}"


def _equal(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and a != a and b != b:
        return True
    try:
        return bool(a == b)
    except Exception:  # e.g. an object whose == is elementwise
        return a is b


def _first_line(exc: BaseException) -> str:
    return (str(exc).strip().splitlines() or [""])[0]
