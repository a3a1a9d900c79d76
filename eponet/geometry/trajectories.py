"""Dense point trajectories from forward/backward flow, their compact storage, and per-pixel painting.

Every pixel of every frame belongs to a trajectory: all pixels of frame 0 start one, positions advance by
bilinearly sampled forward flow, a trajectory ends at an occlusion (forward-backward test) or when it leaves
the frame, and a new one starts at every pixel that no surviving trajectory covers. Trajectories are never
re-linked, so each lives on one contiguous frame interval. Storage is the CSR-like
:class:`eponet.core.types.Trajectories` (float32 positions, no dense frames x trajectories matrix).
"""

from __future__ import annotations

import logging

import numpy as np

from ..core.imaging import fill_from_neighbourhood
from ..core.types import TrackFrame, Trajectories, assemble_trajectories, point_words
from .consistency import exact_round_trip, fb_consistent_points, round_half_up, sample_bilinear

__all__ = [
    "build_dense_trajectories",
    "DenseTrajectoryStream",
    "MAX_LIVE",
    "trajectory_ends",
    "alive_in_frames",
    "trajectory_positions",
    "paint_trajectory_values",
    "fill_from_neighbourhood",
]

#: Default bound on the trajectories alive at once, in multiples of the frame's pixel count (see
#: :func:`build_dense_trajectories`): above the 2.2 the DAVIS-2016 train sequences reach, so their trajectories
#: are those of the unbounded builder, while a long video's stay bounded.
MAX_LIVE = 3.0

log = logging.getLogger(__name__)


def build_dense_trajectories(
    forward: np.ndarray,
    backward: np.ndarray,
    *,
    consistency: str = "tolerance",
    cull_collisions: bool = False,
    max_live: float | None = MAX_LIVE,
) -> Trajectories:
    """Dense trajectories covering every pixel of every frame.

    Positions advance by the bilinearly sampled forward flow (:func:`~eponet.geometry.sample_bilinear`);
    a trajectory ends at an occlusion or when its rounded position leaves the frame, and every pixel that no
    surviving trajectory covers starts a new one (never re-linked).

    Parameters
    ----------
    forward, backward : array (F-1, H, W, 2) float32
        Flow of consecutive pairs (see :mod:`eponet.core.types`). Non-finite vectors (unknown flow) are
        treated as occlusions, with a warning: a trajectory on such a pixel of frame t (forward) or landing
        on one of frame t+1 (backward) ends at t.
    consistency : {"tolerance", "exact"}
        Occlusion test. ``"tolerance"`` (default): at the trajectory's sub-pixel position p with
        ``f = forward(p)`` and ``b = backward(p + f)``, continue iff
        ``|f + b|^2 < 0.01 (|f|^2 + |b|^2) + 0.5`` (Sundaram et al. 2010). ``"exact"``: the original code's
        rounded round trip (:func:`eponet.geometry.consistency.exact_round_trip`) at the rounded position.
    cull_collisions : bool
        When several trajectories land on one pixel, end all but the oldest (lowest id). Without culling they
        all continue (as in the original), and only the oldest is recorded in ``labels``.
    max_live : float or None
        Without culling, the most trajectories alive at once, in multiples of the frame's pixel count ``H * W``
        (>= 1; default :data:`MAX_LIVE`). Trajectories that land on a pixel an older one covers never separate
        from it in a contracting flow, so their number grows with the length of a video (1.3 to 2.2 times the
        pixels after 25 to 91 frames of the DAVIS-2016 train sequences, 4 times after 1200 frames of a
        camera panning to and fro) and with it the memory and time per frame. When a frame would exceed the
        bound, the youngest of the trajectories that cover no pixel end there until it holds. ``None``: no
        bound (the original).

    Returns
    -------
    Trajectories
        ``labels[t, y, x]`` is the trajectory covering pixel (x, y) of frame t: the oldest of those whose
        rounded position is that pixel. ``T >= H * W``.

    Notes
    -----
    Memory: besides the output (8 bytes per trajectory point plus 4 bytes per pixel of ``labels``), the
    builder holds the per-frame positions (8 bytes per point) until the end.

    Examples
    --------
    >>> fw = np.zeros((2, 4, 5, 2), np.float32); fw[..., 0] = 1.0  # everything moves 1 px to the right
    >>> tr = build_dense_trajectories(fw, -fw)
    >>> tr.count, tr.positions_of(0).tolist()  # 20 + 4 + 4 newborn at the left edge
    (28, [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    """
    n_pairs, h, w = forward.shape[:3]
    stream = DenseTrajectoryStream((h, w), consistency=consistency, cull_collisions=cull_collisions, max_live=max_live)
    frames = [stream.first()]
    for t in range(n_pairs):
        frames.append(stream.push(forward[t], backward[t]))
    return assemble_trajectories(frames)[0]


class DenseTrajectoryStream:
    """The live state of :func:`build_dense_trajectories`, advanced one flow pair at a time.

    ``first()`` returns frame 0's :class:`~eponet.core.types.TrackFrame` (every pixel starts a trajectory);
    each ``push(forward[t], backward[t])`` returns frame t+1's. The state between calls is only the
    trajectories alive at the last frame (ids and positions, 12 bytes each), so a stream of any length holds
    memory of one frame's worth; ids are numbered in birth order across the whole stream, exactly as the
    whole-video builder numbers them.
    """

    def __init__(self, shape: tuple[int, int], *, consistency: str = "tolerance", cull_collisions: bool = False,
                 max_live: float | None = MAX_LIVE):
        if consistency not in ("tolerance", "exact"):
            raise ValueError(f"consistency must be 'tolerance' or 'exact', got {consistency!r}")
        if max_live is not None and not max_live >= 1:
            raise ValueError(f"max_live must be at least 1 (times the pixel count) or None, got {max_live!r}")
        self.h, self.w = int(shape[0]), int(shape[1])
        self.consistency = consistency
        self.cull_collisions = bool(cull_collisions)
        self.max_live = None if max_live is None else float(max_live)
        hw = self.h * self.w
        ys, xs = np.mgrid[0 : self.h, 0 : self.w]
        self.grid = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float32)
        self.ids = np.arange(hw, dtype=np.int32)
        self.pos = self.grid.copy()
        self.next_id = hw
        self.t = 0

    def first(self) -> TrackFrame:
        """Frame 0: one new trajectory per pixel."""
        return TrackFrame(0, self.ids, self.pos, self.ids.reshape(self.h, self.w).copy())

    def push(self, fwd: np.ndarray, bwd: np.ndarray) -> TrackFrame:
        """Advance by the flow pair ``forward[t]``, ``backward[t]`` (each ``(H, W, 2)``); frame t+1's tracks."""
        h, w, t = self.h, self.w, self.t
        hw = h * w
        pos, ids = self.pos, self.ids
        fwd = np.asarray(fwd, np.float32)
        bwd = np.asarray(bwd, np.float32)
        bad_f = bad_b = None
        # (a sum is finite only if every term is; cheaper than isfinite over the field)
        if not (np.isfinite(fwd.sum(dtype=np.float64)) and np.isfinite(bwd.sum(dtype=np.float64))):
            # unknown flow (NaN/inf, e.g. from .flo files) counts as occluded: trajectories on it end
            bad_f, bad_b = ~np.isfinite(fwd).all(-1), ~np.isfinite(bwd).all(-1)
            if bad_f.any() or bad_b.any():
                fwd, bwd = np.where(bad_f[..., None], 0, fwd), np.where(bad_b[..., None], 0, bwd)
                log.warning("pair %d: %d forward and %d backward flow vectors are not finite; treated as occluded",
                            t, int(bad_f.sum()), int(bad_b.sum()))
            else:  # finite values whose sum overflowed
                bad_f = bad_b = None
        if self.consistency == "tolerance":
            target, ok = fb_consistent_points(fwd, bwd, pos)
        else:
            target = pos + sample_bilinear(fwd, pos)
            r0 = round_half_up(pos)
            ok = exact_round_trip(fwd, bwd)[r0[:, 1], r0[:, 0]]
        # rounded target pixel; inside the frame iff 0 <= floor(p + 0.5) < (w, h) in both coordinates
        cell = target + np.float32(0.5)
        np.floor(cell, out=cell)
        inside = (cell >= 0) & (cell < np.array([w, h], np.float32))
        ok &= inside.view(np.uint16)[:, 0] == 0x0101  # both booleans of a row true
        if bad_f is not None:
            r0 = round_half_up(pos)
            ok &= ~bad_f[r0[:, 1], r0[:, 0]]
        keep = np.flatnonzero(ok)
        cell = _take_rows(cell, keep).astype(np.int32)
        pix = cell[:, 1] * w + cell[:, 0]
        if bad_b is not None:
            good = ~bad_b.ravel()[pix]
            keep, pix = keep[good], pix[good]
        kept_ids = ids[keep]
        cover = np.full(hw, -1, np.int32)
        cover[pix] = kept_ids
        dup = np.bincount(pix, minlength=hw)[pix] > 1
        collided = bool(dup.any())
        if collided:  # the oldest (lowest id) of the trajectories on one pixel covers it
            np.minimum.at(cover, pix[dup], kept_ids[dup])
            if self.cull_collisions:
                win = cover[pix] == kept_ids
                keep, kept_ids = keep[win], kept_ids[win]
        new_pix = np.flatnonzero(cover < 0)  # (culling and the bound end only trajectories that cover nothing)
        if collided and not self.cull_collisions and self.max_live is not None:
            keep, kept_ids = self._bounded(keep, kept_ids, cover, pix, born=len(new_pix))
        new_ids = np.arange(self.next_id, self.next_id + len(new_pix), dtype=np.int32)
        cover[new_pix] = new_ids
        self.next_id += len(new_pix)
        self.ids = np.concatenate([kept_ids, new_ids])
        self.pos = np.concatenate([_take_rows(target, keep), _take_rows(self.grid, new_pix)])
        self.t = t + 1
        return TrackFrame(t + 1, self.ids, self.pos, cover.reshape(h, w))

    def _bounded(self, keep: np.ndarray, kept_ids: np.ndarray, cover: np.ndarray, pix: np.ndarray, *, born: int):
        """``keep`` and ``kept_ids`` less the youngest trajectories that cover no pixel (an older one covers it),
        as many as the frame holds beyond ``max_live`` times its pixels once ``born`` new ones start."""
        hw = self.h * self.w
        excess = len(kept_ids) + born - int(self.max_live * hw)
        if excess <= 0:
            return keep, kept_ids
        hidden = np.flatnonzero(cover[pix] != kept_ids)  # more than excess: the covering ones and births fit in hw
        youngest = hidden[np.argpartition(kept_ids[hidden], len(hidden) - excess)[len(hidden) - excess:]]
        alive = np.ones(len(kept_ids), bool)
        alive[youngest] = False
        return keep[alive], kept_ids[alive]


def _take_rows(points: np.ndarray, idx: np.ndarray) -> np.ndarray:
    return point_words(points)[idx].view(np.float32).reshape(-1, 2)


def trajectory_ends(trajectories: Trajectories) -> np.ndarray:
    """Last frame of every trajectory, int32 (T,)."""
    return trajectories.start + trajectories.length - 1


def alive_in_frames(
    trajectories: Trajectories, first: int, last: int, ends: np.ndarray | None = None, *, births_ordered: bool = True
) -> np.ndarray:
    """Ids (ascending, int64) of the trajectories present in every frame of ``first .. last``.

    ``births_ordered`` says that ``start`` is non-decreasing (true for :func:`build_dense_trajectories`,
    which numbers trajectories in birth order), so that the candidates are a prefix of the ids.
    """
    start = trajectories.start
    if ends is None:
        ends = trajectory_ends(trajectories)
    if not births_ordered:
        return np.flatnonzero((start <= first) & (ends >= last))
    n = int(np.searchsorted(start, start.dtype.type(first), side="right"))  # same dtype: no copy of start
    return np.flatnonzero(ends[:n] >= last)


def trajectory_positions(trajectories: Trajectories, ids: np.ndarray, frame: int | tuple) -> np.ndarray | list:
    """Positions float32 (N, 2) of trajectories ``ids`` (all alive at ``frame``) in that frame; for a tuple
    of frames, the list of their position arrays (views into one (N, len(frame), 2) array: a trajectory's
    points in nearby frames are neighbours in memory, so one gather of all of them costs about what one
    frame's alone does)."""
    base = trajectories.offsets[ids] - trajectories.start[ids]
    if isinstance(frame, tuple):
        index = np.empty((len(base), len(frame)), np.int64)
        for i, f in enumerate(frame):
            np.add(base, f, out=index[:, i])
        points = point_words(trajectories.positions).take(index.ravel()).view(np.float32)
        points = points.reshape(len(base), len(frame), 2)
        return [points[:, i] for i in range(len(frame))]
    return _take_rows(trajectories.positions, base + frame)


def paint_trajectory_values(labels: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Give every pixel the value of the trajectory covering it: ``values[labels]``.

    Parameters
    ----------
    labels : int array (F, H, W)
    values : array (T,)

    Returns
    -------
    array (F, H, W) float32
    """
    return np.asarray(values, dtype=np.float32)[labels]
