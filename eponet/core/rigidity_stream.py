"""The trajectory and rigidity stages over a stream of frames: their live state carried from window to window,
and checkpoints of that state, so that a run killed in the middle of a long video resumes where it stopped.

:class:`GeometryScorer` is the state machine the run loop (:mod:`eponet.core.stream`) feeds one frame at a time
(see that module's docstring for the windows and the lag). Everything it carries from one frame to the next is
data: the trajectory builder's stream state, the trajectory records of the frames still needed, each trajectory's
summed distance and group count, guided sampling's history, the generator's state, the maps of windows scored as
a whole, and where the windows and the painting stand. :meth:`GeometryScorer.checkpoint` writes all of it as
arrays and JSON (no pickle), :meth:`GeometryScorer.restore` reads it back into a fresh scorer; the frames
themselves and their flow are not in a checkpoint: they are decoded and (from the cache) re-read on resume.

A builder's stream state and a stage's history can be checkpointed when their attributes are numpy arrays,
numpy scalars and plain JSON values (the built-in ones are); for any other, :meth:`~GeometryScorer.checkpoint`
returns ``None`` and a killed run recomputes that video's geometry from its first frame.
"""

from __future__ import annotations

import logging
import zlib
from collections import deque
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from .imaging import fill_from_neighbourhood
from .motion import shrunk_means
from .types import FlowPair, IdIndex, TrackFrame, TrackWindow, assemble_trajectories, union_of_ids

__all__ = ["GeometryScorer", "CHECKPOINT_SECONDS", "CHECKPOINT_VERSION"]

log = logging.getLogger(__name__)

#: The run loop checkpoints a video's geometry after an ED block once the last checkpoint is this many seconds old
#: (a checkpoint holds the trajectory records of the ``chunk + lag`` or so frames in flight, several times a
#: block's size), so a kill loses at most about this much of the geometry's work.
CHECKPOINT_SECONDS = 30.0

#: Bumped when the checkpoint layout changes: a checkpoint of another version is ignored (recomputed).
CHECKPOINT_VERSION = 1

_PLAIN = (bool, int, float, str, type(None))


@dataclass
class _Accumulator:
    """Summed distances and group counts of the trajectories still needed, by ascending global id. What the
    painting reads (the id index, each trajectory's mean, the median) is derived once per change, not per frame:
    the accumulator changes once per window of ``run.chunk`` frames."""

    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    sums: np.ndarray = field(default_factory=lambda: np.zeros(0))
    counts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    prior_groups: float = 0.0

    def __post_init__(self) -> None:
        self._derived: tuple[IdIndex, np.ndarray, float] | None = None

    def add(self, ids: np.ndarray, sums: np.ndarray, counts: np.ndarray) -> None:
        union = union_of_ids([self.ids, ids])
        index = IdIndex(union)
        new_sums, new_counts = np.zeros(len(union)), np.zeros(len(union), np.int64)
        old = index.positions(self.ids)
        new_sums[old], new_counts[old] = self.sums, self.counts
        at = index.positions(ids)
        new_sums[at] += sums
        new_counts[at] += counts
        self.ids, self.sums, self.counts, self._derived = union, new_sums, new_counts, None

    def keep(self, alive: np.ndarray) -> None:
        mask = np.isin(self.ids, alive, assume_unique=False)
        self.ids, self.sums, self.counts, self._derived = self.ids[mask], self.sums[mask], self.counts[mask], None

    def _derive(self) -> tuple[IdIndex, np.ndarray, float]:
        """The id index, the mean distance of each id float32 ``(n + 1,)`` (shrunk by ``prior_groups``, see
        :func:`~eponet.core.motion.shrunk_means`, toward the median of the means in flight; NaN where not scored,
        and a last NaN for ids that are absent) and the median of those means."""
        if self._derived is None:
            scored = self.counts > 0
            means, _ = shrunk_means(self.sums, self.counts, self.prior_groups)
            median = float(np.median(means[scored])) if scored.any() else 0.0
            self._derived = IdIndex(self.ids), np.append(means, np.float32(np.nan)), median
        return self._derived

    def means(self, labels: np.ndarray) -> np.ndarray:
        """Mean distance of the trajectory covering each pixel (NaN where none was scored)."""
        if not len(self.ids):
            return np.full(labels.shape, np.nan, np.float32)
        index, means, _ = self._derive()
        return means[index.positions(labels)]  # (position -1, an absent id: the last entry, NaN)

    def median(self) -> float:
        return self._derive()[2]


class _NotCheckpointable(Exception):
    pass


def _flatten(obj, prefix: str, arrays: dict[str, np.ndarray]) -> dict:
    """``obj``'s attributes: arrays (and numpy scalars, as 0-d arrays, to keep their dtype) into ``arrays`` under
    ``prefix.name``; plain values returned. Anything else cannot be checkpointed."""
    try:
        fields = vars(obj)
    except TypeError:  # __slots__ or a C type
        raise _NotCheckpointable(f"{type(obj).__name__} has no __dict__") from None
    plain = {}
    for name, value in fields.items():
        if isinstance(value, (np.ndarray, np.generic)):
            arrays[f"{prefix}.{name}"] = np.asarray(value)
        elif isinstance(value, _PLAIN):
            plain[name] = value
        else:
            raise _NotCheckpointable(f"{type(obj).__name__}.{name} is a {type(value).__name__}")
    return {"plain": plain, "arrays": sorted(n for n in fields if n not in plain)}


def _unflatten(obj, prefix: str, arrays: dict[str, np.ndarray], saved: dict) -> None:
    """Set ``obj``'s attributes from :func:`_flatten`'s output (a fresh object of the same type and settings)."""
    names = set(saved["plain"]) | set(saved["arrays"])
    if names != set(vars(obj)):
        raise _NotCheckpointable(f"{type(obj).__name__}: attributes changed")
    for name, value in saved["plain"].items():
        setattr(obj, name, value)
    for name in saved["arrays"]:
        value = arrays[f"{prefix}.{name}"]
        setattr(obj, name, value[()] if value.ndim == 0 and isinstance(getattr(obj, name), np.generic) else value)


class GeometryScorer:
    """Trajectories and rigidity of one video, fed frame by frame (:meth:`feed`), each frame's ED map painted as
    soon as the lag allows (:meth:`ready`), the rest at the end (:meth:`finish`). ``stream`` is the
    :class:`~eponet.core.stream.SequenceStream` it works for (stages, settings, timing and checks); the builder
    must have ``stream()``."""

    def __init__(self, stream):
        self.owner = stream
        self.builder, self.rigidity = stream.stages["trajectories"], stream.stages["rigidity"]
        views, stride = int(getattr(self.rigidity, "views", 3)), int(getattr(self.rigidity, "stride", 1))
        self.span = (views - 1) * stride
        self.chunk, self.lag, self.shape = stream.chunk, stream.lag, stream.shape
        self.rng = np.random.default_rng([stream.spec.seed, zlib.crc32(stream.name.encode())])
        self.state = None  # the builder's TrajectoryStream, from the first frame on
        self.records: dict[int, TrackFrame] = {}
        self.pending: deque = deque()  # frames fed and not painted yet
        self.acc = _Accumulator(prior_groups=float(getattr(self.rigidity, "prior_groups", 0.0)))
        self.history = self.rigidity.new_history() if hasattr(self.rigidity, "new_history") else None
        self.direct: dict[int, np.ndarray] = {}  # maps of windows used as they are (no per-trajectory means)
        self.g_next = 0  # first frame group not yet scored
        self.last_t = -1  # the last frame fed
        self.pushed = -1  # frames up to this one are in the state (after a restore: beyond the frames fed again)
        self.finished = False  # the last window is scored (finish() paints the rest)

    # -- the stream -----------------------------------------------------------------------------
    def feed(self, item) -> None:
        """Take frame ``item.t`` (the next one; with its flow pair to ``t + 1`` unless it is the last) and score
        every window whose frames are now there."""
        owner = self.owner
        self.last_t = item.t
        self.pending.append(item)
        if item.t <= self.pushed:  # a restored scorer: this frame's pair is already in the state
            return
        self.pushed = item.t
        if self.state is None:
            self.state = owner._timed("trajectories", lambda: self.builder.stream(self.shape))
            self.records[0] = owner._call("trajectories", self.state.first, frames=None, shape=self.shape)
        if item.forward is not None:
            self.records[item.t + 1] = owner._call("trajectories", lambda: self.state.push(item.forward, item.backward),
                                                   frames=None, shape=self.shape)
            available = item.t + 1
            while self.g_next + self.chunk - 1 + self.span <= available:
                self._score_window(self.g_next, self.g_next + self.chunk + self.span, owned=self.chunk)
                self.g_next += self.chunk
                self._forget()

    def ready(self) -> Iterator:
        """The frames that can be painted now, in order, each painted as it is taken (so that the scorer's state
        between two frames is that of a run stopped there)."""
        pending = self.pending
        while pending and pending[0].t + self.lag < self.g_next and pending[0].t + 1 in self.records:
            yield self._paint(pending.popleft())

    def finish(self) -> Iterator:
        """After the last frame: score the groups left and paint every frame still pending."""
        frames = self.last_t + 1
        if not self.finished and (frames - 1 - self.span >= self.g_next or self.g_next == 0):
            self._score_window(self.g_next, frames, owned=frames - self.g_next)
        self.finished = True
        while self.pending:
            yield self._paint(self.pending.popleft())

    # -- checkpoints ----------------------------------------------------------------------------
    def checkpoint(self) -> tuple[dict[str, np.ndarray], dict] | None:
        """The scorer's state as ``(arrays, meta)`` for the cache (frames and flow left out), or ``None`` when
        the builder's stream state or the stage's history holds something other than arrays and plain values."""
        arrays: dict[str, np.ndarray] = {"acc.ids": self.acc.ids, "acc.sums": self.acc.sums,
                                         "acc.counts": self.acc.counts}
        for t, record in self.records.items():
            arrays[f"records.{t}.ids"] = record.ids
            arrays[f"records.{t}.positions"] = record.positions
            arrays[f"records.{t}.labels"] = record.labels
        for t, ed in self.direct.items():
            arrays[f"direct.{t}"] = ed
        try:
            state = _flatten(self.state, "state", arrays) if self.state is not None else None
            history = _flatten(self.history, "history", arrays) if self.history is not None else None
        except _NotCheckpointable as exc:
            log.debug("%s: no checkpoint of the geometry (%s)", self.owner.name, exc)
            return None
        meta = {"version": CHECKPOINT_VERSION, "g_next": self.g_next, "last_t": self.last_t, "finished": self.finished,
                "painted": self.pending[0].t if self.pending else self.last_t + 1,
                "records": sorted(self.records), "direct": sorted(self.direct),
                "rng": self.rng.bit_generator.state, "state": state, "history": history,
                "triplets": list(self.owner.triplets)}
        return arrays, meta

    def restore(self, arrays: dict[str, np.ndarray], meta: dict) -> int | None:
        """Take the state of :meth:`checkpoint`; returns the first frame not painted then (the run loop feeds the
        frames from there on again), or ``None`` when the checkpoint does not fit this scorer (left unchanged)."""
        try:
            if meta.get("version") != CHECKPOINT_VERSION:
                raise _NotCheckpointable(f"checkpoint version {meta.get('version')}")
            state = self.builder.stream(self.shape) if meta["state"] is not None else None
            if state is not None:
                _unflatten(state, "state", arrays, meta["state"])
            history = self.rigidity.new_history() if self.history is not None else None
            if (history is None) != (meta["history"] is None):
                raise _NotCheckpointable("history")
            if history is not None:
                _unflatten(history, "history", arrays, meta["history"])
            records = {int(t): TrackFrame(int(t), arrays[f"records.{t}.ids"], arrays[f"records.{t}.positions"],
                                          arrays[f"records.{t}.labels"]) for t in meta["records"]}
            direct = {int(t): arrays[f"direct.{t}"] for t in meta["direct"]}
            acc = _Accumulator(arrays["acc.ids"], arrays["acc.sums"], arrays["acc.counts"], self.acc.prior_groups)
            rng = np.random.default_rng(0)
            rng.bit_generator.state = meta["rng"]
        except (_NotCheckpointable, KeyError, TypeError, ValueError) as exc:
            log.debug("%s: geometry checkpoint not used (%s)", self.owner.name, exc)
            return None
        self.state, self.history, self.records, self.direct, self.acc, self.rng = state, history, records, direct, acc, rng
        self.g_next, self.last_t = int(meta["g_next"]), int(meta["last_t"])
        self.pushed, self.finished = self.last_t, bool(meta["finished"])
        self.owner.triplets = list(meta["triplets"])
        return int(meta["painted"])

    # -- windows and painting -------------------------------------------------------------------
    def _score_window(self, first: int, stop: int, *, owned: int) -> None:
        """Score frames ``first .. stop - 1`` (groups starting at ``first .. first + owned - 1``), passing the
        stage's ``history`` (see :class:`~eponet.core.protocols.RigidityModel`) when it keeps one."""
        owner, rigidity, records = self.owner, self.rigidity, self.records
        frames = [records[t] for t in range(first, stop)]
        if hasattr(rigidity, "score_groups"):  # the totals alone: the frames as they are, no flow, no maps
            window = owner._timed("trajectories", lambda: TrackWindow(frames))
            memory = {} if self.history is None else {"history": self.history, "track_ids": window.ids}
            sums, counts, infos = owner._call("rigidity", lambda: rigidity.score_groups(window, self.rng, **memory),
                                              frames=stop - first, shape=self.shape, trajectories=window.count)
            owner.triplets += [{**info, "frames": [int(f) + first for f in info["frames"]]} for info in infos]
            scored = counts > 0
            self.acc.add(window.ids[scored], sums[scored], counts[scored])
            return
        tracks, ids = owner._timed("trajectories", lambda: assemble_trajectories(frames))
        memory = {} if self.history is None else {"history": self.history, "track_ids": ids}
        base = self.pending[0].t
        pairs = [self.pending[t - base] for t in range(first, stop - 1)]  # frame stop - 1 may not have arrived yet
        flow = FlowPair(np.stack([i.forward for i in pairs]), np.stack([i.backward for i in pairs]))
        result = owner._call("rigidity", lambda: rigidity.score(tracks, flow, self.rng, **memory), frames=stop - first,
                             shape=self.shape, trajectories=tracks.count)
        infos = [dict(info) for info in result.triplets]
        groups = [info.get("frames") for info in infos]
        for info in infos:
            if isinstance(info.get("frames"), list):
                info["frames"] = [int(f) + first for f in info["frames"]]
        owner.triplets += infos
        if result.per_trajectory is None or any(not isinstance(g, list) or not g for g in groups):
            for t in range(first, min(stop, first + owned)):  # the window's own maps, as they are
                self.direct[t] = result.ed[t - first]
            return
        start = tracks.start.astype(np.int64)
        end = start + tracks.length - 1
        counts = np.zeros(tracks.count, np.int64)
        for info, group in zip(infos, groups):
            if info.get("model") != "failed":
                counts += (start <= group[0]) & (end >= group[-1])
        means = np.asarray(result.per_trajectory, np.float64)
        scored = counts > 0
        self.acc.add(ids[scored], means[scored] * counts[scored], counts[scored])

    def _forget(self) -> None:
        records = self.records
        oldest = min(self.g_next, self.pending[0].t if self.pending else self.g_next)
        for t in [t for t in records if t < oldest]:
            del records[t]
        if records:
            alive = union_of_ids([records[t].ids for t in records])
            self.acc.keep(alive)
            if self.history is not None:
                self.history.keep(alive)

    def _paint(self, item):
        if item.t in self.direct:
            item.ed = self.direct.pop(item.t)
        else:
            def paint():
                ed = self.acc.means(self.records[item.t].labels)
                valid = ~np.isnan(ed)
                if valid.all():
                    return ed
                if not valid.any():
                    log.warning("%s: frame %s: no scored trajectory; using the median distance", self.owner.name,
                                item.stem)
                return fill_from_neighbourhood(ed, valid, self.acc.median())

            item.ed = self.owner._timed("rigidity", paint)
        return item
