"""Runs a validated spec: the stages of the graph streamed over each sequence, sequences in worker processes,
with caching, timings, outputs written as frames complete, and a run manifest written per finished sequence
(so that a run that was interrupted resumes where it stopped)."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import platform
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from importlib import metadata
from pathlib import Path
from typing import Iterator

import numpy as np

from .cache import Cache, code_fingerprint, content_key, factory_module
from .errors import EponetError, InputError, OutputError, SequenceFailures, StageError
from .graph import GRAPH, check_stage
from .html_report import write_report
from .inputs import SequenceSource, discover_sequences, iter_frames
from .io import atomic_write_bytes, is_no_space, no_space_error
from .memory import needs_full_frames, warn_about_memory
from .outputs import SequenceOutputs, SequenceWriter, remove_partials
from . import progress
from .sanity import SequenceChecks
from .spec import Spec
from .stream import FrameItem, Handoff, SequenceStream, video_digest
from .workers import blas_threads_limited, run_in_workers, torch_threads, torch_threads_limited, worker_count
from .types import FlowPair, Video

__all__ = ["Pipeline", "run_spec", "stage_times_line", "library_versions", "sequences_overlap"]

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


@dataclass
class OpenSequence:
    """A sequence whose stream is prepared, its front possibly running ahead (:meth:`Pipeline.open_sequence`);
    :meth:`Pipeline.finish_sequence` runs the rest."""

    source: SequenceSource
    stream: SequenceStream
    front: Iterator[FrameItem]  # a Front, or a generator without threads (both close())
    handoff: Handoff  # when the front's parts have ended
    first: str  # the first frame's stem

    def close(self) -> None:
        """Stop the front's threads (a sequence that will not be finished, or one that was)."""
        self.front.close()


class Pipeline:
    """Builds the stages of a spec once (each checked against its kind's protocol) and runs them on sequences."""

    def __init__(self, spec: Spec, *, cache: Cache | None = None):
        self.spec = spec
        self.cache = cache or Cache(spec.cache_dir, enabled=spec.cache_enabled)
        self.stages = {}
        for node in GRAPH:
            config = spec.stages.get(node.kind)
            if config is None:
                continue
            try:
                stage = config.build()
            except EponetError:
                raise
            except Exception as exc:
                raise StageError(f"stages.{node.kind}: plugin {config.plugin!r} failed to start: {exc}") from exc
            problem = check_stage(node.kind, config.plugin, stage)
            if problem:
                raise StageError(problem)
            self.stages[node.kind] = stage

    # -- one sequence, whole -------------------------------------------------------------------
    def process(self, video: Video, timer: _Timer | None = None) -> SequenceOutputs:
        """Run every stage on an in-memory ``video`` (the same streaming loop as :meth:`run`); returns the whole
        sequence's results (memory grows with the video: for tools such as the trainers)."""
        timer = timer or _Timer()
        stream = SequenceStream(self, video.name, video.size, video.shape,
                                digest=video_digest(video.frames) if self.cache.enabled else None)
        items = []
        frames = (FrameItem(t, video.stems[t], video.frames[t],
                            video.full_frames[t] if video.full_frames is not None else None)
                  for t in range(video.num_frames))
        for item in stream.items(frames, threads=False):
            items.append(item)
        timer.timings.update(stream.timings)
        timer.cached += stream.cached
        timer.triplets = stream.triplets
        result = SequenceOutputs(video=video)
        if items[0].forward is not None:
            result.flow = FlowPair(np.stack([i.forward for i in items[:-1]]), np.stack([i.backward for i in items[:-1]]))
        if items[0].ed is not None:
            result.ed = np.stack([i.ed for i in items])
        if items[0].motion_image is not None:
            result.motion_images = np.stack([i.motion_image for i in items])
        if items[0].probability is not None:
            result.saliency = np.stack([i.probability for i in items])
        if items[0].mask is not None:
            result.masks = np.stack([i.mask for i in items])
        return result

    def appearance_features(self, video: Video, timer: _Timer | None = None) -> np.ndarray:
        """The appearance stage's features float32 ``(F, C, h, w)`` of ``video.frames``, through the cache
        (entries of ``run.chunk`` frames, the ones a run makes)."""
        if "appearance" not in self.stages:
            raise StageError("stages.appearance: the spec has no appearance stage")
        stream = SequenceStream(self, video.name, video.size, video.shape)
        chunk = self.spec.run.chunk
        parts = []
        for start in range(0, video.num_frames, chunk):
            frames = video.frames[start : start + chunk]
            parts.append(self.features_of(frames, Video(video.name, frames, video.stems[start : start + chunk],
                                                        video.size), stream))
        if timer is not None:
            timer.timings.update(stream.timings)
            timer.cached += [k for k in ("appearance",) if k in stream._hits and k not in stream._misses]
        return np.concatenate(parts)

    def features_of(self, frames: np.ndarray, video: Video, stream: SequenceStream) -> np.ndarray:
        """Features of a chunk of frames through the cache. They are stored and returned at float16 precision
        (relative error <= 2**-11), which halves the cache; a hit and a fresh computation give the same values."""
        from .cache import array_digest

        key = self.key("appearance", array_digest(frames))
        hit = stream._cache_get("appearance", key, frames=len(frames))
        if hit is not None:
            return hit[0]["features"].astype(np.float32)
        features = stream._call("appearance", lambda: self.stages["appearance"].features(video), frames=len(frames),
                                shape=video.shape).astype(np.float16)
        self.cache.save("appearance", key, {"features": features})
        return features.astype(np.float32)

    def key(self, kind: str, upstream: str, **extra) -> str:
        """Cache key of stage ``kind``: its plugin, version, code fingerprint (built-in or third-party:
        :func:`~eponet.core.cache.code_fingerprint`), parameters, what they resolved to on this machine (a stage's
        ``resolved`` dict, e.g. ``precision: auto`` -> bfloat16, where it has one) and upstream key."""
        config = self.spec.stages[kind]
        code = code_fingerprint(factory_module(config.spec.factory))  # a third-party plugin's package too
        resolved = getattr(self.stages.get(kind), "resolved", None)
        if isinstance(resolved, dict):
            extra = {**extra, "resolved": resolved}
        return content_key(stage=kind, plugin=config.plugin, version=config.spec.version, code=code,
                           params=config.params, upstream=upstream, **extra)

    # -- one sequence, streamed ----------------------------------------------------------------
    def run_sequence(self, source: SequenceSource) -> dict:
        """Stream one sequence through the stages, writing its outputs as frames complete; returns its
        ``run.json`` entry."""
        return self.finish_sequence(self.open_sequence(source))

    def open_sequence(self, source: SequenceSource, *, after: Handoff | None = None) -> "OpenSequence":
        """Read the first frame of ``source`` (an unreadable input raises :class:`InputError` here) and prepare
        its stream; with ``run.threads`` the front of the stream (flow, trajectories, rigidity) starts at once in
        its threads, each part after the same part of the sequence whose :class:`Handoff` is ``after``, and works
        ahead while :meth:`finish_sequence` of the previous sequence runs. Nothing is written under ``output.dir``
        before :meth:`finish_sequence`; :meth:`OpenSequence.close` stops a sequence that will not be finished."""
        spec = self.spec
        needs_full = needs_full_frames(spec)
        frames = iter_frames(source, scale=spec.input.scale, max_frames=spec.input.max_frames, keep_full=needs_full)
        first = next(frames)
        size = first[2].shape[:2] if first[2] is not None else source.size
        shape = first[1].shape[:2]

        def items():
            yield FrameItem(0, first[0], first[1], first[2])
            for t, (stem, frame, full) in enumerate(frames, start=1):
                yield FrameItem(t, stem, frame, full)

        def digest():  # one decoding pass more, for cache keys that depend on the whole video
            return video_digest(frame for _, frame, _ in iter_frames(source, scale=spec.input.scale,
                                                                     max_frames=spec.input.max_frames, keep_full=False))

        size = tuple(int(v) for v in (size or shape))
        stream = SequenceStream(self, source.name, size, tuple(int(v) for v in shape))
        handoff = Handoff()
        front = stream.front(items(), threads=spec.run.threads, previous=after, handoff=handoff,
                             digest=digest if self.cache.enabled else None)
        if spec.run.threads:
            front.start()
        return OpenSequence(source, stream, front, handoff, first[0])

    def finish_sequence(self, opened: "OpenSequence") -> dict:
        """Run the rest of an :meth:`open_sequence` (motion net, appearance, fusion, refiner) and write its outputs
        as frames complete; returns its ``run.json`` entry."""
        spec, source, stream = self.spec, opened.source, opened.stream
        started = time.perf_counter()
        log.info("%s: frames at %dx%d (input %dx%d)", source.name, stream.shape[1], stream.shape[0],
                 stream.size[1], stream.size[0])
        writer = SequenceWriter(spec.output.dir, source.name, spec.output.save, stream.size, stream.shape,
                                fps=spec.output.fps or source.fps)
        checks = SequenceChecks(source.name)
        count, last_stem = 0, None
        report = progress.current()
        report.start(source.name, source.count)
        try:
            write_time = 0.0
            for item in stream.back(opened.front):
                start = time.perf_counter()
                writer.write(item)
                write_time += time.perf_counter() - start
                checks.observe(item.t, item.motion_flow, item.mask)
                count += 1
                last_stem = item.stem
                report.advance(source.name)
            writer.close()
        except BaseException:
            writer.abort()
            raise
        finally:
            opened.close()
            report.finish(source.name)
        stream.timings["write"] = write_time
        return {
            "frames": count,
            "input_size": list(stream.size),
            "processing_size": list(stream.shape),
            "timings_s": {k: round(v, 4) for k, v in stream.timings.items()},
            "seconds": round(time.perf_counter() - started, 3),
            "cached": stream.cached,
            "frames_from_cache": stream.from_cache,
            "triplets": _summarise_triplets(stream.triplets),
            **checks.finish(),
            "config": self.config_digest(),
            **({"stopped": f"{source.stopped}; the sequence ends there: its first {count} frames ({opened.first} to "
                           f"{last_stem}) were processed and their outputs kept"} if source.stopped else {}),
        }

    def config_digest(self) -> str:
        """What a sequence's outputs depend on besides its frames (stages, parameters, seed, run settings,
        outputs): a finished sequence is reused on a re-run only when this is unchanged."""
        document = {k: v for k, v in self.spec.document.items() if k not in ("cache", "evaluate")}
        document["run"] = {k: v for k, v in document.get("run", {}).items() if k in ("chunk", "lag")}
        return hashlib.sha256(json.dumps(document, sort_keys=True, default=str).encode()).hexdigest()[:16]

    # -- a whole run ---------------------------------------------------------------------------
    def run(self, *, invocation: dict | None = None) -> dict:
        """Process every input sequence, write outputs and ``run.json`` (rewritten after every finished
        sequence); sequences a previous run of the same spec finished are skipped. ``invocation`` (the command
        line's ``--set`` overrides and cache options) is recorded as given. The records of earlier runs into the
        same ``output.dir`` move into the new record's ``runs`` list, oldest first. Returns the manifest.

        Of several sequences, a corpus entry that is missing or unreadable, a sequence whose input or a stage fails
        on it (with ``run.executor: ray`` any failure, a lost worker included) is recorded under ``failed`` while
        the others run; then :class:`SequenceFailures` is raised. A failure of the output folder (a full disk)
        stops the run."""
        spec = self.spec
        started = time.time()
        sources = discover_sequences(spec.input.path, sequences=spec.input.sequences,
                                     resolution=spec.input.resolution, max_frames=spec.input.max_frames, isolate=True)
        remove_partials(spec.output.dir)
        previous = _read_record(spec.output.dir / "run.json")
        runs = previous.pop("runs", [])
        history = (runs if isinstance(runs, list) else []) + ([previous] if previous else [])
        manifest = {**self.record(invocation, started), "sequences": {}, "runs": history}
        config = self.config_digest()
        earlier = previous.get("sequences") if isinstance(previous.get("sequences"), dict) else {}
        todo = []
        failures: dict[str, tuple[str, int]] = {}

        def failed(name: str, reason: str, exit_code: int) -> None:
            """A sequence that cannot finish: named on the console and in ``run.json``; the others go on."""
            failures[name] = (reason, exit_code)
            manifest["failed"] = {n: {"reason": r, "exit_code": c} for n, (r, c) in failures.items()}
            if len(sources) > 1:  # a run of one sequence ends with this line as its error
                log.error("%s: failed: %s", name, reason)
            _write_manifest(spec.output.dir / "run.json", manifest)

        for source in sources:
            entry = earlier.get(source.name)
            if source.error is not None:  # a corpus entry that is missing or unreadable
                failed(source.name, source.error, 2)
                continue
            if (entry and entry.get("config") == config and not entry.get("stopped")
                    and (spec.output.dir / source.name).is_dir()):
                manifest["sequences"][source.name] = {**entry, "resumed": True}
                log.info("%s: finished by an earlier run of this spec; skipped", source.name)
            else:
                todo.append(source)
        workers = worker_count(spec.run.workers, len(todo))
        manifest["workers"] = workers
        warn_about_memory(spec, todo, overlap=sequences_overlap(spec, len(todo)))
        order = {s.name: k for k, s in enumerate(sources)}

        done = []

        def finished(name: str, entry: dict) -> None:
            manifest["sequences"][name] = entry
            manifest["sequences"] = dict(sorted(manifest["sequences"].items(), key=lambda kv: order.get(kv[0], 0)))
            _write_manifest(spec.output.dir / "run.json", manifest)
            if entry.get("stopped"):  # cut short by a corrupt frame: its outputs are kept, and the run fails
                failed(name, entry["stopped"], 2)
            done.append(name)
            log.info("%s", stage_times_line(name, entry))
            log.info("%d/%d sequences done, %.1f s elapsed", len(done), len(todo), time.time() - started)

        # of several sequences, one whose input or stage fails is recorded and the others go on (a run of one
        # sequence fails with that sequence's own error)
        isolate = failed if len(sources) > 1 else None
        total = sum(s.count for s in todo) if all(s.count for s in todo) else None
        with progress.RunProgress(total).active():
            if spec.run.executor == "ray":
                from .ray_executor import run_on_ray

                manifest["ray"] = run_on_ray(self, todo, finished, failed)
            elif workers <= 1:
                with torch_threads_limited(torch_threads(os.cpu_count() or 1, spec.run.threads)), blas_threads_limited():
                    self._run_here(todo, finished, isolate)
            else:
                run_in_workers(self, todo, workers, finished, isolate)
        manifest["total_seconds"] = round(time.time() - started, 3)
        _write_manifest(spec.output.dir / "run.json", manifest)  # the record is kept whatever scoring does
        if failures:
            self._write_report(manifest)  # of the sequences that finished
            raise SequenceFailures(failures, len(sources))
        if spec.evaluate is not None:
            from .registry import get_registry

            try:
                manifest["evaluation"] = get_registry().evaluate(spec, [s.name for s in sources])
            except BaseException as exc:
                manifest["evaluation"] = {"error": f"{exc.__class__.__name__}: {exc}"}
                _write_manifest(spec.output.dir / "run.json", manifest)
                self._write_report(manifest)  # the page says that scoring failed
                raise
            manifest["total_seconds"] = round(time.time() - started, 3)
            _write_manifest(spec.output.dir / "run.json", manifest)
        self._write_report(manifest)
        return manifest

    def _run_here(self, todo: list[SequenceSource], finished, isolate) -> None:
        """The sequences one after another in this process. With ``run.threads`` the next sequence is opened while
        the current one runs: its flow starts as soon as the current one's flow is done and its geometry after the
        current one's geometry, so the next video's flow and geometry overlap this one's geometry, networks and
        CRF on other cores. The outputs are those of one sequence at a time (each stage still sees the sequences in
        order, one at a time); memory holds two sequences' windows at the end of each."""
        overlap = sequences_overlap(self.spec, len(todo))
        current = upcoming = None  # an OpenSequence, or the error its opening raised (raised at its turn)
        try:
            for k, source in enumerate(todo):
                current, upcoming = upcoming if upcoming is not None else self._open_or_error(source), None
                try:
                    if overlap and k + 1 < len(todo):
                        after = current.handoff if isinstance(current, OpenSequence) else None
                        upcoming = self._open_or_error(todo[k + 1], after=after)
                    if isinstance(current, BaseException):
                        raise current
                    entry = self.finish_sequence(current)
                except (InputError, StageError) as exc:
                    if isolate is None:
                        raise
                    isolate(source.name, str(exc), exc.exit_code)
                    continue
                finally:
                    if isinstance(current, OpenSequence):
                        current.close()
                finished(source.name, entry)
        finally:
            for opened in (current, upcoming):
                if isinstance(opened, OpenSequence):
                    opened.close()

    def _open_or_error(self, source: SequenceSource, *, after: Handoff | None = None):
        """:meth:`open_sequence`, or the exception it raised (raised in turn when the sequence's turn comes)."""
        try:
            return self.open_sequence(source, after=after)
        except Exception as exc:
            return exc

    def _write_report(self, manifest: dict) -> None:
        if "report" in self.spec.output.save:
            log.info("report: %s", write_report(self.spec.output.dir, manifest))

    def record(self, invocation: dict | None = None, started: float | None = None) -> dict:
        """What ``run.json`` says about the run besides its sequences: versions, the resolved spec and cache,
        ``invocation`` as given, seed, plugins, weights digests, what stages resolved at build (a stage's
        ``resolved`` dict, e.g. the motion net's device and precision), libraries and the start time."""
        spec = self.spec
        started = time.time() if started is None else started
        return {
            "eponet": _dist_version("eponet"),
            "spec_file": spec.file,
            "spec": {**spec.document, "cache": {"enabled": self.cache.enabled, "dir": str(self.cache.root)}},
            "invocation": invocation or {},
            "seed": spec.seed,
            "plugins": {kind: {"plugin": c.plugin, "package": c.spec.package, "version": c.spec.version,
                               "params": c.params} for kind, c in spec.stages.items()},
            "weights_sha256": self.weights_digests(),
            "resolved": {kind: dict(stage.resolved) for kind, stage in self.stages.items()
                         if isinstance(getattr(stage, "resolved", None), dict)},
            "libraries": library_versions(),
            "started": datetime.fromtimestamp(started, timezone.utc).isoformat(timespec="seconds"),
        }

    def weights_digests(self) -> dict:
        """sha256 of every weights file the stages use (a stage's ``sha256`` attribute: one or a list)."""
        return {kind: getattr(stage, "sha256") for kind, stage in self.stages.items()
                if isinstance(getattr(stage, "sha256", None), (str, list))}


def stage_times_line(name: str, entry: dict) -> str:
    """One line of a finished sequence's stage seconds, e.g. ``bear: flow 6.3 s, trajectories 4.8 s, ...; 82
    frames in 31.0 s``."""
    stages = ", ".join(f"{kind} {seconds:.1f} s" for kind, seconds in entry.get("timings_s", {}).items())
    cached = f" (cached: {', '.join(entry['cached'])})" if entry.get("cached") else ""
    return f"{name}: {stages}{cached}; {entry.get('frames', 0)} frames in {entry.get('seconds', 0):.1f} s"


def sequences_overlap(spec: Spec, sequences: int) -> bool:
    """Whether a run of ``sequences`` sequences starts the next one's flow and geometry while one finishes (in one
    process with ``run.threads``: :meth:`Pipeline._run_here`)."""
    return (spec.run.threads and spec.run.executor != "ray" and sequences > 1
            and worker_count(spec.run.workers, sequences) <= 1)


def _read_record(path: Path) -> dict:
    """An earlier run's ``run.json``; one that cannot be read is kept aside as ``run-unreadable-<time>.json``."""
    if not path.is_file():
        return {}
    try:
        record = json.loads(path.read_text())
        if isinstance(record, dict):
            return record
    except (OSError, ValueError):
        pass
    aside = path.with_name(f"run-unreadable-{int(time.time())}.json")
    log.warning("%s: unreadable run record, kept as %s", path, aside.name)
    try:
        os.replace(path, aside)
    except OSError:
        pass
    return {}


def _write_manifest(path: Path, manifest: dict) -> None:
    try:
        atomic_write_bytes(path, json.dumps(manifest, indent=2, default=_json_default).encode())
    except OSError as exc:
        if is_no_space(exc):
            raise no_space_error(path.parent, f"writing {path.name}") from None
        raise OutputError(f"{path}: cannot write the run manifest ({exc.strerror or exc})") from None


def _summarise_triplets(triplets: list[dict]) -> dict:
    if not triplets:
        return {}
    models: dict[str, int] = {}
    for triplet in triplets:
        model = str(triplet.get("model", "unknown"))
        models[model] = models.get(model, 0) + 1
    fallbacks = sum(1 for t in triplets if t.get("fallback"))
    return {"count": len(triplets), "models": models, "fallbacks": fallbacks}


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
