"""The streaming run loop of one sequence: frames decoded lazily and passed through the stage graph in chunks,
so that memory is bounded by a window of frames, not by the length of the video.

Each stage of :data:`eponet.core.graph.GRAPH` is driven by its temporal context:

- ``pairs`` (flow): chunks of ``run.chunk + 1`` frames, consecutive chunks sharing one frame.
- ``state`` + ``groups`` (trajectories, rigidity): the trajectory builder's live state is advanced one flow
  pair at a time; the rigidity stage scores windows of ``run.chunk`` frame groups (plus the
  ``(views - 1) * stride`` frames the last group reaches), each group in exactly one window, with one seeded
  generator drawn in order over the windows. Each trajectory's mean distance is accumulated over its groups
  across windows. **Lag**: frame t is painted once every group starting at or before ``t + run.lag`` has been
  scored; a trajectory covering t that ended by then has its final mean, a longer one the mean over its groups
  so far (it has run at least ``lag`` frames past t).
- ED scale: the motion net's ED scale of frame t is the 95th percentile over frames ``t - 30 .. t + 30``
  (``run.ed_window``, default :data:`eponet.core.motion.ED_WINDOW`), so it waits for 30 painted frames of look-ahead
  (``ed_window: null``: the whole video's scale, so every frame waits for the last).
- ``frame`` (motion net, appearance, refiner): batches of ``run.chunk`` frames.
- ``window`` (fusion): the stage's own ``window`` / ``overlap`` windows, each run as soon as its frames exist;
  every frame is taken from the window where it lies farthest from an inner window edge (centre stitching).

With ``run.chunk`` and ``run.lag`` at least the video's length the loop computes exactly what a whole-video
composition of the same stages computes (``tests/core/test_stream.py``); shorter settings differ only in what
the lag cuts off (a rigidity stage with ``new_history()``, as the built-in ones, carries guided sampling's
memory from window to window, so its groups are sampled as in the whole video).

Threads: the **front** of a sequence (flow; trajectories, rigidity and the ED scale) runs in two threads, the
**back** (motion net, appearance, fusion, refiner) in the caller's (:meth:`SequenceStream.front`,
:meth:`SequenceStream.back`). Of several sequences in one process the next one's front starts while this one's back
runs, each part after the same part of the previous sequence (:class:`Handoff`), so that a stage sees one sequence
at a time, in order, and computes what it computes alone.

Resume: the ED maps are cached in blocks of ``chunk`` frames as they are painted, with a checkpoint of the
trajectory and rigidity state (:mod:`eponet.core.rigidity_stream`) after a block now and then, so that a run killed
in the middle of a long video takes the frames before the checkpoint from the cache and continues from there,
computing exactly what an uninterrupted run computes (``tests/core/test_rigidity_stream.py``).

Memory: about ``chunk + lag + 30`` frames of flow, trajectory records and ED maps at the processing size, plus
``chunk`` full-size frames (and the fusion's window) at a time; :func:`eponet.core.memory.memory_estimate` puts a
number on it.
"""

from __future__ import annotations

import hashlib
import logging
import sys
import threading
import time
import zlib
from collections import deque
from dataclasses import dataclass, field
from typing import Iterable, Iterator

import numpy as np

from .cache import array_digest
from .errors import EponetError, StageError
from .graph import KINDS, check_output
from .imaging import resize_map
from .motion import FLOW_SCALE, ed_frame_sample, ed_window_scale, normalise_ed
from .prefetch import Prefetch, wait_for
from .temporal import temporal_mean
from . import rigidity_stream
from .rigidity_stream import GeometryScorer
from .types import FlowPair, Video

__all__ = ["FrameItem", "SequenceStream", "Front", "Handoff", "video_digest"]

log = logging.getLogger(__name__)


@dataclass
class FrameItem:
    """What the loop knows about frame ``t`` as it moves through the stages (maps at the processing size unless
    stated)."""

    t: int
    stem: str
    frame: np.ndarray  # uint8 (h, w, 3)
    full: np.ndarray | None = None  # uint8 (H, W, 3) at the input size
    forward: np.ndarray | None = None  # flow t -> t+1 (None for the last frame)
    backward: np.ndarray | None = None  # flow t+1 -> t on the grid of t+1 (pair t)
    motion_flow: np.ndarray | None = None  # the frame's motion: forward, or -backward of the last pair
    ed: np.ndarray | None = None  # float32 (h, w), pixels
    ed_scale: float | None = None  # pixels: the ED scale of the frames around t
    motion_image: np.ndarray | None = None  # float32 (3, h, w)
    saliency: np.ndarray | None = None  # float32 (h, w): the motion net's probability
    features: np.ndarray | None = None  # float32 (C, fh, fw)
    fused: np.ndarray | None = None  # float32 (h, w): the fusion's probability
    averaged: np.ndarray | None = None  # float32 (h, w): fused or saliency averaged along the flow (refiner.temporal)
    probability: np.ndarray | None = None  # float32 (H, W) at the input size: what the refiner reads
    mask: np.ndarray | None = None  # uint8 (H, W)


def video_digest(frames: Iterable[np.ndarray]) -> str:
    """sha256 over the processing-size frames of a video, frame by frame (the same for a stream and an array)."""
    digest = hashlib.sha256()
    for frame in frames:
        digest.update(array_digest(np.asarray(frame)).encode())
    return digest.hexdigest()


def _graph_order(kind: str) -> int:
    return KINDS.index(kind) if kind in KINDS else len(KINDS)


@dataclass
class Handoff:
    """When the parts of a sequence's :meth:`SequenceStream.front` have ended (``flow``: its flow, ``geometry``: its
    trajectories, rigidity and ED scale): the next sequence's front in the same process waits for them."""

    flow: threading.Event = field(default_factory=threading.Event)
    geometry: threading.Event = field(default_factory=threading.Event)


class Front:
    """A sequence's front running in threads (:meth:`SequenceStream.front`): iterate it for its frames;
    :meth:`start` runs it ahead before anything is asked, :meth:`close` stops all its threads."""

    def __init__(self, closed: threading.Event, last: Prefetch, *others: Prefetch):
        self._closed = closed
        self._parts = (last, *others)

    def start(self) -> "Front":
        for part in reversed(self._parts):
            part.start()
        return self

    def __iter__(self) -> "Front":
        return self

    def __next__(self) -> FrameItem:
        return next(self._parts[0])

    def close(self) -> None:
        self._closed.set()
        for part in self._parts:  # all told first, so that none waits for another that is told later
            part.stop()
        for part in self._parts:
            part.close()


class SequenceStream:
    """Runs the stages of a :class:`~eponet.core.pipeline.Pipeline` over one sequence as a chain of generators
    of :class:`FrameItem`; :meth:`items` yields every frame once all stages are done with it."""

    def __init__(self, pipeline, name: str, size: tuple[int, int], shape: tuple[int, int], *, digest: str | None = None):
        self.pipeline = pipeline
        self.spec = pipeline.spec
        self.stages = pipeline.stages
        self.name = name
        self.size = size  # input (H, W)
        self.shape = shape  # processing (h, w)
        self.chunk = self.spec.run.chunk
        self.lag = self.spec.run.lag
        self.ed_window = self.spec.run.ed_window
        self.digest = digest
        self.timings: dict[str, float] = {}
        self.cached: list[str] = []
        self.triplets: list[dict] = []
        self._misses: set[str] = set()
        self._hits: set[str] = set()
        #: frames (flow: pairs) of each cached stage that came from the cache
        self.from_cache: dict[str, int] = {}

    # -- the chain ------------------------------------------------------------------------------
    def items(self, frames: Iterator[FrameItem], *, threads: bool = True) -> Iterator[FrameItem]:
        """Every frame of ``frames`` once all stages are done with it (:meth:`front`, then :meth:`back`)."""
        front = self.front(frames, threads=threads)
        try:
            yield from self.back(front)
        finally:
            front.close()

    def front(self, frames: Iterator[FrameItem], *, threads: bool = True, previous: "Handoff | None" = None,
              handoff: "Handoff | None" = None, digest=None) -> Iterator[FrameItem]:
        """The stages before the per-frame ones: flow, then trajectories, rigidity and the ED scale (the geometry).
        With ``threads`` a :class:`Front`, flow and geometry in a thread each, which :meth:`Front.start` runs ahead
        of any consumer. ``previous``: the :class:`Handoff` of the sequence before this one in the same process,
        whose flow (geometry) this front's flow (geometry) waits for, so that a stage never works on two sequences
        at once and sees them in order; ``handoff``: this front's own, set as its parts end, however they end;
        ``digest``: a callable giving :attr:`digest` (the cache key of the whole video), called in the geometry's
        thread before it starts."""
        geometry = "rigidity" in self.stages
        handoff = handoff or Handoff()
        closed = threading.Event()  # set when a threaded front is closed: a part still waiting for its turn ends

        def flows():
            try:
                if previous is None or wait_for(previous.flow, closed):
                    yield from self._flow(frames)
            finally:
                handoff.flow.set()

        def geometries(stream):
            try:
                if previous is None or wait_for(previous.geometry, closed):
                    if digest is not None:
                        self.digest = digest()
                    yield from self._ed_scale(self._geometry(stream))
            finally:
                handoff.geometry.set()

        if not threads:
            return geometries(flows()) if geometry else flows()
        flow = Prefetch(flows(), self.chunk + 1, "flow")
        if not geometry:
            handoff.geometry.set()
            return Front(closed, flow)
        return Front(closed, Prefetch(geometries(flow), self.chunk, "geometry"), flow)

    def back(self, stream: Iterator[FrameItem]) -> Iterator[FrameItem]:
        """The per-frame and window stages (motion net, appearance, fusion, refiner) over the items of a
        :meth:`front`, in the calling thread."""
        stages = self.stages
        if "motion_net" in stages or "rigidity" in stages or "motion_images" in self.spec.output.save:
            stream = self._motion_images(stream)
        if "motion_net" in stages:
            stream = self._per_frame("motion_net", stream, self._predict)
        if "appearance" in stages and "fusion" in stages:
            stream = self._per_frame("appearance", stream, self._features)
        if "fusion" in stages:
            stream = self._fusion(stream)
        if "refiner" in stages and getattr(stages["refiner"], "temporal", 0):
            stream = self._temporal(stream)
        stream = self._probability(stream)
        if "refiner" in stages:
            stream = self._per_frame("refiner", stream, self._refine)
        yield from stream
        # in graph order, whichever stage ran first (a resumed run may start with its trajectories)
        self.timings = {kind: self.timings[kind] for kind in sorted(self.timings, key=_graph_order)}
        for kind in ("flow", "rigidity", "appearance"):
            if kind in self._hits and kind not in self._misses:
                self.cached += ["trajectories", "rigidity"] if kind == "rigidity" else [kind]

    def _timed(self, kind: str, compute):
        start = time.perf_counter()
        try:
            value = compute()
        except EponetError:
            raise
        except Exception as exc:
            raise StageError(f"{self.name}: stage {kind} ({self.spec.stages[kind].plugin}) failed: "
                             f"{exc.__class__.__name__}: {exc}") from exc
        self.timings[kind] = self.timings.get(kind, 0.0) + time.perf_counter() - start
        return value

    def _call(self, kind: str, compute, *, frames: int | None, shape, trajectories: int | None = None):
        """Run a method of stage ``kind`` (timed) and check what it returns against the kind's protocol
        (:func:`eponet.core.graph.check_output`): a violation is a :class:`StageError` naming the plugin."""
        value = self._timed(kind, compute)
        problem = check_output(kind, self.spec.stages[kind].plugin, value, frames=frames, shape=shape,
                               trajectories=trajectories)
        if problem:
            raise StageError(f"{self.name}: {problem}")
        return value

    def _cache_get(self, kind: str, key: str, *, frames: int = 0):
        """Entry ``key`` of stage ``kind`` (``None`` on a miss); a hit counts ``frames`` in :attr:`from_cache`."""
        hit = self.pipeline.cache.load(kind, key)
        (self._hits if hit is not None else self._misses).add(kind)
        if hit is not None and frames:
            self.from_cache[kind] = self.from_cache.get(kind, 0) + frames
        return hit

    # -- pairs: flow ----------------------------------------------------------------------------
    def _flow(self, frames: Iterator[FrameItem]) -> Iterator[FrameItem]:
        buffer: list[FrameItem] = []
        before_last = None
        for item in frames:
            buffer.append(item)
            if len(buffer) == self.chunk + 1:
                self._flow_chunk(buffer)
                before_last = buffer[-2]
                yield from buffer[:-1]
                buffer = buffer[-1:]
        if len(buffer) > 1:
            self._flow_chunk(buffer)
            before_last = buffer[-2]
        last = buffer[-1]
        last.motion_flow = -before_last.backward
        yield from buffer[:-1]
        yield last

    def _flow_chunk(self, items: list[FrameItem]) -> None:
        frames = np.stack([item.frame for item in items])
        stems = [item.stem for item in items]
        video = Video(self.name, frames, stems, self.size)
        key = self.pipeline.key("flow", array_digest(frames), stems=stems, size=self.size)
        hit = self._cache_get("flow", key, frames=len(items) - 1)
        if hit is not None:
            flow = FlowPair(hit[0]["forward"], hit[0]["backward"])
        else:
            flow = self._call("flow", lambda: self.stages["flow"].estimate(video), frames=len(items) - 1,
                              shape=self.shape)
            self.pipeline.cache.save("flow", key, {"forward": flow.forward, "backward": flow.backward})
        for k, item in enumerate(items[:-1]):
            item.forward, item.backward = flow.forward[k], flow.backward[k]
            item.motion_flow = item.forward

    # -- state + groups: trajectories and rigidity ----------------------------------------------
    def _geometry(self, stream: Iterator[FrameItem]) -> Iterator[FrameItem]:
        """ED maps of every frame, through the cache: saved in blocks of ``chunk`` frames as they are painted, each
        block followed by a checkpoint of the scorer's state (:class:`~eponet.core.rigidity_stream.GeometryScorer`)
        and the whole video by an index, written last. A complete earlier run (an index) serves every map; a run
        killed half-way left blocks and a checkpoint: the frames of those blocks take their maps from the cache and
        the scorer resumes from the checkpoint, computing what an uninterrupted run computes."""
        cache = self.pipeline.cache
        key = None
        if self.digest is not None and cache.enabled:
            key = self.pipeline.key("rigidity", self.pipeline.key("trajectories", self.digest), seed=self.spec.seed,
                                    chunk=self.chunk, lag=self.lag)
            index = cache.load("rigidity", f"{key}-index")
            blocks = int(index[1].get("blocks", -1)) if index is not None else -1
            if blocks >= 0 and all(cache.exists("rigidity", f"{key}-{k}") for k in range(blocks)):
                self._hits.add("rigidity")
                self.triplets = index[1].get("triplets", [])
                yield from self._cached_geometry(stream, key)
                return
        if not hasattr(self.stages["trajectories"], "stream"):
            if key is not None:
                self._misses.add("rigidity")
            yield from self._save_blocks(self._whole_geometry(stream), key, None)
            return
        scorer = GeometryScorer(self)
        start = self._resume(scorer, key) if key is not None else 0

        def scored():
            last = -1
            for item in self._cached_geometry(stream, key, stop=start) if start else stream:
                last = item.t
                if item.t < start:
                    yield item
                    continue
                scorer.feed(item)
                yield from scorer.ready()
            yield from scorer.finish()
            if key is not None:
                (self._hits if start else self._misses).add("rigidity")
                if start <= last:  # frames computed besides those from the cache
                    self._misses.add("rigidity")

        yield from self._save_blocks(scored(), key, scorer, first_block=start // self.chunk)

    def _save_blocks(self, painted: Iterator[FrameItem], key: str | None, scorer, *, first_block: int = 0):
        """Pass ``painted`` on, saving its ED maps in blocks of ``chunk`` frames (from block ``first_block``),
        a block followed by ``scorer``'s checkpoint when the last one is
        :data:`~eponet.core.rigidity_stream.CHECKPOINT_SECONDS` old, and the index (which replaces the checkpoint)
        at the end."""
        cache = self.pipeline.cache
        block: list[np.ndarray] = []
        count = first_block
        checkpointed = time.monotonic()
        for item in painted:
            if key is None or item.t < first_block * self.chunk:
                yield item
                continue
            block.append(item.ed)
            if len(block) == self.chunk:
                cache.save("rigidity", f"{key}-{count}", {"ed": np.stack(block)})
                block, count = [], count + 1
                if scorer is not None and time.monotonic() - checkpointed >= rigidity_stream.CHECKPOINT_SECONDS:
                    saved = scorer.checkpoint()
                    if saved is not None:
                        cache.save("rigidity", f"{key}-state", saved[0], {**saved[1], "blocks": count})
                    checkpointed = time.monotonic()
            yield item
        if key is not None:
            if block:
                cache.save("rigidity", f"{key}-{count}", {"ed": np.stack(block)})
                count += 1
            cache.save("rigidity", f"{key}-index", {}, {"blocks": count, "triplets": self.triplets})
            cache.remove("rigidity", f"{key}-state")

    def _resume(self, scorer, key: str) -> int:
        """The first frame a killed run of this video left unpainted, with ``scorer`` restored to its state there
        (0, scorer untouched, without a usable checkpoint)."""
        cache = self.pipeline.cache
        saved = cache.load("rigidity", f"{key}-state")
        if saved is None:
            return 0
        arrays, meta = saved
        blocks = int(meta.get("blocks", 0))
        if meta.get("painted") != blocks * self.chunk or not all(cache.exists("rigidity", f"{key}-{k}")
                                                                 for k in range(blocks)):
            return 0
        start = scorer.restore(arrays, meta)
        if not start:
            return 0
        log.info("%s: resuming the geometry at frame %d (from the cache)", self.name, start)
        return start

    def _cached_geometry(self, stream: Iterator[FrameItem], key: str, *, stop: float = float("inf")):
        """``stream`` with the ED maps of frames before ``stop`` read from the cache's blocks (every later frame
        passed on as it is)."""
        loaded, maps = -1, None
        for item in stream:
            if item.t >= stop:
                yield item
                continue
            block = item.t // self.chunk
            if block != loaded:
                hit = self.pipeline.cache.load("rigidity", f"{key}-{block}")
                if hit is None:
                    raise StageError(f"{self.name}: cache entry {key}-{block} of the ED maps is unreadable; run with "
                                     "--no-cache or remove it")
                loaded, maps = block, hit[0]["ed"]
            item.ed = maps[item.t % self.chunk]
            self.from_cache["rigidity"] = self.from_cache.get("rigidity", 0) + 1
            yield item

    def _whole_geometry(self, stream: Iterator[FrameItem]) -> Iterator[FrameItem]:
        """A builder without ``stream()``: its flow, built at the end (memory grows with the video)."""
        builder, rigidity = self.stages["trajectories"], self.stages["rigidity"]
        rng = np.random.default_rng([self.spec.seed, zlib.crc32(self.name.encode())])
        whole = list(stream)
        frames = len(whole)
        flow = FlowPair(np.stack([i.forward for i in whole[:-1]]), np.stack([i.backward for i in whole[:-1]]))
        tracks = self._call("trajectories", lambda: builder.build(flow), frames=frames, shape=self.shape)
        result = self._call("rigidity", lambda: rigidity.score(tracks, flow, rng), frames=frames, shape=self.shape,
                            trajectories=tracks.count)
        self.triplets += list(result.triplets)
        for item in whole:
            item.ed = result.ed[item.t]
        yield from whole

    # -- the ED scale and the motion images -----------------------------------------------------
    def _ed_scale(self, stream: Iterator[FrameItem]) -> Iterator[FrameItem]:
        """Each frame's ED scale over ``run.ed_window`` frames centred on it (``None``: the whole video, so every
        frame waits for the last). The samples of consecutive frames are kept by ascending frame, and a window
        equal to the previous frame's (the whole video, or both clipped by the video's ends) is not scored again."""
        half = self.ed_window // 2 if self.ed_window is not None else sys.maxsize
        samples: dict[int, np.ndarray] = {}
        waiting: deque[FrameItem] = deque()
        scored: tuple = (None, None)  # ((first, last) frame of the last window, its scale)

        def scaled(item: FrameItem) -> FrameItem:
            nonlocal scored
            window = (max(item.t - half, next(iter(samples))), min(item.t + half, next(reversed(samples))))
            if scored[0] != window:
                frames = range(window[0], window[1] + 1)
                scored = (window, ed_window_scale([samples[t] for t in frames if t in samples]))
            item.ed_scale = scored[1]
            while samples and next(iter(samples)) < item.t - half + 1:  # not in the next frame's window
                del samples[next(iter(samples))]
            return item

        for item in stream:
            samples[item.t] = ed_frame_sample(item.ed)
            waiting.append(item)
            while waiting and waiting[0].t + half <= item.t:
                yield scaled(waiting.popleft())
        while waiting:
            yield scaled(waiting.popleft())

    def _motion_images(self, stream: Iterator[FrameItem]) -> Iterator[FrameItem]:
        for item in stream:
            if item.ed is not None:
                # unsaturated: the motion net saturates the ED channel as its weights were trained (encode_ed)
                ed = normalise_ed(item.ed[None], scales=np.array([item.ed_scale]), saturate=False)[0]
            else:
                ed = np.zeros(self.shape, np.float32)
            motion = (item.motion_flow / FLOW_SCALE).transpose(2, 0, 1)
            item.motion_image = np.concatenate([motion, ed[None]], axis=0).astype(np.float32)
            yield item

    # -- frame: batched per-frame stages --------------------------------------------------------
    def _per_frame(self, kind: str, stream: Iterator[FrameItem], apply) -> Iterator[FrameItem]:
        batch: list[FrameItem] = []
        for item in stream:
            batch.append(item)
            if len(batch) == self.chunk:
                apply(batch)
                yield from batch
                batch = []
        if batch:
            apply(batch)
            yield from batch

    def _predict(self, batch: list[FrameItem]) -> None:
        images = np.stack([item.motion_image for item in batch])
        saliency = self._call("motion_net", lambda: self.stages["motion_net"].predict(images), frames=len(batch),
                              shape=self.shape)
        for item, value in zip(batch, saliency):
            item.saliency = value

    def _features(self, batch: list[FrameItem]) -> None:
        frames = np.stack([item.frame for item in batch])
        features = self.pipeline.features_of(frames, Video(self.name, frames, [i.stem for i in batch], self.size),
                                             self)
        for item, value in zip(batch, features):
            item.features = value

    def _refine(self, batch: list[FrameItem]) -> None:
        frames = np.stack([item.full if item.full is not None else item.frame for item in batch])
        probability = np.stack([item.probability for item in batch])
        masks = self._call("refiner", lambda: self.stages["refiner"].refine(frames, probability), frames=len(batch),
                           shape=frames.shape[1:3])
        for item, value in zip(batch, masks):
            item.mask = value

    def _temporal(self, stream: Iterator[FrameItem]) -> Iterator[FrameItem]:
        """Each frame's probability (fused, else saliency) averaged with its neighbours' warped into it along the
        flow (:func:`eponet.core.temporal.temporal_mean`), into ``averaged``: one frame of look-ahead."""
        def own(item):
            return item.fused if item.fused is not None else item.saliency

        def neighbour(other, there, back):  # (probability, flow there, flow back) or None where one is missing
            values = (own(other), there, back) if other is not None else (None,)
            return None if any(v is None for v in values) else values

        def average(before, item, after):
            if own(item) is None:
                return
            previous = neighbour(before, before and before.backward, before and before.forward)
            following = neighbour(after, item.forward, item.backward)
            item.averaged = self._timed("refiner", lambda: temporal_mean(own(item), previous, following))

        before = item = None
        for after in stream:
            if item is not None:
                average(before, item, after)
                yield item
            before, item = item, after
        if item is not None:
            average(before, item, None)
            yield item

    def _probability(self, stream: Iterator[FrameItem]) -> Iterator[FrameItem]:
        for item in stream:
            value = next((v for v in (item.averaged, item.fused, item.saliency) if v is not None), None)
            if value is not None:
                item.probability = resize_map(value, self.size).clip(0, 1)
            yield item

    # -- window: the fusion ---------------------------------------------------------------------
    def _fusion(self, stream: Iterator[FrameItem]) -> Iterator[FrameItem]:
        """Windows of the stage's ``window`` frames advancing by ``window - overlap``, the last one ending at the
        last frame (as :func:`eponet.fusion.window_starts` places them), each run as soon as its frames exist and
        the next window's start is known; centre stitching (:meth:`_owned`)."""
        fusion = self.stages["fusion"]
        window = getattr(fusion, "window", None)
        overlap = int(getattr(fusion, "overlap", 0) or 0)
        inputs: deque[FrameItem] = deque()
        if window is None:  # the stage wants the whole video in one pass (memory grows with the video)
            inputs.extend(stream)
            self._fuse_window(inputs, 0, len(inputs), None, None)
            yield from inputs
            return
        length, step = int(window), int(window) - overlap
        start, previous = 0, None

        pending: deque[FrameItem] = deque()  # yielded in order once fused
        for item in stream:
            inputs.append(item)
            pending.append(item)
            if item.t >= start + step + length - 1:  # the next window is a regular one at start + step
                self._fuse_window(inputs, start, length, previous, start + step)
                previous, start = start, start + step
                while inputs and inputs[0].t < start:
                    inputs.popleft()
                while pending and pending[0].fused is not None:
                    yield pending.popleft()
        if not pending:
            return
        frames = pending[-1].t + 1
        starts = [start] if frames > length else [0]
        if frames > length and start + length < frames:
            starts.append(frames - length)
        for k, first in enumerate(starts):
            nxt = starts[k + 1] if k + 1 < len(starts) else None
            self._fuse_window(inputs, first, min(length, frames - first), previous, nxt,
                              next_is_last=k + 2 == len(starts))
            previous = first
        yield from pending

    def _fuse_window(self, inputs: deque, first: int, length: int, previous, nxt, *, next_is_last: bool = False) -> None:
        base = inputs[0].t
        window = [inputs[t - base] for t in range(first, first + length)]
        features = np.stack([item.features for item in window])
        saliency = np.stack([item.saliency for item in window])
        fused = self._call("fusion", lambda: self.stages["fusion"].fuse(features, saliency), frames=len(window),
                           shape=self.shape)
        owned = self._owned(first, length, previous, nxt, next_is_last=next_is_last)
        for item, value, mine in zip(window, fused, owned):
            if mine:
                item.fused = value

    @staticmethod
    def _owned(first: int, length: int, previous, nxt, *, next_is_last: bool) -> np.ndarray:
        """Which frames of the window starting at ``first`` it owns: a frame belongs to the window in which it lies
        farthest from an inner edge (an edge shared with a neighbour), the earlier window on ties (as
        :func:`eponet.fusion.window_weights` with ``blend="centre"``)."""
        far = length + 1
        f = np.arange(first, first + length)

        def weight(start, is_first, is_last):
            left = f - start + 1 if not is_first else np.full(length, far)
            right = start + length - f if not is_last else np.full(length, far)
            w = np.minimum(left, right).astype(float)
            w[(f < start) | (f >= start + length)] = -1.0
            return w

        mine = weight(first, first == 0, nxt is None)
        owned = np.ones(length, bool)
        if previous is not None:
            owned &= mine > weight(previous, previous == 0, False)
        if nxt is not None:
            owned &= mine >= weight(nxt, False, next_is_last)
        return owned
