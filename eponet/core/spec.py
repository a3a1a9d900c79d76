"""Pipeline specs: YAML documents validated as a whole (every problem with its YAML path) before anything runs."""

from __future__ import annotations

import copy
import glob
import os
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Mapping

import yaml

from .errors import PluginNotFound, SpecError
from .hookspecs import StageSpec
from .io import is_pattern
from .motion import ED_WINDOW
from .params import Param, validate_params
from .graph import KINDS, OUTPUTS, missing_needs, producer_of, producers
from .registry import Registry, get_registry, nearest

__all__ = [
    "SAVE_ITEMS",
    "TOP_LEVEL_KEYS",
    "StageConfig",
    "InputConfig",
    "OutputConfig",
    "RunConfig",
    "Spec",
    "load_spec",
    "parse_spec",
    "apply_overrides",
    "default_cache_dir",
]

TOP_LEVEL_KEYS = ("preset", "input", "stages", "output", "run", "seed", "cache", "evaluate")
SAVE_ITEMS = tuple(OUTPUTS)

_INPUT = {
    "path": Param("path", "path", None, "a folder of frames, a video file, a DAVIS-layout root, or a corpus: a .txt "
                  "file listing videos and frame folders (one a line) or a glob", required=True),
    "sequences": Param("sequences", "list", None, "sequence names to process (DAVIS-layout roots)", nullable=True),
    "resolution": Param("resolution", "str", "480p", "DAVIS resolution folder (JPEGImages/<resolution>/)"),
    "scale": Param("scale", "float", 0.5, "processing resolution relative to the input frames", minimum=0.0, maximum=1.0, exclusive_min=True),
    "max_frames": Param("max_frames", "int", None, "use at most this many frames per sequence", minimum=3, nullable=True),
}
_OUTPUT = {
    "dir": Param("dir", "path", None, "output folder (one sub-folder per sequence)", required=True),
    "save": Param("save", "list", ["masks"], "what to write: " + ", ".join(SAVE_ITEMS)),
    "fps": Param("fps", "float", None, "frame rate of overlay.mp4 (default: a video file's own rate, 24 for "
                 "frames)", minimum=0.0, exclusive_min=True, nullable=True),
}
_RUN = {
    "chunk": Param("chunk", "int", 16, "frames per chunk: flow, rigidity windows (frame groups) and network batches "
                   "work on this many frames at a time", minimum=2),
    "lag": Param("lag", "int", 30, "frames a trajectory's ED may still change after a frame it covers is painted: "
                 "frame t waits for every frame group starting by t + lag", minimum=0),
    "ed_window": Param("ed_window", "int", ED_WINDOW, "frames of the centred window whose ED sets a frame's ED scale (its "
                       "95th percentile): a stream waits for ed_window // 2 frames of look-ahead; null: the whole "
                       "video's scale (the original's; holds every frame until the video ends)", minimum=1,
                       nullable=True),
    "workers": Param("workers", "str", "auto", "sequences processed at once in worker processes: 'auto' (one per "
                     "core, at most one per sequence) or a number"),
    "threads": Param("threads", "bool", True, "overlap the stages of one video in threads (flow of the next chunk "
                     "while the networks work on this one)"),
    "executor": Param("executor", "choice", "local", "where sequences run: 'local' worker processes or 'ray' actors "
                      "(pip install -e '.[ray]')", choices=("local", "ray")),
    "address": Param("address", "str", None, "executor ray: null starts a local Ray instance, 'auto' joins the "
                     "cluster of this machine, 'ray://host:port' or 'host:port' a remote one", nullable=True),
}
_CACHE = {
    "enabled": Param("enabled", "bool", True, "reuse intermediate results (flow, trajectories, ED, ...)"),
    "dir": Param("dir", "path", None, "cache folder (default $EPONET_CACHE or ~/.cache/eponet)", nullable=True),
}


def default_cache_dir() -> Path:
    """``$EPONET_CACHE``, else ``$XDG_CACHE_HOME/eponet``, else ``~/.cache/eponet``."""
    if os.environ.get("EPONET_CACHE"):
        return Path(os.environ["EPONET_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "eponet"


@dataclass
class StageConfig:
    """One resolved stage: its plugin and validated parameters (defaults filled in)."""

    kind: str
    spec: StageSpec
    params: dict

    @property
    def plugin(self) -> str:
        return self.spec.name

    def build(self):
        return self.spec.factory(**self.params)


@dataclass
class InputConfig:
    path: Path
    sequences: list[str] | None = None
    resolution: str = "480p"
    scale: float = 0.5
    max_frames: int | None = None


@dataclass
class OutputConfig:
    dir: Path
    save: tuple[str, ...] = ("masks",)
    fps: float | None = None


@dataclass
class RunConfig:
    chunk: int = 16
    lag: int = 30
    ed_window: int | None = ED_WINDOW
    workers: int | str = "auto"
    threads: bool = True
    executor: str = "local"
    address: str | None = None


@dataclass
class Spec:
    """A validated pipeline spec. ``document`` is the resolved YAML (for ``run.json``)."""

    preset: str
    input: InputConfig
    stages: dict[str, StageConfig]
    output: OutputConfig
    run: RunConfig = field(default_factory=RunConfig)
    seed: int = 0
    cache_enabled: bool = True
    cache_dir: Path = field(default_factory=default_cache_dir)
    evaluate: dict | None = None
    file: str | None = None
    document: dict = field(default_factory=dict)


# -- reading ------------------------------------------------------------------------------------
def load_spec(path: str | Path, overrides: list[str] | Mapping[str, Any] = (), registry: Registry | None = None) -> Spec:
    """Read, override and validate a spec file. Raises :class:`SpecError` listing every problem."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SpecError(f"cannot read spec ({exc.strerror or exc})", file=str(path)) from None
    try:
        document = yaml.safe_load(text)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        raise SpecError(f"{where}YAML syntax error: {exc.problem}", file=str(path)) from None
    except yaml.YAMLError as exc:
        raise SpecError(f"YAML syntax error: {exc}", file=str(path)) from None
    if document is None:
        document = {}
    if not isinstance(document, dict):
        raise SpecError(f"expected a mapping of {', '.join(TOP_LEVEL_KEYS)}, got {type(document).__name__}", file=str(path))
    document, overridden = apply_overrides(document, overrides)
    return parse_spec(document, base_dir=path.resolve().parent, overridden=overridden, registry=registry, file=str(path))


def apply_overrides(document: dict, overrides: list[str] | Mapping[str, Any]) -> tuple[dict, set[str]]:
    """Apply overrides: ``key.path=value`` strings (``--set``; values parsed as YAML) or a mapping of dotted key
    to value (the Python API; values as given). Returns the new document and the set of overridden dotted paths."""
    document = copy.deepcopy(document)
    overridden: set[str] = set()
    problems = []
    pairs = []  # (dotted key, value, how the problem lines name the override)
    if isinstance(overrides, Mapping):
        pairs = [(str(key), value, str(key)) for key, value in overrides.items()]
    else:
        for item in overrides:
            key, sep, raw = item.partition("=")
            if not sep:
                problems.append(f"--set {item}: expected key.path=value")
                continue
            try:
                value = yaml.safe_load(raw) if raw != "" else None
            except yaml.YAMLError:
                value = raw
            pairs.append((key, value, f"--set {item}"))
    for key, value, label in pairs:
        if not key or any(not part for part in key.split(".")):
            problems.append(f"{label}: expected key.path=value")
            continue
        node = document
        parts = key.split(".")
        try:
            for part in parts[:-1]:
                if isinstance(node, list):  # numeric indices reach into lists: phases.1.epochs=3
                    node = node[int(part)]
                    continue
                if not isinstance(node.get(part), (dict, list)):
                    node[part] = {}
                node = node[part]
            if isinstance(node, list):
                node[int(parts[-1])] = value
            else:
                node[parts[-1]] = value
        except (ValueError, IndexError):
            problems.append(f"{label}: {key} does not name an existing list element")
            continue
        overridden.add(key)
    if problems:
        raise SpecError(problems)
    return document, overridden


def parse_spec(
    document: dict,
    *,
    base_dir: Path | None = None,
    overridden: set[str] = frozenset(),
    registry: Registry | None = None,
    file: str | None = None,
) -> Spec:
    """Validate a spec document as a whole; raise :class:`SpecError` with every problem found.

    Relative paths in the document resolve against ``base_dir`` (the spec file's folder), except values
    given with ``--set`` (listed in ``overridden``), which resolve against the current directory.
    """
    registry = registry or get_registry()
    base_dir = base_dir or Path.cwd()
    problems: list[str] = []

    def resolve_path(key: str, value: str | None) -> Path | None:
        if value is None:
            return None
        value = os.path.expanduser(value)
        root = Path.cwd() if key in overridden else base_dir
        return Path(os.path.normpath(value if os.path.isabs(value) else root / value))

    for key in document:
        if key not in TOP_LEVEL_KEYS:
            problems.append(f"{key}: unknown top-level key{_hint(key, TOP_LEVEL_KEYS)}; known: {', '.join(TOP_LEVEL_KEYS)}")

    # preset
    preset_name = document.get("preset", registry.default_preset)
    preset_stages: dict[str, dict] = {}
    preset_known = False  # without the preset's stages, what the composition lacks is not known: not reported
    if not isinstance(preset_name, str):
        problems.append(f"preset: expected a preset name ({', '.join(registry.presets)}), got {preset_name!r}")
    else:
        try:
            preset_stages = registry.resolve_preset(preset_name)
            preset_known = True
        except PluginNotFound as exc:
            problems.extend(exc.problems)

    # sections
    input_values = _section(document, "input", _INPUT, problems)
    output_values = _section(document, "output", _OUTPUT, problems)
    cache_values = _section(document, "cache", _CACHE, problems)
    run_document = dict(document.get("run") or {}) if isinstance(document.get("run"), dict) else document.get("run")
    if isinstance(run_document, dict) and isinstance(run_document.get("workers"), int) and not isinstance(run_document.get("workers"), bool):
        run_document["workers"] = str(run_document["workers"])
    run_values = _section({"run": run_document}, "run", _RUN, problems)
    workers = run_values.get("workers", "auto")
    if isinstance(workers, str) and workers != "auto":
        if not workers.isdigit() or int(workers) < 1:
            problems.append(f"run.workers: expected 'auto' or a positive integer, got {workers!r}")
            workers = "auto"
        else:
            workers = int(workers)
    if run_values.get("executor") == "ray" or run_values.get("address") is not None:
        from .ray_executor import address_problem, ray_missing

        problems.extend(p for p in (ray_missing() if run_values.get("executor") == "ray" else None,
                                    address_problem(run_values.get("address"))) if p)
    seed = document.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        problems.append(f"seed: expected a non-negative integer, got {seed!r}")
        seed = 0

    sequences = input_values.get("sequences")
    if isinstance(sequences, list) and not all(isinstance(s, str) and s for s in sequences):
        problems.append(f"input.sequences: expected a list of sequence names, got {sequences!r}")

    input_path = resolve_path("input.path", input_values.get("path"))
    if input_path is not None and is_pattern(input_path):
        if not glob.glob(str(input_path), recursive=True):
            problems.append(f"input.path: no file or folder matches {input_path}")
    elif input_path is not None and not input_path.exists():
        problems.append(f"input.path: {input_path} does not exist")

    save = output_values.get("save") or []
    for item in save if isinstance(save, list) else []:
        if item not in SAVE_ITEMS:
            problems.append(f"output.save: unknown output {item!r}{_hint(str(item), SAVE_ITEMS)}; known: {', '.join(SAVE_ITEMS)}")
    out_dir = resolve_path("output.dir", output_values.get("dir"))
    if out_dir is not None:
        problem = _unwritable(out_dir)
        if problem:
            problems.append(f"output.dir: {problem}")

    # stages: preset merged with overrides
    stage_doc = document.get("stages") or {}
    merged: dict[str, dict] = {k: dict(v) for k, v in preset_stages.items()}
    if not isinstance(stage_doc, dict):
        problems.append(f"stages: expected a mapping of stage kind to settings, got {type(stage_doc).__name__}")
        stage_doc = {}
    for kind, config in stage_doc.items():
        if kind not in KINDS:
            problems.append(f"stages.{kind}: unknown stage kind{_hint(kind, KINDS)}; kinds: {', '.join(KINDS)}")
            continue
        if config is None:  # remove the stage
            merged.pop(kind, None)
            continue
        if not isinstance(config, dict):
            problems.append(f"stages.{kind}: expected a mapping like {{plugin: NAME, ...}}, got {config!r}")
            continue
        base = merged.get(kind, {})
        if "plugin" in config and config["plugin"] != base.get("plugin"):
            base = {}
        merged[kind] = {**base, **config}

    stages: dict[str, StageConfig] = {}
    unchecked: set[str] = set()  # stages whose own parameters have problems: not checked against the others
    for kind in KINDS:
        if kind not in merged:
            continue
        config = dict(merged[kind])
        path = f"stages.{kind}"
        name = config.pop("plugin", None)
        if not isinstance(name, str):
            problems.append(f"{path}.plugin: expected a plugin name, got {name!r}")
            continue
        try:
            spec = registry.get(kind, name, path=f"{path}.plugin")
        except PluginNotFound as exc:
            problems.extend(exc.problems)
            continue
        params, param_problems = validate_params(config, spec.params, path)
        problems.extend(param_problems)
        for param in spec.params:
            if param.type in ("path", "weights") and params.get(param.name) is not None:
                params[param.name] = _resolve_files(param, params[param.name], partial(resolve_path, f"{path}.{param.name}"),
                                                    registry.builtin_weights)
        checked = []
        if spec.check is not None and not param_problems:
            checked = spec.check(params)
            problems.extend(f"{path}.{problem}" for problem in checked)
        stages[kind] = StageConfig(kind, spec, params)
        if param_problems or checked:
            unchecked.add(kind)
    for kind, stage in stages.items():  # each stage against the others (e.g. a fusion and its appearance)
        if stage.spec.check_stages is not None and kind not in unchecked:
            others = {k: (s.plugin, s.params) for k, s in stages.items() if k != kind}
            problems.extend(f"stages.{kind}.{problem}" for problem in stage.spec.check_stages(stage.params, others))

    # the composition must be complete (the stage graph says what each stage and output needs)
    present = set(merged)
    if preset_known:
        problems.extend(missing_needs({kind: (stages[kind].params if kind in stages else merged[kind])
                                       for kind in merged}))
        if "flow" not in present:
            problems.append("stages.flow: every pipeline needs a flow stage")
        made = producers(present)
        for item in save if isinstance(save, list) else []:
            need = OUTPUTS.get(item)
            if need and need not in made:
                problems.append(f"output.save: {item!r} needs a {producer_of(need)} stage, which preset "
                                f"{preset_name!r} with these stages does not have")

    evaluate = document.get("evaluate")
    if evaluate is not None:
        evaluate = _validate_evaluate(evaluate, resolve_path, problems)
        if evaluate is not None and preset_known and "refiner" not in present:
            problems.append("evaluate: scoring needs masks, i.e. a refiner stage")
        if evaluate is not None and evaluate.get("dataset") == "generic" and not evaluate.get("masks"):
            problems.append("evaluate.masks: dataset generic needs the folder of ground-truth masks")
        if evaluate is not None and "dataset" in evaluate and input_path is not None and input_path.exists():
            problems.extend(registry.evaluate_problems(evaluate, input_path, input_values.get("resolution", "480p"),
                                                       sequences if isinstance(sequences, list) else None))

    if problems:
        raise SpecError(problems, file=file)

    cache_dir = resolve_path("cache.dir", cache_values.get("dir")) or default_cache_dir()
    resolved = {
        "preset": preset_name,
        "input": {**input_values, "path": str(input_path)},
        "stages": {k: {"plugin": s.plugin, **s.params} for k, s in stages.items()},
        # fps only when given: the documents (and config digests) of earlier runs stay as they were
        "output": {"dir": str(out_dir), "save": list(save),
                   **({"fps": output_values["fps"]} if output_values.get("fps") is not None else {})},
        "run": {**run_values, "workers": workers},
        "seed": seed,
        "cache": {"enabled": cache_values["enabled"], "dir": str(cache_dir)},
    }
    if evaluate is not None:
        resolved["evaluate"] = {k: str(v) if isinstance(v, Path) else v for k, v in evaluate.items()}
    return Spec(
        preset=preset_name,
        input=InputConfig(
            path=input_path,
            sequences=sequences,
            resolution=input_values["resolution"],
            scale=input_values["scale"],
            max_frames=input_values["max_frames"],
        ),
        stages=stages,
        output=OutputConfig(dir=out_dir, save=tuple(save), fps=output_values.get("fps")),
        run=RunConfig(chunk=run_values["chunk"], lag=run_values["lag"], ed_window=run_values["ed_window"],
                      workers=workers, threads=run_values["threads"],
                      executor=run_values["executor"], address=run_values["address"]),
        seed=seed,
        cache_enabled=cache_values["enabled"],
        cache_dir=cache_dir,
        evaluate=evaluate,
        file=file,
        document=resolved,
    )


_EVALUATE = {
    "dataset": Param("dataset", "choice", "davis2016", "ground-truth layout",
                     choices=("davis2016", "davis2017", "segtrackv2", "fbms", "generic")),
    "root": Param("root", "path", None, "data-set root (default: input.path)", nullable=True),
    "resolution": Param("resolution", "str", None, "annotation resolution folder (default: input.resolution)", nullable=True),
    "masks": Param("masks", "path", None, "ground-truth masks folder (dataset generic)", nullable=True),
    "t": Param("t", "bool", True, "also compute temporal stability T"),
}


def _validate_evaluate(evaluate: Any, resolve_path, problems: list[str]) -> dict | None:
    if not isinstance(evaluate, dict):
        problems.append(f"evaluate: expected a mapping like {{dataset: davis2016, root: PATH}}, got {evaluate!r}")
        return None
    values, param_problems = validate_params(evaluate, tuple(_EVALUATE.values()), "evaluate")
    problems.extend(param_problems)
    for key in ("root", "masks"):
        if values.get(key):
            values[key] = resolve_path(f"evaluate.{key}", values[key])
            if not values[key].exists():
                problems.append(f"evaluate.{key}: {values[key]} does not exist")
    return values


def _section(document: dict, name: str, schema: dict[str, Param], problems: list[str]) -> dict:
    raw = document.get(name)
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        problems.append(f"{name}: expected a mapping with keys {', '.join(schema)}, got {raw!r}")
        raw = {}
    values, section_problems = validate_params(raw, tuple(schema.values()), name)
    problems.extend(section_problems)
    return values


def _resolve_files(param, value, resolve, builtin_weights):
    """A ``path`` or ``weights`` parameter's value (one or a list) with each path made absolute by ``resolve``;
    built-in weights names (``builtin_weights()``, from the registry) stay names."""
    if isinstance(value, list):
        return [_resolve_files(param, v, resolve, builtin_weights) for v in value]
    if param.type == "weights" and value in builtin_weights():
        return value
    return str(resolve(value))


def _hint(name: str, candidates) -> str:
    match = nearest(name, list(candidates))
    return f" (did you mean {match!r}?)" if match else ""


def _unwritable(path: Path) -> str | None:
    """Why ``path`` cannot be used as an output folder, or ``None`` (nothing is created)."""
    probe = path
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    if probe.exists() and not probe.is_dir():
        return f"{probe} exists and is not a folder"
    if not os.access(probe, os.W_OK | os.X_OK):
        return f"cannot write to {probe} (permission denied)"
    return None
