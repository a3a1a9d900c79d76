"""The evaluation driver: score a results folder against a data set's ground truth and aggregate as DAVIS does."""

from __future__ import annotations

import logging
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from ..core.errors import InputError
from ..core.io import read_mask
from . import stats
from .datasets import (
    GT_LABELS,
    MAX_PROPOSALS,
    Dataset,
    limit_frames,
    load_dataset,
    locate_results,
    read_ground_truth,
)
from .metrics import T_SCALE, boundary_f_matrix, db_eval_boundary, db_eval_iou, db_eval_t, iou_matrix, seg2bmap

__all__ = ["evaluate", "evaluate_dataset", "default_workers"]

log = logging.getLogger(__name__)

#: Frames below which the work is done in this process (a pool costs more than it saves).
_MIN_JOBS_FOR_POOL = 48


def default_workers() -> int:
    """``min(2, number of CPUs)``."""
    return max(1, min(2, os.cpu_count() or 1))


# ---------------------------------------------------------------------------------------------------------------
# Per-frame jobs (module-level so that worker processes can run them)
# ---------------------------------------------------------------------------------------------------------------
def _worker_init() -> None:
    try:
        import cv2

        cv2.setNumThreads(1)
    except Exception:  # pragma: no cover - cv2 is a dependency; this is only a tuning knob
        pass


def _check_size(pred_path: Path, pred_shape, gt_path: Path, gt_shape) -> None:
    if tuple(pred_shape) != tuple(gt_shape):
        raise InputError(
            f"{pred_path}: result is {pred_shape[1]}x{pred_shape[0]} but the ground truth {gt_path} is "
            f"{gt_shape[1]}x{gt_shape[0]}; write results at the ground-truth resolution"
        )


def _job_binary(job: tuple) -> tuple[float, float]:
    pred_path, gt_mode, gt_paths, compute_f, bound_th = job
    gt, void = read_ground_truth(gt_mode, gt_paths)
    pred = read_mask(pred_path).astype(bool)
    _check_size(pred_path, pred.shape, gt_paths[0], gt.shape)
    j = db_eval_iou(pred, gt, void)
    f = db_eval_boundary(pred, gt, bound_th, void) if compute_f else math.nan
    return j, f


def _job_multi(job: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    pred_path, gt_paths, gt_ids, bound_th = job
    gt_raw, void = read_ground_truth(GT_LABELS, gt_paths)
    pred = read_mask(pred_path, keep_labels=True)
    _check_size(pred_path, pred.shape, gt_paths[0], gt_raw.shape)
    n_pred = int(pred.max()) if pred.size else 0
    if n_pred > MAX_PROPOSALS:
        hint = " (a binary 0/255 mask? write object ids as palette indices)" if n_pred == 255 else ""
        raise InputError(f"{pred_path}: object id {n_pred} in a result mask; the DAVIS-2017 unsupervised task "
                         f"allows ids 1..{MAX_PROPOSALS}{hint}")
    # ground-truth objects renumbered 1..G in the order of gt_ids
    lut = np.zeros(256, dtype=np.int64)
    lut[np.asarray(gt_ids, dtype=np.int64)] = np.arange(1, len(gt_ids) + 1)
    gt = lut[gt_raw]
    n_gt = len(gt_ids)
    j = iou_matrix(pred, gt, n_pred, n_gt, void)
    f = boundary_f_matrix(pred, gt, n_pred, n_gt, void, bound_th)
    keep = None if void is None else ~void
    j_empty = np.empty(n_gt)
    f_empty = np.empty(n_gt)
    for k in range(n_gt):
        obj = gt == k + 1
        if keep is not None:
            obj &= keep
        j_empty[k] = 0.0 if obj.any() else 1.0
        f_empty[k] = 0.0 if seg2bmap(obj).any() else 1.0
    return j, f, j_empty, f_empty


def _job_t(job: tuple) -> float:
    path_a, path_b = job
    return db_eval_t(read_mask(path_a), read_mask(path_b)) * T_SCALE


class _Runner:
    """Maps jobs in this process or in a pool of worker processes (created on first need)."""

    def __init__(self, workers: int):
        self.workers = max(1, int(workers))
        self._pool: ProcessPoolExecutor | None = None

    def map(self, fn: Callable, jobs: list, chunksize: int = 8, inline: bool = False) -> list:
        if inline or self.workers <= 1 or len(jobs) < _MIN_JOBS_FOR_POOL:
            return [fn(job) for job in jobs]
        if self._pool is None:
            import multiprocessing

            # Never plain fork: a parent that has run threads (torch's OpenMP pool after a pipeline run, a writer
            # thread, a thread pool of a test) can leave a lock held in the child, which then hangs for ever.
            # forkserver forks from a clean single-threaded server; like spawn it imports the caller's
            # __main__, so scripts calling evaluate() need the usual ``if __name__ == "__main__"`` guard.
            methods = multiprocessing.get_all_start_methods()
            method = "forkserver" if "forkserver" in methods else "spawn"
            self._pool = ProcessPoolExecutor(max_workers=self.workers, mp_context=multiprocessing.get_context(method),
                                             initializer=_worker_init)
        chunksize = max(1, min(chunksize, len(jobs) // (4 * self.workers) or 1))
        return list(self._pool.map(fn, jobs, chunksize=chunksize))

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(cancel_futures=True)
            self._pool = None


# ---------------------------------------------------------------------------------------------------------------
# Aggregation helpers
# ---------------------------------------------------------------------------------------------------------------
def _clean(value: Any) -> Any:
    """NaN/inf -> None and numpy scalars -> Python, recursively (JSON-ready)."""
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _mean_of(rows: Iterable[Mapping[str, float]], key: str) -> float:
    return stats.nanmean([r[key] for r in rows])


def _overall(per_seq: Mapping[str, Mapping], metrics: Sequence[str]) -> dict:
    out: dict[str, Any] = {}
    for metric in metrics:
        rows = [s[metric] for s in per_seq.values() if metric in s]
        out[metric] = {key: _mean_of(rows, key) for key in ("mean", "recall", "decay")}
    return out


def _attribute_table(dataset: Dataset, per_seq: Mapping[str, Mapping]) -> dict:
    table = {}
    seqs = [s for s in dataset.sequences if s.name in per_seq]
    for attr in dataset.attributes:
        with_attr = [per_seq[s.name]["J"]["mean"] for s in seqs if attr in s.attributes]
        without = [per_seq[s.name]["J"]["mean"] for s in seqs if attr not in s.attributes]
        m_with = stats.nanmean(with_attr)
        m_without = stats.nanmean(without)
        table[attr] = {
            "with": m_with,
            "without": m_without,
            "change": m_with - m_without,
            "n_with": len(with_attr),
            "n_without": len(without),
        }
    return table


# ---------------------------------------------------------------------------------------------------------------
# Protocols
# ---------------------------------------------------------------------------------------------------------------
def _evaluate_binary(dataset: Dataset, found, runner: _Runner, *, compute_f: bool, compute_t: bool,
                     bound_th: float, per_frame: bool, timings: dict) -> dict:
    jobs, owners = [], []
    for seq in dataset.sequences:
        files = found[seq.name].files
        for frame in seq.scored:
            jobs.append((files[frame], seq.gt_mode, seq.gt[frame], compute_f, bound_th))
            owners.append(seq.name)
    t0 = time.perf_counter()
    log.info("scoring %d frames of %d sequences (J%s)", len(jobs), len(dataset.sequences), " and F" if compute_f else "")
    # J and F stay in this process: a frame costs ~8 ms (PNG decoding and OpenCV, which is multi-threaded
    # already) and the benchmark ran slower with a pool of two; T is ~20x heavier per frame and uses the pool.
    values = runner.map(_job_binary, jobs, chunksize=16, inline=True)
    timings["J_F" if compute_f else "J"] = time.perf_counter() - t0
    by_seq: dict[str, list[tuple[float, float]]] = {}
    for name, val in zip(owners, values):
        by_seq.setdefault(name, []).append(val)

    t_values: dict[str, list[float]] = {}
    if compute_t:
        t_jobs, t_owners = [], []
        for seq in dataset.sequences:
            if not seq.eval_t:
                continue
            files = found[seq.name].files
            for a, b in zip(seq.scored[:-1], seq.scored[1:]):
                t_jobs.append((files[a], files[b]))
                t_owners.append(seq.name)
        t0 = time.perf_counter()
        log.info("temporal stability T on %d frame pairs of %d sequences", len(t_jobs),
                 len({o for o in t_owners}))
        for name, val in zip(t_owners, runner.map(_job_t, t_jobs, chunksize=4)):
            t_values.setdefault(name, []).append(val)
        timings["T"] = time.perf_counter() - t0

    per_seq: dict[str, dict] = {}
    for seq in dataset.sequences:
        vals = by_seq.get(seq.name, [])
        j = [v[0] for v in vals]
        entry: dict[str, Any] = {"J": stats.sequence_statistics(j)}
        if compute_f:
            entry["F"] = stats.sequence_statistics([v[1] for v in vals])
        if dataset.name == "davis2016":
            t_mean = stats.nanmean(t_values[seq.name]) if seq.name in t_values else math.nan
            entry["T"] = {"mean": t_mean}
            why = _why_no_t(dataset, seq, compute_t)
            if why:
                entry["T"]["missing"] = why
            entry["eval_t"] = seq.eval_t
            entry["attributes"] = list(seq.attributes)
        entry["n_frames"] = len(vals)
        if per_frame:
            entry["per_frame"] = {"frames": list(seq.scored), "J": j}
            if compute_f:
                entry["per_frame"]["F"] = [v[1] for v in vals]
            if seq.name in t_values:
                entry["per_frame"]["T_pairs"] = t_values[seq.name]
        per_seq[seq.name] = entry

    missing_t = {name: e["T"]["missing"] for name, e in per_seq.items() if "missing" in e.get("T", {})}
    if compute_t and missing_t:
        log.info("no T for %s", "; ".join(f"{name} ({why})" for name, why in missing_t.items()))
    metrics = ["J", "F"] if compute_f else ["J"]
    overall = _overall(per_seq, metrics)
    if dataset.name == "davis2016":
        t_seqs = [e["T"]["mean"] for e in per_seq.values() if e.get("eval_t")]
        overall["T"] = {"mean": stats.nanmean(t_seqs) if compute_t else math.nan}
    if compute_f:
        overall["JF"] = {"mean": (overall["J"]["mean"] + overall["F"]["mean"]) / 2}
    all_j = [v[0] for vals in by_seq.values() for v in vals]
    overall["J"]["frame_mean"] = stats.nanmean(all_j)
    overall["n_sequences"] = len(per_seq)
    overall["n_frames"] = len(all_j)
    return {"sequences": per_seq, "overall": overall}


def _why_no_t(dataset: Dataset, seq, compute_t: bool) -> str | None:
    """Why a DAVIS-2016 sequence has no T, or ``None`` when it has one."""
    if not compute_t:
        return "T not asked for"
    if not seq.eval_t:
        return "db_info.yml does not set eval_t for it: DAVIS leaves T out there"
    if len(seq.scored) < 2:
        return f"too few frames: {len(seq.scored)} scored, T needs 2 consecutive"
    return None


def _evaluate_davis2017(dataset: Dataset, found, runner: _Runner, *, bound_th: float, per_frame: bool,
                        timings: dict) -> dict:
    from scipy.optimize import linear_sum_assignment

    t0 = time.perf_counter()
    # ground-truth object ids per sequence: every id seen in any frame (void and background excluded)
    gt_ids: dict[str, list[int]] = {}
    id_jobs = [(seq.name, seq.gt[frame]) for seq in dataset.sequences for frame in seq.scored]
    for name, ids in zip([j[0] for j in id_jobs],
                         runner.map(_job_gt_ids, [j[1] for j in id_jobs], chunksize=16, inline=True)):
        gt_ids.setdefault(name, set()).update(ids)
    jobs, owners = [], []
    for seq in dataset.sequences:
        ids = sorted(gt_ids.get(seq.name, ()))
        gt_ids[seq.name] = ids
        if not ids:
            log.warning("sequence %s: no ground-truth objects; skipped", seq.name)
            continue
        files = found[seq.name].files
        for frame in seq.scored:
            jobs.append((files[frame], seq.gt[frame], ids, bound_th))
            owners.append(seq.name)
    log.info("scoring %d frames of %d sequences (DAVIS-2017 unsupervised)", len(jobs), len(dataset.sequences))
    results = runner.map(_job_multi, jobs, chunksize=8)
    timings["J_F"] = time.perf_counter() - t0

    by_seq: dict[str, list] = {}
    for name, res in zip(owners, results):
        by_seq.setdefault(name, []).append(res)
    per_seq: dict[str, dict] = {}
    all_objects: list[dict] = []
    for seq in dataset.sequences:
        frames = by_seq.get(seq.name)
        if not frames:
            continue
        n_gt = len(gt_ids[seq.name])
        n_pred = max(n_gt, max(f[0].shape[0] for f in frames))
        n_t = len(frames)
        j_all = np.empty((n_pred, n_gt, n_t))
        f_all = np.empty((n_pred, n_gt, n_t))
        for t, (j, f, j_empty, f_empty) in enumerate(frames):
            k = j.shape[0]
            j_all[:k, :, t] = j
            f_all[:k, :, t] = f
            j_all[k:, :, t] = j_empty[None, :]
            f_all[k:, :, t] = f_empty[None, :]
        score = (j_all.mean(axis=2) + f_all.mean(axis=2)) / 2
        rows, cols = linear_sum_assignment(-score)
        objects = {}
        for r, c in zip(rows, cols):
            entry = {"J": stats.sequence_statistics(j_all[r, c]), "F": stats.sequence_statistics(f_all[r, c]),
                     "matched_id": int(r + 1)}
            if per_frame:
                entry["per_frame"] = {"frames": list(seq.scored), "J": j_all[r, c].tolist(),
                                      "F": f_all[r, c].tolist()}
            objects[str(gt_ids[seq.name][c])] = entry
            all_objects.append(entry)
        seq_entry = _overall(objects, ["J", "F"])
        seq_entry["T"] = {"mean": math.nan}
        seq_entry["objects"] = objects
        seq_entry["n_frames"] = n_t
        seq_entry["attributes"] = list(seq.attributes)
        per_seq[seq.name] = seq_entry
    # every ground-truth object is one entry of the data-set means
    overall = _overall({str(k): o for k, o in enumerate(all_objects)}, ["J", "F"])
    overall["T"] = {"mean": math.nan}
    overall["JF"] = {"mean": (overall["J"]["mean"] + overall["F"]["mean"]) / 2}
    overall["n_sequences"] = len(per_seq)
    overall["n_objects"] = len(all_objects)
    return {"sequences": per_seq, "overall": overall}


def _job_gt_ids(gt_paths: tuple) -> set[int]:
    labels, _ = read_ground_truth(GT_LABELS, gt_paths)
    ids = np.flatnonzero(np.bincount(labels.ravel(), minlength=256))
    return {int(i) for i in ids if i != 0}


# ---------------------------------------------------------------------------------------------------------------
# Entry points
# ---------------------------------------------------------------------------------------------------------------
_PROTOCOLS = {
    "davis2016": "DAVIS-2016: frames 1..n-2 scored; J, F (Mean/Recall/Decay), T on eval_t sequences; "
                 "means over sequences",
    "davis2017": "DAVIS-2017 unsupervised: all frames; up to 20 result ids matched to ground-truth objects "
                 "(Hungarian on (J+F)/2); means over objects",
    "segtrackv2": "SegTrack-v2: all frames, objects merged into one foreground; mean IoU per sequence, "
                  "overall = mean over sequences (frame_mean: over all frames)",
    "fbms59": "FBMS-59: annotated frames only, all regions but the background merged; J and F; means over "
              "sequences",
    "folders": "generic folders: every frame with ground truth; J and F; means over sequences",
}


def evaluate_dataset(
    dataset: Dataset,
    results: str | Path,
    *,
    compute_t: bool = True,
    workers: int | None = None,
    bound_th: float = 0.008,
    per_frame: bool = False,
    max_frames: int | None = None,
) -> dict:
    """Score ``results`` against an already loaded :class:`~eponet.evaluation.datasets.Dataset`.

    See :func:`evaluate` for the result structure.
    """
    in_ground_truth = {seq.name: len(seq.scored) for seq in dataset.sequences}
    if max_frames is not None:
        dataset = limit_frames(dataset, max_frames)
        scored = sum(len(seq.scored) for seq in dataset.sequences)
        log.info("scoring the frames a run with max_frames %d processed: %d of %d scored ground-truth frames",
                 max_frames, scored, sum(in_ground_truth.values()))
    found = locate_results(dataset, results)
    runner = _Runner(default_workers() if workers is None else workers)
    timings: dict[str, float] = {}
    try:
        if dataset.name == "davis2017":
            body = _evaluate_davis2017(dataset, found, runner, bound_th=bound_th, per_frame=per_frame,
                                       timings=timings)
        else:
            body = _evaluate_binary(
                dataset, found, runner, compute_f=dataset.name != "segtrackv2",
                compute_t=compute_t and dataset.name == "davis2016", bound_th=bound_th, per_frame=per_frame,
                timings=timings)
    finally:
        runner.close()
    for seq in dataset.sequences:
        if seq.name in body["sequences"]:
            body["sequences"][seq.name].update(frames_scored=len(seq.scored),
                                               frames_in_ground_truth=in_ground_truth[seq.name])
    attributes = _attribute_table(dataset, body["sequences"]) if dataset.attributes else {}
    out = {
        "dataset": dataset.name,
        "protocol": _PROTOCOLS[dataset.name],
        "root": str(dataset.root),
        "results": str(Path(results)),
        "resolution": dataset.resolution,
        "sequences": body["sequences"],
        "overall": body["overall"],
        "attributes": attributes,
        "timings_s": timings,
    }
    if max_frames is not None:
        out["max_frames"] = max_frames
    if dataset.notes:
        out["notes"] = list(dataset.notes)
    return _clean(out)


def evaluate(
    dataset: str,
    root: str | Path,
    results: str | Path,
    sequences: Sequence[str] | None = None,
    resolution: str = "480p",
    *,
    split: str | None = None,
    frames: str | Path | None = None,
    compute_t: bool = True,
    workers: int | None = None,
    bound_th: float = 0.008,
    per_frame: bool = False,
    max_frames: int | None = None,
) -> dict:
    """Evaluate a results folder on a data set with the DAVIS protocol (``shared/docs/metrics.md``).

    Parameters
    ----------
    dataset : str
        ``davis2016``, ``davis2017``, ``segtrackv2``, ``fbms59`` or ``folders``.
    root : path
        The data set's root (see :func:`~eponet.evaluation.datasets.load_dataset`).
    results : path
        Folder holding ``<seq>/masks/<frame>.png`` (eponet's output layout) or ``<seq>/<frame>.png``;
        DAVIS-2017: palette masks of object ids 1..20.
    sequences : list of str, optional
        Only these sequences.
    resolution : str
        DAVIS annotation resolution (results must have the same size as the ground truth).
    split, frames
        See :func:`~eponet.evaluation.datasets.load_dataset`.
    compute_t : bool
        Compute T (DAVIS-2016 only; the slow part).
    workers : int, optional
        Processes for T and for the DAVIS-2017 object matrices; default ``min(2, CPUs)``. J and F of binary data
        sets run in this process (fast enough, and a pool did not pay off for them).
    bound_th : float
        F tolerance (fraction of the diagonal, or pixels if >= 1).
    per_frame : bool
        Also keep the per-frame values of every sequence (``"per_frame"``).
    max_frames : int, optional
        Score only the first ``max_frames`` frames of each sequence (those a run with ``input.max_frames``
        processed); each sequence records ``frames_scored`` and ``frames_in_ground_truth``.

    Returns
    -------
    dict
        JSON-ready (missing values are ``None``)::

            {"dataset", "protocol", "root", "results", "resolution",
             "sequences": {seq: {"J": {"mean", "recall", "decay"}, "F": {...}, "T": {"mean"[, "missing": why]},
                                 "n_frames", "frames_scored", "frames_in_ground_truth", ...}},
             "overall": {"J": {...}, "F": {...}, "T": {"mean"}, "JF": {"mean"}, "n_sequences", ...},
             "attributes": {attr: {"with", "without", "change", "n_with", "n_without"}},
             "timings_s": {...}}

    Raises
    ------
    InputError
        Missing root, unknown data set or sequence, missing results for a sequence or frame (all named), a
        result whose size differs from its ground truth, unreadable masks.
    """
    ds = load_dataset(dataset, root, sequences=sequences, resolution=resolution, split=split, frames=frames)
    return evaluate_dataset(ds, results, compute_t=compute_t, workers=workers, bound_th=bound_th,
                            per_frame=per_frame, max_frames=max_frames)
