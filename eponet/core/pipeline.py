"""Runs a validated spec: stage by stage per sequence, with caching, timings, outputs and a run manifest."""

from __future__ import annotations

import json
import logging
import platform
import sys
import time
import zlib
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path

import numpy as np

from .cache import Cache, array_digest, code_fingerprint, content_key
from .errors import EponetError, StageError
from .imaging import resize_map
from .inputs import discover_sequences, load_video
from .io import atomic_write_bytes
from .motion import motion_images, normalise_ed
from .outputs import SequenceOutputs, write_sequence
from .spec import Spec
from .types import FlowPair, RigidityResult, Trajectories, Video

__all__ = ["Pipeline", "run_spec", "library_versions"]

log = logging.getLogger(__name__)

_LIBRARIES = ("numpy", "scipy", "torch", "opencv-python-headless", "pluggy", "pydensecrf2", "scikit-image", "PyYAML", "pillow")


def library_versions() -> dict[str, str | None]:
    versions = {"python": platform.python_version(), "eponet": _dist_version("eponet")}
    versions.update({name: _dist_version(name) for name in _LIBRARIES})
    return versions


def _dist_version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


@dataclass
class _Timer:
    timings: dict[str, float] = field(default_factory=dict)
    cached: list[str] = field(default_factory=list)
    triplets: list[dict] = field(default_factory=list)


class Pipeline:
    """Builds the stages of a spec once and runs them on sequences."""

    def __init__(self, spec: Spec, *, cache: Cache | None = None):
        self.spec = spec
        self.cache = cache or Cache(spec.cache_dir, enabled=spec.cache_enabled)
        self.stages = {}
        for kind, config in spec.stages.items():
            try:
                self.stages[kind] = config.build()
            except EponetError:
                raise
            except Exception as exc:
                raise StageError(f"stages.{kind}: plugin {config.plugin!r} failed to start: {exc}") from exc

    # -- one sequence --------------------------------------------------------------------------
    def process(self, video: Video, timer: _Timer | None = None) -> SequenceOutputs:
        """Run every stage on ``video``; returns what the outputs need."""
        timer = timer or _Timer()
        spec, stages = self.spec, self.stages
        result = SequenceOutputs(video=video)
        input_key = array_digest(video.frames)
        key_of = self._key

        flow_key = key_of("flow", input_key, stems=video.stems, size=video.size)
        result.flow = self._cached("flow", flow_key, timer, video,
                                   lambda: stages["flow"].estimate(video),
                                   lambda f: ({"forward": f.forward, "backward": f.backward}, {}),
                                   lambda a, m: FlowPair(a["forward"], a["backward"]))
        _check_flow(result.flow, video)
        if "rigidity" in stages:
            traj_key = key_of("trajectories", flow_key)
            rig_key = key_of("rigidity", traj_key, seed=spec.seed)
            cached = self.cache.load("rigidity", rig_key)
            if cached is not None:
                rigidity = RigidityResult(cached[0]["ed"], cached[0].get("per_trajectory"), cached[1].get("triplets", []))
                timer.timings["trajectories"] = 0.0
                timer.timings["rigidity"] = 0.0
                timer.cached += ["trajectories", "rigidity"]
            else:
                trajectories = self._cached("trajectories", traj_key, timer, video,
                                            lambda: stages["trajectories"].build(result.flow),
                                            lambda tr: ({k: getattr(tr, k) for k in ("start", "length", "offsets", "positions", "labels")}, {}),
                                            lambda a, m: Trajectories(**a))
                rng = np.random.default_rng([spec.seed, zlib.crc32(video.name.encode())])
                rigidity = self._timed("rigidity", timer, video, lambda: stages["rigidity"].score(trajectories, result.flow, rng))
                del trajectories
                arrays = {"ed": rigidity.ed}
                if rigidity.per_trajectory is not None:
                    arrays["per_trajectory"] = rigidity.per_trajectory
                self.cache.save("rigidity", rig_key, arrays, {"triplets": rigidity.triplets})
            result.ed = rigidity.ed
            timer.triplets = rigidity.triplets
            # unsaturated: the motion net saturates the ED channel as its weights were trained (ed_encoding)
            result.motion_images = motion_images(result.flow, normalise_ed(rigidity.ed, saturate=False))
        if "motion_net" in stages:
            saliency = self._timed("motion_net", timer, video, lambda: stages["motion_net"].predict(result.motion_images))
            probability = saliency
            if "fusion" in stages:
                features = self.appearance_features(video, timer)
                probability = self._timed("fusion", timer, video, lambda: stages["fusion"].fuse(features, saliency))
            result.saliency = np.stack([resize_map(p, video.size) for p in probability]).clip(0, 1)
        if "refiner" in stages:
            frames = video.full_frames if video.full_frames is not None else video.frames
            result.masks = self._timed("refiner", timer, video, lambda: stages["refiner"].refine(frames, result.saliency))
        return result

    def appearance_features(self, video: Video, timer: _Timer | None = None) -> np.ndarray:
        """The appearance stage's features float32 ``(F, C, h, w)`` of ``video.frames``, through the cache.

        They are stored and returned at float16 precision (relative error <= 2**-11), which halves the cache
        (a 240p frame's 472 EfficientNet-Lite0 channels take 1.5 MB instead of 3 MB); a cache hit and a fresh
        computation therefore give the same values.
        """
        if "appearance" not in self.stages:
            raise StageError("stages.appearance: the spec has no appearance stage")
        key = self._key("appearance", array_digest(video.frames))
        stored = self._cached("appearance", key, timer or _Timer(), video,
                              lambda: self.stages["appearance"].features(video).astype(np.float16),
                              lambda f: ({"features": f}, {}), lambda a, m: a["features"])
        return stored.astype(np.float32)

    def _key(self, kind: str, upstream: str, **extra) -> str:
        """Cache key of stage ``kind``: its plugin, version, code fingerprint, parameters and upstream key."""
        config = self.spec.stages[kind]
        code = code_fingerprint(config.spec.factory.__module__) if config.spec.package == "eponet" else None
        return content_key(stage=kind, plugin=config.plugin, version=config.spec.version, code=code,
                           params=config.params, upstream=upstream, **extra)

    def _timed(self, kind: str, timer: _Timer, video: Video, compute):
        start = time.perf_counter()
        try:
            value = compute()
        except EponetError:
            raise
        except Exception as exc:
            raise StageError(f"{video.name}: stage {kind} ({self.spec.stages[kind].plugin}) failed: "
                             f"{exc.__class__.__name__}: {exc}") from exc
        timer.timings[kind] = timer.timings.get(kind, 0.0) + time.perf_counter() - start
        return value

    def _cached(self, kind: str, key: str, timer: _Timer, video: Video, compute, encode, decode):
        hit = self.cache.load(kind, key)
        if hit is not None:
            timer.timings[kind] = 0.0
            timer.cached.append(kind)
            return decode(*hit)
        value = self._timed(kind, timer, video, compute)
        arrays, meta = encode(value)
        self.cache.save(kind, key, arrays, meta)
        return value

    # -- a whole run ---------------------------------------------------------------------------
    def run(self) -> dict:
        """Process every input sequence, write outputs and ``run.json``; returns the manifest."""
        spec = self.spec
        started = time.time()
        sources = discover_sequences(spec.input.path, sequences=spec.input.sequences,
                                     resolution=spec.input.resolution, max_frames=spec.input.max_frames)
        manifest = {
            "eponet": _dist_version("eponet"),
            "spec_file": spec.file,
            "spec": spec.document,
            "seed": spec.seed,
            "plugins": {kind: {"plugin": c.plugin, "package": c.spec.package, "version": c.spec.version,
                               "params": c.params} for kind, c in spec.stages.items()},
            "libraries": library_versions(),
            "started": datetime.fromtimestamp(started, timezone.utc).isoformat(timespec="seconds"),
            "sequences": {},
        }
        for source in sources:
            video = load_video(source, scale=spec.input.scale, max_frames=spec.input.max_frames)
            timer = _Timer()
            log.info("%s: %d frames at %dx%d (input %dx%d)", video.name, video.num_frames, video.shape[1],
                     video.shape[0], video.size[1], video.size[0])
            result = self.process(video, timer)
            start = time.perf_counter()
            write_sequence(result, spec.output.dir, spec.output.save)
            timer.timings["write"] = time.perf_counter() - start
            manifest["sequences"][video.name] = {
                "frames": video.num_frames,
                "input_size": list(video.size),
                "processing_size": list(video.shape),
                "timings_s": {k: round(v, 4) for k, v in timer.timings.items()},
                "cached": timer.cached,
                "triplets": _summarise_triplets(timer.triplets),
            }
        if spec.evaluate is not None:
            manifest["evaluation"] = self.evaluate([s.name for s in sources])
        manifest["total_seconds"] = round(time.time() - started, 3)
        atomic_write_bytes(spec.output.dir / "run.json", json.dumps(manifest, indent=2, default=_json_default).encode())
        return manifest

    def evaluate(self, sequences: list[str]) -> dict:
        """Score the written masks against ground truth (the spec's ``evaluate:`` section)."""
        from eponet.evaluation import evaluate

        options = self.spec.evaluate
        extra = {}
        root = options.get("root") or self.spec.input.path
        if options["dataset"] == "generic":  # ground-truth masks folder + the frames that were processed
            root, extra["frames"] = options.get("masks") or root, self.spec.input.path
        return evaluate(
            options["dataset"],
            root=root,
            results=self.spec.output.dir,
            sequences=sequences,
            resolution=options.get("resolution") or self.spec.input.resolution,
            compute_t=options.get("t", True),
            **extra,
        )


def _summarise_triplets(triplets: list[dict]) -> dict:
    if not triplets:
        return {}
    models: dict[str, int] = {}
    for triplet in triplets:
        model = str(triplet.get("model", "unknown"))
        models[model] = models.get(model, 0) + 1
    fallbacks = sum(1 for t in triplets if t.get("fallback"))
    return {"count": len(triplets), "models": models, "fallbacks": fallbacks}


def _check_flow(flow: FlowPair, video: Video) -> None:
    expected = (video.num_frames - 1,) + video.shape + (2,)
    for name, field_ in (("forward", flow.forward), ("backward", flow.backward)):
        if field_.shape != expected:
            raise StageError(f"{video.name}: {name} flow has shape {field_.shape}, expected {expected}")
        if not np.isfinite(field_).all():
            raise StageError(f"{video.name}: {name} flow has NaN or infinite values")


def _json_default(value):
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    return str(value)


def run_spec(spec: Spec, *, cache: Cache | None = None) -> dict:
    return Pipeline(spec, cache=cache).run()
