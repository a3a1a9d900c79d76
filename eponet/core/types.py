"""Conventions shared by every stage: array layouts, dtypes, units. Defined here and nowhere else.

- Frames are indexed ``t = 0..F-1`` and named after their input file stem (``stems[t]``).
- Images are uint8 RGB ``(H, W, 3)``; a video is ``(F, H, W, 3)``.
- A flow field is float32 ``(H, W, 2)`` holding ``(dx, dy)`` in pixels.
  ``forward[t]`` maps frame t -> t+1 on the grid of frame t; ``backward[t]`` maps frame t+1 -> t on
  the grid of frame t+1. There are ``F - 1`` of each, stacked as ``(F-1, H, W, 2)``.
- Points are ``(x, y) = (column, row)``, pixel centres at integer coordinates, 0-based.
- Masks are uint8 in {0, 1}; probabilities float32 in [0, 1]; epipolar distances float32 in pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "FLOW_DTYPE",
    "MIN_FRAMES",
    "MIN_SIDE",
    "Video",
    "FlowPair",
    "Trajectories",
    "union_of_ids",
    "IdIndex",
    "RigidityResult",
    "TrackFrame",
    "assemble_trajectories",
    "TrackWindow",
    "check_shape",
]

FLOW_DTYPE = np.float32
#: The fewest frames any pipeline can run on: rigidity works on triplets of frames.
MIN_FRAMES = 3
#: The smallest frame side in pixels, of the input frames and of the processing size: smaller frames cannot be
#: encoded (e.g. the overlay video) and carry too little to segment.
MIN_SIDE = 16


def check_shape(name: str, array: np.ndarray, dims: list[str | int], dtype=None) -> None:
    """Raise ``ValueError`` unless ``array`` has the named layout, e.g. ``["F", "H", "W", 2]``.

    String dimensions match any size (but the same letter must match the same size); integers must match
    exactly.
    """
    if array.ndim != len(dims):
        raise ValueError(f"{name}: expected {len(dims)} dimensions {dims}, got shape {tuple(array.shape)}")
    seen: dict[str, int] = {}
    for axis, (want, got) in enumerate(zip(dims, array.shape)):
        if isinstance(want, int):
            if got != want:
                raise ValueError(f"{name}: expected size {want} on axis {axis} of {dims}, got shape {tuple(array.shape)}")
        elif seen.setdefault(want, got) != got:
            raise ValueError(f"{name}: axis {axis} ({want}) is {got} but was {seen[want]} before, shape {tuple(array.shape)}")
    if dtype is not None and array.dtype != dtype:
        raise ValueError(f"{name}: expected dtype {np.dtype(dtype).name}, got {array.dtype.name}")


@dataclass
class Video:
    """One input sequence.

    ``frames`` are the frames at the *processing* resolution (after ``input.scale``), uint8 RGB
    ``(F, H, W, 3)``; ``size`` is the input frame size ``(H0, W0)`` that outputs come back at.
    ``sources`` are the files the frames were read from (one video file, or one file per frame).
    """

    name: str
    frames: np.ndarray
    stems: list[str]
    size: tuple[int, int]
    sources: list[str] = field(default_factory=list)
    #: Frames at the input size, kept only when an output or refiner needs them.
    full_frames: np.ndarray | None = None

    @property
    def num_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def shape(self) -> tuple[int, int]:
        """Processing size ``(H, W)``."""
        return int(self.frames.shape[1]), int(self.frames.shape[2])


@dataclass
class FlowPair:
    """Forward and backward flow of a video, each float32 ``(F-1, H, W, 2)`` in pixels (see module doc)."""

    forward: np.ndarray
    backward: np.ndarray

    def __post_init__(self) -> None:
        check_shape("forward flow", self.forward, ["N", "H", "W", 2])
        check_shape("backward flow", self.backward, [self.forward.shape[0], self.forward.shape[1], self.forward.shape[2], 2])


@dataclass
class Trajectories:
    """Dense point trajectories in a compact CSR-like layout.

    Trajectory ``j`` lives in frames ``start[j] .. start[j] + length[j] - 1`` (one contiguous interval);
    its positions are ``positions[offsets[j] : offsets[j + 1]]``, float32 ``(length[j], 2)`` as (x, y) pixels.
    ``labels[t, y, x]`` is the id of the trajectory that covers pixel (x, y) of frame t (every pixel of every
    frame is covered, so no entry is negative).
    """

    start: np.ndarray  # int32 (T,)
    length: np.ndarray  # int32 (T,)
    offsets: np.ndarray  # int64 (T+1,)
    positions: np.ndarray  # float32 (N, 2)
    labels: np.ndarray  # int32 (F, H, W)

    @property
    def count(self) -> int:
        return int(self.start.shape[0])

    @property
    def num_frames(self) -> int:
        return int(self.labels.shape[0])

    @property
    def frame_shape(self) -> tuple[int, int]:
        return tuple(self.labels.shape[1:])

    def positions_of(self, j: int) -> np.ndarray:
        return self.positions[self.offsets[j] : self.offsets[j + 1]]


@dataclass
class RigidityResult:
    """Output of a rigidity stage.

    ``ed`` is float32 ``(F, H, W)``: the epipolar distance (or the selected model's residual) in pixels of the
    processing resolution, for every pixel of every frame. ``per_trajectory`` is float32 ``(T,)`` or ``None``.
    ``triplets`` holds one small dict of diagnostics per triplet (frames, model chosen, inlier ratio, ...).
    """

    ed: np.ndarray
    per_trajectory: np.ndarray | None = None
    triplets: list[dict] = field(default_factory=list)


@dataclass
class TrackFrame:
    """The trajectories present in one frame ``t`` of a stream: their global ``ids`` int32 ``(N,)`` ascending
    (ids are numbered in birth order over the whole video), their ``positions`` float32 ``(N, 2)`` (x, y) in
    that frame, and ``labels`` int32 ``(H, W)``, the global id covering each pixel."""

    t: int
    ids: np.ndarray
    positions: np.ndarray
    labels: np.ndarray


def _as_int(values, fits: int = 0) -> np.ndarray:
    """Integer ``values`` as they are (int32 trajectory ids are not copied to int64), or as int64 when they are
    not integers or ``fits`` would overflow their type."""
    values = np.asarray(values)
    if values.dtype.kind != "i" or not np.iinfo(values.dtype).min <= fits <= np.iinfo(values.dtype).max:
        return values.astype(np.int64)
    return values


def _dense_range(arrays: list[np.ndarray]) -> tuple[int, int] | None:
    """``(lo, hi)`` of the values of non-empty integer arrays when a table over that range is small (at most 16
    entries per value, plus 1024), else None."""
    lo, hi = min(int(a.min()) for a in arrays), max(int(a.max()) for a in arrays)
    return (lo, hi) if hi - lo + 1 <= 16 * sum(len(a) for a in arrays) + 1024 else None


def union_of_ids(arrays: list[np.ndarray]) -> np.ndarray:
    """The distinct values of integer arrays (trajectory ids), int64 ascending: a bitmap over their range, O(n)
    where ``np.unique`` of the concatenation sorts or hashes (100 ms for a window of 240p frames). Ranges much
    wider than the values fall back to ``np.unique``.

    >>> union_of_ids([np.array([7, 3, 5]), np.array([5, 9]), np.array([], np.int64)]).tolist()
    [3, 5, 7, 9]
    """
    arrays = [_as_int(a) for a in arrays if len(a)]
    if not arrays:
        return np.zeros(0, np.int64)
    dense = _dense_range(arrays)
    if dense is None:
        return np.unique(np.concatenate(arrays)).astype(np.int64)
    seen = np.zeros(dense[1] - dense[0] + 1, bool)
    for a in arrays:
        seen[a - dense[0]] = True
    return np.flatnonzero(seen).astype(np.int64) + dense[0]


class IdIndex:
    """Positions of values in ascending distinct int64 ``ids``: a table over their range (O(1) a lookup) where
    ``np.searchsorted`` costs a binary search per value; ranges much wider than the ids use the search.

    >>> IdIndex(np.array([3, 5, 9])).positions(np.array([9, 3, 4, 12, 5])).tolist()
    [2, 0, -1, -1, 1]
    >>> IdIndex(np.array([3, 5, 9])).positions(np.array([[5, 2]], np.int32)).tolist()  # any integer type and shape
    [[1, -1]]
    """

    def __init__(self, ids: np.ndarray):
        self.ids = np.asarray(ids, np.int64)
        dense = _dense_range([self.ids]) if len(self.ids) else None
        self.lo, self.table = 0, None
        if dense is not None:
            self.lo = dense[0]
            self.table = np.full(dense[1] - dense[0] + 1, -1, np.int64)
            self.table[self.ids - self.lo] = np.arange(len(self.ids))

    def positions(self, values: np.ndarray) -> np.ndarray:
        """int64 array of ``values``' shape: the position of each value in ``ids``, -1 where it is absent."""
        values = _as_int(values, self.lo + (len(self.table) if self.table is not None else 0))
        if not len(self.ids):
            return np.full(values.shape, -1, np.int64)
        if self.table is not None:
            shifted = values - self.lo
            if shifted.size and 0 <= shifted.min() and shifted.max() < len(self.table):
                return self.table[shifted]
            inside = (shifted >= 0) & (shifted < len(self.table))
            out = np.full(values.shape, -1, np.int64)
            out[inside] = self.table[shifted[inside]]
            return out
        at = np.clip(np.searchsorted(self.ids, values), 0, len(self.ids) - 1)
        return np.where(self.ids[at] == values, at, -1)


def point_words(points: np.ndarray) -> np.ndarray:
    """(N,) uint64 view of float32 (N, 2) points (a contiguous copy if they are not): one 8-byte word per point,
    so that gathering or scattering whole points is a 1-D indexing, several times faster than indexing rows."""
    return np.ascontiguousarray(points, dtype=np.float32).view(np.uint64)[:, 0]


def assemble_trajectories(frames: list[TrackFrame]) -> tuple[Trajectories, np.ndarray]:
    """The :class:`Trajectories` of consecutive stream frames (``frames[0].t`` becomes frame 0), and the
    global id of each of its trajectories, int64 ``(T,)`` ascending (:class:`TrackWindow` reads the same frames
    without assembling them).

    A trajectory present in several of the frames is one trajectory (it lives on one contiguous interval);
    one that started before ``frames[0]`` starts at frame 0 here, one that lives on past the last frame ends
    there. Window-local ids keep the global order, so ``start`` is non-decreasing as the whole-video builder
    gives it.

    >>> a = TrackFrame(5, np.array([0, 1], np.int32), np.zeros((2, 2), np.float32), np.array([[0, 1]], np.int32))
    >>> b = TrackFrame(6, np.array([1, 2], np.int32), np.ones((2, 2), np.float32), np.array([[2, 1]], np.int32))
    >>> tracks, ids = assemble_trajectories([a, b])
    >>> ids.tolist(), tracks.start.tolist(), tracks.length.tolist(), tracks.labels.tolist()
    ([0, 1, 2], [0, 0, 1], [1, 2, 1], [[[0, 1]], [[2, 1]]])
    """
    _check_consecutive(frames, "assemble_trajectories")
    ids = union_of_ids([f.ids for f in frames])
    index = IdIndex(ids)
    n = len(ids)
    start = np.full(n, len(frames), np.int32)
    end = np.full(n, -1, np.int32)
    local = []
    for k, frame in enumerate(frames):
        loc = index.positions(frame.ids)
        start[loc] = np.minimum(start[loc], k)
        end[loc] = k
        local.append(loc)
    length = (end - start + 1).astype(np.int32)
    offsets = np.zeros(n + 1, np.int64)
    np.cumsum(length, out=offsets[1:])
    positions = np.empty((int(offsets[-1]), 2), np.float32)
    words = point_words(positions)  # (a view: what is written to it lands in positions)
    first = offsets[:-1] - start  # a trajectory's point of frame k is at first + k
    labels = np.empty((len(frames),) + frames[0].labels.shape, np.int32)
    for k, (frame, loc) in enumerate(zip(frames, local)):
        words[first[loc] + k] = point_words(frame.positions)
        labels[k] = index.positions(frame.labels)  # (a table lookup; a binary search per pixel cost 3x more)
    return Trajectories(start=start, length=length, offsets=offsets, positions=positions, labels=labels), ids


def _check_consecutive(frames: list[TrackFrame], caller: str) -> None:
    if not frames:
        raise ValueError(f"{caller}: no frames")
    for k, frame in enumerate(frames):
        if frame.t != frames[0].t + k:
            raise ValueError(f"{caller}: frame {k} is t={frame.t}, expected {frames[0].t + k} (consecutive)")


class TrackWindow:
    """Consecutive frames of a trajectory stream (``frames[0].t`` becomes frame 0) read frame by frame, as a run
    loop's rigidity window is scored (``score_groups`` of :class:`~eponet.core.protocols.RigidityModel`).

    The window's trajectories are ``ids`` (global, int64 ascending; window-local index ``i`` is ``ids[i]``, the
    trajectory index :func:`assemble_trajectories` gives the same frames). :meth:`group` returns those present in
    every frame of a frame group and their positions there, read from the frames as they are: no trajectory-major
    :class:`Trajectories` is assembled (a scatter of every point of the window, a quarter of the geometry's time
    at 854x480). It relies on what :class:`TrackFrame` promises: ids ascending and numbered in birth order, each
    trajectory on one contiguous interval of frames.

    >>> a = TrackFrame(5, np.array([0, 1], np.int32), np.zeros((2, 2), np.float32), np.array([[0, 1]], np.int32))
    >>> b = TrackFrame(6, np.array([1, 2], np.int32), np.ones((2, 2), np.float32), np.array([[2, 1]], np.int32))
    >>> window = TrackWindow([a, b])
    >>> window.ids.tolist(), window.count, window.num_frames, window.frame_shape
    ([0, 1, 2], 3, 2, (1, 2))
    >>> local, (p, q) = window.group((0, 1))
    >>> local.tolist(), p.tolist(), q.tolist()
    ([1], [[0.0, 0.0]], [[1.0, 1.0]])
    """

    def __init__(self, frames: list[TrackFrame]):
        _check_consecutive(frames, "TrackWindow")
        self.frames = list(frames)
        self.ids = union_of_ids([f.ids for f in frames])
        index = IdIndex(self.ids)
        self._local = [index.positions(f.ids) for f in frames]  # each row's window-local index
        self._end = np.empty(len(self.ids), np.int32)  # the last window frame each trajectory is in
        for k, local in enumerate(self._local):
            self._end[local] = k

    @property
    def count(self) -> int:
        return len(self.ids)

    @property
    def num_frames(self) -> int:
        return len(self.frames)

    @property
    def frame_shape(self) -> tuple[int, int]:
        return tuple(self.frames[0].labels.shape)

    def group(self, frames: tuple[int, ...]) -> tuple[np.ndarray, list[np.ndarray]]:
        """Window-local indices int64 ``(N,)`` (ascending) of the trajectories present in every one of ``frames``
        (ascending window frame numbers), and their positions float32 ``(N, 2)`` in each frame.

        Present in the first and the last frame means present in between (one contiguous life); born no later
        than the first frame means an id no larger than its newest one (birth order). So in each frame they are
        the rows up to that id whose trajectory lasts until the last frame: in the last frame a prefix."""
        newest = self.frames[frames[0]].ids[-1] if len(self.frames[frames[0]].ids) else -1
        points = []
        for k in frames:
            frame = self.frames[k]
            born = int(np.searchsorted(frame.ids, newest, side="right"))
            if k == frames[-1]:
                local = self._local[k][:born]
                points.append(frame.positions[:born])
            else:
                rows = np.flatnonzero(self._end[self._local[k][:born]] >= frames[-1])
                points.append(point_words(frame.positions)[rows].view(np.float32).reshape(-1, 2))
        return local, points
