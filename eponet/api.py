"""The Python API: :func:`run` a spec as ``eponet run`` does, :func:`segment` a video into arrays."""

from __future__ import annotations

import json
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from .core.errors import InputError, SpecError

__all__ = ["run", "segment", "Segmentation"]


def run(spec: str | Path | Mapping | Any, *, set: Mapping[str, Any] | None = None, **overrides: Any) -> dict:
    """Run a pipeline spec, as ``eponet run`` does; returns the run manifest, the dict written to ``run.json``.

    Parameters
    ----------
    spec : path, dict or Spec
        A YAML spec file (relative paths in it resolve against its folder), a spec document as a dict (relative
        paths resolve against the current folder) or a :class:`eponet.core.spec.Spec` from ``parse_spec``.
    set : dict, optional
        Overrides by dotted key, e.g. ``{"input.max_frames": 5}``, as ``--set`` gives them (values as given,
        not parsed as YAML). Keyword arguments are more of them: ``**{"stages.refiner.iterations": 3}``.

    Raises
    ------
    SpecError, InputError, StageError, ...
        eponet's typed errors (:mod:`eponet.core.errors`), each one line.

    Examples
    --------
    >>> import eponet
    >>> manifest = eponet.run("examples/demo.yaml", **{"input.max_frames": 5})  # doctest: +SKIP
    >>> manifest["sequences"]["demo"]["frames"]  # doctest: +SKIP
    5
    """
    from .core.pipeline import Pipeline
    from .core.spec import Spec, apply_overrides, load_spec, parse_spec

    overrides = {**(set or {}), **overrides}
    if isinstance(spec, Spec):
        if overrides:
            document, overridden = apply_overrides(spec.document, overrides)
            base_dir = Path(spec.file).resolve().parent if spec.file else None
            spec = parse_spec(document, base_dir=base_dir, overridden=overridden, file=spec.file)
    elif isinstance(spec, Mapping):
        document, overridden = apply_overrides(dict(spec), overrides)
        spec = parse_spec(document, overridden=overridden)
    elif isinstance(spec, (str, Path)):
        spec = load_spec(spec, overrides)
    else:
        raise SpecError(f"eponet.run: expected a spec file path, a dict or a Spec, got {type(spec).__name__}")
    Pipeline(spec).run(invocation={"api": "eponet.run", "overrides": overrides})  # (paths recorded as strings)
    return json.loads((spec.output.dir / "run.json").read_text())


@dataclass
class Segmentation:
    """What :func:`segment` returns, maps at the input frame size ``(F, H, W)``: ``masks`` uint8 in {0, 1}
    (``None`` without a refiner stage), ``saliency`` float32 foreground probability in [0, 1] (``None`` without a
    motion net), ``ed`` float32 epipolar distance in pixels of the input frames (``None`` without a rigidity
    stage), and ``manifest``, the run's record as ``run.json`` would hold it for this one sequence."""

    masks: np.ndarray | None
    saliency: np.ndarray | None
    ed: np.ndarray | None
    manifest: dict


def segment(video, preset: str = "epo", *, scale: float = 0.5, max_frames: int | None = None,
            device: str | None = None, cache: bool = True, **stages: Any) -> Segmentation:
    """Segment the moving objects of one video into arrays; nothing is written but the cache.

    Parameters
    ----------
    video : path, list of arrays or array
        A video file or a folder of frames; a list of uint8 RGB ``(H, W, 3)`` frames; or a uint8 ``(F, H, W, 3)``
        array. At least 3 frames of at least 16x16 px.
    preset : str
        ``geometry``, ``epo`` (default) or ``epo+``.
    scale, max_frames
        As ``input.scale`` and ``input.max_frames`` of a spec.
    device : str, optional
        ``cpu``, ``cuda`` or ``auto`` for every stage that has a ``device`` parameter.
    cache : bool
        Reuse and store intermediate results in the cache (``cache.dir``'s default, ``$EPONET_CACHE``).
    **stages
        Stage overrides as in a spec's ``stages:``, e.g. ``refiner={"plugin": "threshold"}`` or ``refiner=None``.

    Examples
    --------
    >>> import numpy as np, eponet
    >>> frames = np.random.default_rng(0).integers(0, 256, (4, 32, 32, 3), dtype=np.uint8)
    >>> result = eponet.segment(frames, "geometry", scale=1.0, cache=False)
    >>> result.ed.shape, result.ed.dtype.name, result.masks is None
    ((4, 32, 32), 'float32', True)
    """
    from .core.inputs import discover_sequences, load_video, video_from_frames
    from .core.outputs import ed_at_input_size
    from .core.pipeline import Pipeline, _Timer
    from .core.spec import parse_spec
    from .core.workers import blas_threads_limited

    path = Path(video) if isinstance(video, (str, Path)) else None
    document = {"preset": preset, "input": {"path": str(path or "."), "scale": scale, "max_frames": max_frames},
                "stages": dict(stages), "output": {"dir": tempfile.gettempdir(), "save": []},
                "cache": {"enabled": cache}}
    spec = parse_spec(document)
    if device is not None:
        for kind, config in spec.stages.items():
            if any(param.name == "device" for param in config.spec.params):
                document["stages"][kind] = {**(document["stages"].get(kind) or {}), "device": device}
        spec = parse_spec(document)
    keep_full = "refiner" in spec.stages
    if path is not None:
        sources = discover_sequences(path, max_frames=max_frames)
        if len(sources) > 1:
            raise InputError(f"eponet.segment: {path} holds {len(sources)} sequences; segment takes one video "
                             f"(eponet.run processes a DAVIS root)")
        source = sources[0]
        clip = load_video(source, scale=scale, max_frames=max_frames, keep_full=keep_full)
    elif isinstance(video, (list, tuple, np.ndarray)):
        clip = video_from_frames(video, scale=scale, max_frames=max_frames, keep_full=keep_full)
    else:
        raise InputError(f"eponet.segment: expected a path, a list of frames or a (F, H, W, 3) uint8 array, got "
                         f"{type(video).__name__}")
    pipeline = Pipeline(spec)
    timer = _Timer()
    with blas_threads_limited():  # small matrices: see eponet.core.workers.BLAS_THREADS
        result = pipeline.process(clip, timer)
    manifest = pipeline.record({"api": "eponet.segment"})
    manifest["spec"]["input"]["path"] = str(path) if path is not None else None
    manifest["spec"].pop("output")
    manifest["sequences"] = {clip.name: {"frames": clip.num_frames, "input_size": list(clip.size),
                                         "processing_size": list(clip.shape),
                                         "timings_s": {k: round(v, 4) for k, v in timer.timings.items()},
                                         "cached": timer.cached}}
    ed = None if result.ed is None else np.stack([ed_at_input_size(e, clip.size) for e in result.ed])
    return Segmentation(masks=result.masks, saliency=result.saliency, ed=ed, manifest=manifest)

