"""Training specs (YAML): validated as a whole, every problem reported with its YAML path."""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml

from eponet.core.errors import SpecError
from eponet.core.motion import ED_ENCODINGS, FLOW_CENTRINGS, flow_spread_problem
from eponet.core.params import Param, validate_params
from eponet.core.spec import apply_overrides, default_cache_dir, parse_spec
from eponet.core.registry import nearest
from eponet.training.losses import LOSSES

__all__ = ["TASKS", "DEFAULT_TIMEOUT", "TrainConfig", "Phase", "DataSource", "load_train_config", "parse_train_config"]

#: What ``eponet train`` can train: the EpO motion network, or the EpO+ fusion on top of a trained one.
TASKS = ("motion_net", "fusion")
_COMMON_TOP_LEVEL = ("task", "seed", "model", "geometry", "phases", "validation", "optimizer", "loss", "input_dropout",
                     "augment", "output", "cache", "device", "threads", "distributed")
TOP_LEVEL = _COMMON_TOP_LEVEL + ("teacher",)
FUSION_TOP_LEVEL = _COMMON_TOP_LEVEL + ("motion_net", "appearance", "clips", "motion_maps")

#: Shared by both tasks' optimiser sections.
_EMA = Param("ema", "float", 0.0, "decay of an exponential moving average of the weights, updated every step, that "
             "is validated and exported instead of the raw weights (0: off; e.g. 0.995)", minimum=0.0, maximum=0.9999)
_MODEL = (
    Param("inputs", "choice", "ed+flow", "input modality", choices=("ed+flow", "flow", "ed")),
    Param("depth", "int", 4, "number of encoder (and decoder) blocks", minimum=2, maximum=4),
    Param("widths", "list", [16, 32, 64, 128], "channels of the encoder blocks, shallow to deep"),
    Param("head_channels", "int", 128, "channels before the 1x1 classifier (128 in the paper)", minimum=1),
    Param("ed_encoding", "choice", "clip", "how the network saturates the scaled ED channel: clip at "
          "1 (the paper) or log (1 + ln ED above 1)", choices=ED_ENCODINGS),
    Param("flow_centring", "choice", "none", "what the network subtracts from each frame's flow channels: none (the "
          "paper), rigid (the median flow of the pixels whose ED is at most the frame's median) or affine "
          "(an affine flow field fitted to those pixels)",
          choices=FLOW_CENTRINGS),
    Param("flow_spread", "int", 0, "window in pixels (odd) of one more input channel: the local spread of the flow, "
          "ln(1 + std of the flow vectors around each pixel), large on dynamic texture such as water (0: off)",
          minimum=0),
)
_OPTIMIZER = (
    Param("name", "choice", "sgd", "optimiser", choices=("sgd", "adam", "adamw", "rmsprop")),
    Param("lr", "float", 1e-3, "learning rate", minimum=0.0, exclusive_min=True),
    Param("momentum", "float", 0.9, "momentum (sgd, rmsprop)", minimum=0.0, maximum=1.0),
    Param("weight_decay", "float", 5e-3, "weight decay", minimum=0.0),
    Param("batch_size", "int", 12, "frames per batch", minimum=1),
    Param("step_epochs", "int", 5, "multiply the learning rate by gamma every this many epochs of a phase", minimum=1),
    Param("gamma", "float", 0.1, "learning-rate decay factor", minimum=0.0, maximum=1.0, exclusive_min=True),
    _EMA,
)
_DROPOUT = (
    Param("probability", "float", 0.2, "fraction of training samples whose ED channel is replaced", minimum=0.0, maximum=1.0),
    Param("zero_epochs", "int", 3, "epochs (counted over all phases) in which the replacement is zeros", minimum=0),
    Param("then", "choice", "noise", "replacement afterwards", choices=("zero", "noise", "random")),
    Param("noise_std", "float", 0.05, "std of the Gaussian noise (normalised ED units)", minimum=0.0),
)
_AUGMENT = (
    Param("crop", "list", [224, 384], "random crop size [height, width] (null: whole frames)", nullable=True),
    Param("flip", "bool", True, "random left-right flips"),
)
_MOTION_AUGMENT = _AUGMENT + (
    Param("zoom", "list", None, "range [low, high] of a random magnification of each cropped sample, drawn "
          "log-uniformly: a window of crop / factor pixels resized to the crop, its flow scaled with it (null: off; "
          "needs a crop)", nullable=True),
    Param("flow_shift", "float", 0.0, "std of a random constant added to each sample's (dx, dy), in FLOW_SCALE units "
          "(20 px at 427x240): a camera pan of another speed (0: off)", minimum=0.0),
)
_LOSS = (
    Param("name", "choice", "bce", "training loss: bce (the paper) or bce+iou (adds a per-frame soft Jaccard term, "
          "which optimises J directly)", choices=LOSSES),
    Param("iou_weight", "float", 1.0, "weight of the soft Jaccard term (bce+iou)", minimum=0.0),
)
_TEACHER = (
    Param("weights", "list", [], "motion networks (built-in names or weights files) whose mean foreground probability "
          "on each training sample is mixed into the target: distillation, e.g. of an ensemble into one network "
          "([]: off)"),
    Param("share", "float", 0.5, "the teachers' share of the target: (1 - share) x ground truth + share x their "
          "probability", minimum=0.0, maximum=1.0),
)
_OUTPUT = (Param("dir", "path", None, "folder for checkpoints, weights, curves and the model card", required=True),)
_CACHE = (
    Param("enabled", "bool", True, "reuse cached flow, trajectories and ED"),
    Param("dir", "path", None, "cache folder (default $EPONET_CACHE or ~/.cache/eponet)", nullable=True),
)
#: Under torchrun: seconds a process waits for the others before the run fails (``distributed.timeout``).
DEFAULT_TIMEOUT = 1800.0
_DISTRIBUTED = (
    Param("timeout", "float", DEFAULT_TIMEOUT, "under torchrun: seconds a process waits for the others (joining the run, each "
          "collective) before the run fails; a process that dies is noticed at once", minimum=1.0),
)
_DAVIS = (
    Param("root", "path", None, "DAVIS-layout root (JPEGImages/<resolution>/<seq>/, Annotations/...)", required=True),
    Param("resolution", "str", "240p", "frames resolution folder"),
    Param("sequences", "list", None, "sequences to use (default: all)", nullable=True),
    Param("exclude", "list", [], "sequences to leave out"),
)
_RBSF = (
    Param("dir", "path", None, "where the generated data set is written (reused when present)", required=True),
    Param("sequences", "int", 40, "number of clips", minimum=1),
    Param("frames", "int", 30, "frames per clip", minimum=3),
    Param("size", "str", "427x240", "frame size WxH"),
    Param("seed", "int", 0, "generator seed", minimum=0),
)
# and ``scene``: settings of eponet.synth.SceneConfig (e.g. dynamic_texture_probability: 1.0), checked by it
_PASTE = (
    Param("dir", "path", None, "where the pasted clips are written (reused when present)", required=True),
    *_DAVIS,
    Param("clips", "int", 24, "number of clips", minimum=1),
    Param("frames", "int", 30, "frames per clip", minimum=3),
    Param("seed", "int", 0, "which backgrounds, objects, windows and paths", minimum=0),
    Param("object_area", "list", [0.02, 0.25], "range of the pasted object's area, as a fraction of the frame"),
    Param("speed", "list", [0.5, 4.0], "range of the pasted object's speed, pixels per frame"),
)
#: Data source kinds and their settings.
_SOURCES = {"davis": _DAVIS, "rbsf": _RBSF, "paste": _PASTE}
# -- task: fusion (EpO+, paper sections 4.3 and 5.2) --------------------------------------------------------
_FUSION_MODEL = (
    Param("bottleneck", "int", 128, "channels of the 1x1 bottleneck on the appearance features (128 in the paper)",
          minimum=1),
    Param("hidden", "int", 64, "ConvGRU state channels (not given in the paper)", minimum=1),
    Param("kernel_size", "int", 3, "ConvGRU kernel size (odd; not given in the paper)", minimum=1),
    Param("motion_residual", "bool", False, "predict a correction of the motion net: add the full-resolution "
          "motion map's logit (learned weight from 1; classifier from 0) to the upsampled logits (eponet extension)"),
    Param("feature_dropout", "float", 0.0, "probability of dropping an appearance channel in training "
          "(Dropout2d before the bottleneck; eponet extension)", minimum=0.0, maximum=0.99),
)
_FUSION_OPTIMIZER = (
    Param("name", "choice", "rmsprop", "optimiser (the paper: RMSProp)", choices=("rmsprop", "sgd", "adam", "adamw")),
    Param("lr", "float", 1e-3, "initial learning rate", minimum=0.0, exclusive_min=True),
    Param("schedule", "choice", "linear", "learning-rate decay: linear = lr * (1 - epoch / epochs), decreased every "
          "epoch (the paper's 'factor epoch/50'); step = x gamma every step_epochs; constant",
          choices=("linear", "step", "constant")),
    Param("step_epochs", "int", 5, "step schedule: epochs between decays", minimum=1),
    Param("gamma", "float", 0.1, "step schedule: decay factor", minimum=0.0, maximum=1.0, exclusive_min=True),
    Param("momentum", "float", 0.0, "momentum (sgd, rmsprop)", minimum=0.0, maximum=1.0),
    Param("weight_decay", "float", 0.0, "weight decay", minimum=0.0),
    Param("batch_size", "int", 1, "clips per optimisation step", minimum=1),
    Param("clip_gradients", "float", 50.0, "clip every gradient element to [-value, value] (the paper: 50); null: "
          "no clipping", minimum=0.0, exclusive_min=True, nullable=True),
    _EMA,
)
_CLIPS = (
    Param("length", "int", 12, "frames per training clip, back-propagated through time (the paper: 12)", minimum=2),
)
_FUSION_DROPOUT = (
    Param("probability", "float", 0.2, "fraction of training frames whose motion map is replaced by zeros",
          minimum=0.0, maximum=1.0),
    Param("sequences", "list", None, "only these sequences (the paper: fast motion, dynamic background); "
          "null: all", nullable=True),
)
_FUSION_STAGES = {"motion_net": "epo_unet", "appearance": "efficientnet_lite2"}  # the epo+ preset's
_SCHEMAS = {
    "motion_net": {"model": _MODEL, "optimizer": _OPTIMIZER, "input_dropout": _DROPOUT, "augment": _MOTION_AUGMENT},
    "fusion": {"model": _FUSION_MODEL, "optimizer": _FUSION_OPTIMIZER, "input_dropout": _FUSION_DROPOUT,
               "clips": _CLIPS, "augment": _AUGMENT},
}

_PHASE = (
    Param("name", "str", None, "phase name", required=True),
    Param("epochs", "int", 10, "epochs of this phase", minimum=1),
    Param("samples_per_epoch", "int", None, "frames drawn per epoch (default: every frame once)", minimum=1, nullable=True),
)


def _range_problem(value: list, upper: float | None) -> str | None:
    """Why ``value`` is not a range ``[low, high]`` of numbers with ``0 < low <= high`` (``<= upper``), or None."""
    if (len(value) == 2 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
            and 0 < value[0] <= value[1] and (upper is None or value[1] <= upper)):
        return None
    bound = f" <= {upper:g}" if upper is not None else ""
    return f"expected [low, high] with 0 < low <= high{bound}, got {value!r}"


@dataclass
class DataSource:
    kind: str  # "davis", "rbsf" or "paste"
    options: dict


@dataclass
class Phase:
    """One training phase. ``data``: one source, or several whose sequences are mixed in each epoch."""

    name: str
    data: DataSource | tuple[DataSource, ...]
    epochs: int
    samples_per_epoch: int | None = None


@dataclass
class TrainConfig:
    """A validated training spec. ``geometry`` is the pipeline spec of the stages that make the training data
    (flow, trajectories, rigidity; for ``task: fusion`` also the appearance stage); ``stages`` holds, for
    ``task: fusion``, the validated ``motion_net`` and ``appearance`` stage configurations."""

    task: str
    seed: int
    model: dict
    geometry: Any  # eponet.core.spec.Spec of the geometry stages
    phases: list[Phase]
    validation: DataSource | None
    optimizer: dict
    input_dropout: dict
    augment: dict
    output_dir: Path
    cache_enabled: bool = True
    cache_dir: Path = field(default_factory=default_cache_dir)
    device: str = "auto"
    threads: int | None = None
    file: str | None = None
    document: dict = field(default_factory=dict)
    stages: dict = field(default_factory=dict)
    clips: dict = field(default_factory=dict)
    loss: dict = field(default_factory=lambda: {"name": "bce", "iou_weight": 1.0})
    distributed: dict = field(default_factory=lambda: {"timeout": DEFAULT_TIMEOUT})
    teacher: dict = field(default_factory=lambda: {"weights": [], "share": 0.5})
    #: ``task: fusion``: ``{sequence name: weights}`` whose motion net gives that sequence's training (and
    #: validation) maps instead of ``stages["motion_net"]``'s weights (``motion_maps`` in the spec)
    motion_maps: dict = field(default_factory=dict)


def parse_motion_maps(raw, resolve) -> tuple[dict, list[str]]:
    """``{sequence: weights}`` and the problems found, from a fusion spec's ``motion_maps``: a list of ``{weights:
    name, file or list of them, sequences: [names]}``, e.g. each sequence's map from a network trained without it
    (out of fold); weights files resolved as ``resolve`` does."""
    from eponet.core.errors import MissingWeights
    from eponet.weights import resolve_weights

    expected = "motion_maps: expected a list of {weights: <name, file or list>, sequences: [<names>]}"
    if not isinstance(raw, list):
        return {}, [f"{expected}, got {raw!r}"]
    out: dict = {}
    problems: list[str] = []
    for i, entry in enumerate(raw):
        where = f"motion_maps[{i}]"
        if not isinstance(entry, dict) or set(entry) != {"weights", "sequences"}:
            problems.append(f"{where}: expected {{weights: ..., sequences: [...]}}, got {entry!r}")
            continue
        weights, names = entry["weights"], entry["sequences"]
        listed = weights if isinstance(weights, list) else [weights]
        if not listed or not all(isinstance(w, str) and w for w in listed):
            problems.append(f"{where}.weights: expected a weights name or file, or a list of them, got {weights!r}")
            continue
        if not (isinstance(names, list) and names and all(isinstance(n, str) and n for n in names)):
            problems.append(f"{where}.sequences: expected a list of sequence names, got {names!r}")
            continue
        listed = [str(resolve(f"{where}.weights", w)) if w.endswith(".pt") else w for w in listed]
        for w in listed:
            try:
                resolve_weights(w, kind="motion_net")
            except MissingWeights as exc:
                problems.append(f"{where}.weights: {exc.problem}")
        for name in names:
            if name in out:
                problems.append(f"{where}.sequences: {name!r} is given a motion net twice")
            out[name] = listed if isinstance(weights, list) else listed[0]
    return out, problems


def load_train_config(path: str | Path, overrides: list[str] = ()) -> TrainConfig:
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text()) or {}
    except OSError as exc:
        raise SpecError(f"cannot read training spec ({exc.strerror or exc})", file=str(path)) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark
        raise SpecError(f"line {mark.line + 1}, column {mark.column + 1}: YAML syntax error: {exc.problem}", file=str(path)) from None
    if not isinstance(document, dict):
        raise SpecError("expected a mapping", file=str(path))
    document, overridden = apply_overrides(document, overrides)
    return parse_train_config(document, base_dir=path.resolve().parent, overridden=overridden, file=str(path))


def parse_train_config(document: dict, *, base_dir: Path, overridden: set[str] = frozenset(), file: str | None = None) -> TrainConfig:
    problems: list[str] = []

    def resolve(key: str, value):
        if value is None:
            return None
        value = Path(str(value)).expanduser()
        return Path(os.path.normpath(value if value.is_absolute() else (Path.cwd() if key in overridden else base_dir) / value))

    task = document.get("task", "motion_net")
    if task not in TASKS:
        problems.append(f"task: expected one of {', '.join(repr(t) for t in TASKS)}, got {task!r}")
        task = "motion_net"
    known = FUSION_TOP_LEVEL if task == "fusion" else TOP_LEVEL
    for key in document:
        if key not in known:
            hint = nearest(key, list(known))
            problems.append(f"{key}: unknown top-level key{f' (did you mean {hint!r}?)' if hint else ''}; known: {', '.join(known)}")
    seed = document.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        problems.append(f"seed: expected a non-negative integer, got {seed!r}")

    def section(name: str, schema) -> dict:
        raw = document.get(name) or {}
        if not isinstance(raw, dict):
            problems.append(f"{name}: expected a mapping, got {raw!r}")
            raw = {}
        values, found = validate_params(raw, schema, name)
        problems.extend(found)
        return values

    schemas = _SCHEMAS[task]
    model = section("model", schemas["model"])
    if task == "motion_net":
        widths = model.get("widths")
        if not (isinstance(widths, list) and all(isinstance(w, int) and not isinstance(w, bool) and w > 0 for w in widths)
                and len(widths) >= model.get("depth", 4)):
            problems.append(f"model.widths: expected a list of at least depth={model.get('depth')} positive integers, got {widths!r}")
        spread = model.get("flow_spread", 0)
        if isinstance(spread, int) and flow_spread_problem(spread):
            problems.append(f"model.flow_spread: {flow_spread_problem(spread)}")
    elif isinstance(model.get("kernel_size"), int) and model["kernel_size"] % 2 == 0:
        problems.append(f"model.kernel_size: expected an odd integer, got {model['kernel_size']}")
    optimizer = section("optimizer", schemas["optimizer"])
    dropout = section("input_dropout", schemas["input_dropout"])
    loss = section("loss", _LOSS)
    clips = section("clips", schemas["clips"]) if task == "fusion" else {}
    augment = section("augment", schemas["augment"])
    crop = augment.get("crop")
    if crop is not None and not (isinstance(crop, list) and len(crop) == 2 and all(isinstance(c, int) and c >= 16 for c in crop)):
        problems.append(f"augment.crop: expected [height, width] of integers >= 16 or null, got {crop!r}")
    zoom = augment.get("zoom")
    if zoom is not None and not (isinstance(zoom, list) and len(zoom) == 2
                                 and all(isinstance(z, (int, float)) and not isinstance(z, bool) and z > 0 for z in zoom)
                                 and zoom[0] <= zoom[1]):
        problems.append(f"augment.zoom: expected [low, high] with 0 < low <= high, or null, got {zoom!r}")
    elif zoom is not None and crop is None:
        problems.append("augment.zoom: needs augment.crop (a zoom resizes a window to the crop's size)")
    output = section("output", _OUTPUT)
    cache = section("cache", _CACHE)
    distributed = section("distributed", _DISTRIBUTED)
    teacher = section("teacher", _TEACHER)  # (task fusion: rejected above as an unknown key, so the defaults)
    if not (isinstance(teacher.get("weights"), list) and all(isinstance(w, str) and w for w in teacher["weights"])):
        problems.append(f"teacher.weights: expected a list of weights names or files, got {teacher.get('weights')!r}")
    else:  # files relative to the spec, like the other paths; built-in names as they are
        teacher["weights"] = [str(resolve("teacher.weights", w)) if w.endswith(".pt") else w
                              for w in teacher["weights"]]
    motion_maps = {}
    if task == "fusion" and document.get("motion_maps") is not None:
        motion_maps, found = parse_motion_maps(document["motion_maps"], resolve)
        problems.extend(found)
    device = document.get("device", "auto")
    if device not in ("auto", "cpu", "cuda"):
        problems.append(f"device: expected one of 'auto', 'cpu', 'cuda', got {device!r}")
    threads = document.get("threads")
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        problems.append(f"threads: expected a positive integer or null (all cores), got {threads!r}")

    def data_source(raw, path: str) -> DataSource | None:
        if not isinstance(raw, dict) or len(raw) != 1 or next(iter(raw)) not in _SOURCES:
            problems.append(f"{path}: expected {{davis: {{root: ...}}}}, {{rbsf: {{dir: ...}}}} or {{paste: {{dir: ..., "
                            f"root: ...}}}}, got {raw!r}")
            return None
        kind, options = next(iter(raw.items()))
        if task == "fusion" and kind != "davis":
            problems.append(f"{path}: task fusion trains on DAVIS-layout data ({{davis: {{root: ...}}}}), got {kind}")
            return None
        if options is not None and not isinstance(options, dict):
            problems.append(f"{path}.{kind}: expected a mapping of settings, got {options!r}")
            return None
        options = dict(options or {})
        scene = options.pop("scene", None) if kind == "rbsf" else None
        schema = _SOURCES[kind]
        values, found = validate_params(options, schema, f"{path}.{kind}")
        problems.extend(found)
        for name, upper in (("object_area", 1.0), ("speed", None)) if kind == "paste" else ():
            if isinstance(values.get(name), list) and (problem := _range_problem(values[name], upper)):
                problems.append(f"{path}.paste.{name}: {problem}")
        if scene is not None:
            values["scene"] = scene
            from eponet.synth.scene import SceneConfig  # local: the generator is only needed for rbsf data

            try:
                SceneConfig.from_dict(scene)
            except SpecError as exc:
                problems.extend(f"{path}.rbsf.scene: {p}" for p in exc.problems)
        for param in schema:
            if param.type == "path":
                values[param.name] = resolve(f"{path}.{kind}.{param.name}", values.get(param.name))
        root = values.get("root")
        if root is not None and not (root / "JPEGImages").is_dir():
            problems.append(f"{path}.{kind}.root: {root} is not a DAVIS-layout root (no JPEGImages/)")
        return DataSource(kind, values)

    phases: list[Phase] = []
    raw_phases = document.get("phases")
    if not isinstance(raw_phases, list) or not raw_phases:
        problems.append("phases: expected a list of phases like [{name: davis, data: {davis: {root: ...}}, epochs: 10}]")
        raw_phases = []
    for i, raw in enumerate(raw_phases):
        path = f"phases[{i}]"
        if not isinstance(raw, dict):
            problems.append(f"{path}: expected a mapping, got {raw!r}")
            continue
        values, found = validate_params({k: v for k, v in raw.items() if k != "data"}, _PHASE, path)
        problems.extend(found)
        raw_data = raw.get("data")
        if isinstance(raw_data, list):  # several sources, mixed in each epoch
            if not raw_data:
                problems.append(f"{path}.data: expected a source or a non-empty list of sources, got []")
            sources = [data_source(item, f"{path}.data[{j}]") for j, item in enumerate(raw_data)]
            source = tuple(sources) if sources and None not in sources else None
        else:
            source = data_source(raw_data, f"{path}.data")
        if source is not None and not found:
            phases.append(Phase(values["name"], source, values["epochs"], values["samples_per_epoch"]))
    validation = data_source(document["validation"], "validation") if document.get("validation") is not None else None

    geometry_doc = document.get("geometry") or {}
    geometry = None
    stages = {}
    extra_stages = {}  # task fusion: motion_net and appearance, validated with the geometry stages
    for kind, default in _FUSION_STAGES.items() if task == "fusion" else ():
        raw = document.get(kind) or {}
        if not isinstance(raw, dict):
            problems.append(f"{kind}: expected a mapping like {{plugin: {default}, ...}}, got {raw!r}")
            raw = {}
        extra_stages[kind] = {"plugin": default, **raw}
    if not isinstance(geometry_doc, dict):
        problems.append("geometry: expected {stages: {...}, scale: 1.0}")
    else:
        unknown = set(geometry_doc) - {"stages", "scale"}
        problems.extend(f"geometry.{k}: unknown key; known: stages, scale" for k in sorted(unknown))
        stage_doc = geometry_doc.get("stages") or {}
        if isinstance(stage_doc, dict) and extra_stages:
            stage_doc = {k: v for k, v in stage_doc.items() if k not in extra_stages} | extra_stages
        try:
            geometry = parse_spec(
                {"preset": "geometry", "input": {"path": str(base_dir), "scale": geometry_doc.get("scale", 1.0)},
                 "stages": stage_doc, "output": {"dir": str(base_dir), "save": []},
                 "cache": {"enabled": cache["enabled"], "dir": str(cache["dir"]) if cache["dir"] else None},
                 "seed": seed if isinstance(seed, int) else 0},
                base_dir=base_dir, overridden={f"stages.{k}" for k in overridden if k.split(".")[0] in extra_stages})
        except SpecError as exc:
            for p in exc.problems:
                kind = p.split(".")[1].split(":")[0] if p.startswith("stages.") else None
                problems.append(p[len("stages."):] if kind in extra_stages else f"geometry.{p.replace('input.', '')}")
        if geometry is not None and extra_stages:
            stages = {kind: geometry.stages[kind] for kind in extra_stages}
            # the data pipeline keeps the appearance stage (its features are cached like the geometry's)
            geometry = replace(geometry, stages={k: v for k, v in geometry.stages.items() if k != "motion_net"})
    if problems:
        raise SpecError(problems, file=file)
    return TrainConfig(
        task=task, seed=seed, model=model, geometry=geometry, phases=phases, validation=validation,
        optimizer=optimizer, input_dropout=dropout, augment=augment, output_dir=resolve("output.dir", output["dir"]),
        cache_enabled=cache["enabled"], cache_dir=resolve("cache.dir", cache["dir"]) or default_cache_dir(),
        device=device, threads=threads, file=file, document=document, stages=stages, clips=clips, loss=loss,
        distributed=distributed, teacher=teacher, motion_maps=motion_maps,
    )
