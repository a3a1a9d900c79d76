"""Ground-truth loaders: DAVIS-2016, DAVIS-2017 (unsupervised), SegTrack-v2, FBMS-59 and a generic masks folder.

A loader lists, per sequence, the ordered frame names (file stems), which frames are scored and where their
ground truth is; masks are read lazily with :func:`read_ground_truth` (so that worker processes can read them).
Results are looked up with :func:`locate_results`: ``DIR/<seq>/masks/<frame>.png`` (eponet's output layout)
or ``DIR/<seq>/<frame>.png``.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from ..core.errors import InputError
from ..core.io import IMAGE_SUFFIXES, natural_key, read_mask
from ..core.registry import nearest

__all__ = [
    "DATASETS",
    "davis_annotations",
    "limit_frames",
    "DATASET_ALIASES",
    "VOID_LABEL",
    "MAX_PROPOSALS",
    "SequenceGT",
    "Dataset",
    "canonical_dataset",
    "load_dataset",
    "read_ground_truth",
    "read_davis_info",
    "locate_results",
    "ResultFiles",
]

log = logging.getLogger(__name__)

#: Data sets this module can load, by canonical name.
DATASETS = ("davis2016", "davis2017", "segtrackv2", "fbms59", "folders")
DATASET_ALIASES = {
    "davis2016": "davis2016", "davis-2016": "davis2016", "davis16": "davis2016", "davis": "davis2016",
    "davis2017": "davis2017", "davis-2017": "davis2017", "davis17": "davis2017",
    "segtrackv2": "segtrackv2", "segtrack-v2": "segtrackv2", "segtrack": "segtrackv2", "segtrack2": "segtrackv2",
    "fbms59": "fbms59", "fbms-59": "fbms59", "fbms": "fbms59",
    "folders": "folders", "generic": "folders", "folder": "folders",
}
#: DAVIS-2017 ground-truth label for pixels that are not scored.
VOID_LABEL = 255
#: DAVIS-2017 unsupervised: the most object ids a result mask may use.
MAX_PROPOSALS = 20
#: Result files are looked for with these suffixes, in this order (lossless formats only).
RESULT_SUFFIXES = (".png", ".bmp", ".pgm", ".ppm", ".tif", ".tiff")

#: Files read as masks or frames (FBMS-59 ships PGM/PPM ground truth).
MASK_SUFFIXES = tuple(dict.fromkeys(IMAGE_SUFFIXES + (".pgm", ".pbm", ".ppm")))

# How a sequence's ground-truth files are turned into masks (see read_ground_truth).
GT_BINARY = "binary"  # one file, non-zero is foreground
GT_LABELS = "labels"  # one file of object ids, 255 void (DAVIS-2017)
GT_UNION = "union"  # one file per object, merged into one foreground (SegTrack-v2)
GT_BORDER_BACKGROUND = "border_background"  # region colours; the one covering most of the border is background


@dataclass(frozen=True)
class SequenceGT:
    """Ground truth of one sequence.

    ``frames`` are all frame names in order; ``scored`` the ones whose results are scored (a subset, in the same
    order); ``gt[frame]`` the file(s) holding that frame's ground truth, read with ``gt_mode``.
    """

    name: str
    frames: tuple[str, ...]
    scored: tuple[str, ...]
    gt: Mapping[str, tuple[Path, ...]]
    gt_mode: str = GT_BINARY
    attributes: tuple[str, ...] = ()
    eval_t: bool = False

    def read_gt(self, frame: str) -> tuple[np.ndarray, np.ndarray | None]:
        """The ground truth of ``frame``: see :func:`read_ground_truth`."""
        return read_ground_truth(self.gt_mode, self.gt[frame])


@dataclass(frozen=True)
class Dataset:
    """A loaded data set: its canonical ``name``, ``root``, sequences in order, and attribute names."""

    name: str
    root: Path
    sequences: tuple[SequenceGT, ...]
    attributes: tuple[str, ...] = ()
    resolution: str | None = None
    notes: tuple[str, ...] = field(default=())

    def __getitem__(self, name: str) -> SequenceGT:
        for seq in self.sequences:
            if seq.name == name:
                return seq
        raise KeyError(name)


def canonical_dataset(name: str) -> str:
    """The canonical name of a data set given any accepted spelling; :class:`InputError` if unknown."""
    key = str(name).strip().lower().replace("_", "-")
    if key in DATASET_ALIASES:
        return DATASET_ALIASES[key]
    if key.replace("-", "") in DATASET_ALIASES:
        return DATASET_ALIASES[key.replace("-", "")]
    raise InputError(f"unknown dataset {name!r}; choose one of: {', '.join(DATASETS)}")


# ---------------------------------------------------------------------------------------------------------------
# Reading ground truth
# ---------------------------------------------------------------------------------------------------------------
def read_ground_truth(mode: str, paths: Sequence[Path]) -> tuple[np.ndarray, np.ndarray | None]:
    """Read one frame's ground truth.

    Returns ``(gt, void)``: for ``"labels"`` (DAVIS-2017) ``gt`` is uint8 object ids with the void label
    replaced by 0 and ``void`` the bool mask of void pixels; otherwise ``gt`` is a bool foreground mask and
    ``void`` is None. All files of one frame must have the same size.
    """
    if mode == GT_BINARY:
        return read_mask(paths[0]).astype(bool), None
    if mode == GT_LABELS:
        labels = read_mask(paths[0], keep_labels=True)
        void = labels == VOID_LABEL
        if void.any():
            labels = np.where(void, 0, labels).astype(np.uint8)
            return labels, void
        return labels, None
    if mode == GT_UNION:
        merged = None
        for path in paths:
            mask = read_mask(path).astype(bool)
            if merged is None:
                merged = mask
            elif mask.shape != merged.shape:
                raise InputError(
                    f"{path}: ground truth is {mask.shape[1]}x{mask.shape[0]} but {paths[0]} is "
                    f"{merged.shape[1]}x{merged.shape[0]}; all objects of a frame must have one size"
                )
            else:
                merged |= mask
        return merged, None
    if mode == GT_BORDER_BACKGROUND:
        labels = read_mask(paths[0], keep_labels=True)
        border = np.concatenate([labels[0], labels[-1], labels[1:-1, 0], labels[1:-1, -1]])
        background = np.bincount(border, minlength=256).argmax()
        return labels != background, None
    raise ValueError(f"unknown ground-truth mode {mode!r}")


# ---------------------------------------------------------------------------------------------------------------
# Helpers
# ---------------------------------------------------------------------------------------------------------------
def _check_root(root: str | Path, what: str) -> Path:
    root = Path(root).expanduser()
    if not root.exists():
        raise InputError(f"{root}: {what} root does not exist")
    if not root.is_dir():
        raise InputError(f"{root}: {what} root is not a folder")
    return root


def list_images(folder: Path) -> list[Path]:
    """Image files (masks included: PGM/PPM) directly inside ``folder``, in natural order."""
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in MASK_SUFFIXES
             and not p.name.startswith(".")]
    return sorted(files, key=lambda p: natural_key(p.name))


def _subdirs(folder: Path) -> list[Path]:
    return sorted((p for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")),
                  key=lambda p: natural_key(p.name))


def _stems(files: Iterable[Path]) -> list[str]:
    return [p.stem for p in files]


def _unique_stems(folder: Path, files: list[Path]) -> dict[str, Path]:
    out: dict[str, Path] = {}
    for path in files:
        if path.stem in out:
            raise InputError(f"{folder}: two files for frame {path.stem!r}: {out[path.stem].name} and {path.name}")
        out[path.stem] = path
    return out


def read_davis_info(root: Path) -> dict:
    """``db_info.yml`` of a DAVIS root (``ROOT/db_info.yml``, ``.yaml`` or ``ROOT/Annotations/db_info.yml``) as
    ``{"attributes": [...], "sequences": {name: {"attributes": [...], "eval_t": bool, "set": str|None}}}``;
    empty when there is none."""
    import yaml

    for candidate in (root / "db_info.yml", root / "db_info.yaml", root / "Annotations" / "db_info.yml"):
        if candidate.is_file():
            try:
                data = yaml.safe_load(candidate.read_text(encoding="utf-8")) or {}
            except (OSError, yaml.YAMLError) as exc:
                raise InputError(f"{candidate}: cannot read ({exc.__class__.__name__}: {exc})".splitlines()[0]) from None
            if not isinstance(data, dict):
                raise InputError(f"{candidate}: expected a mapping with 'sequences'")
            seqs = {}
            for entry in data.get("sequences") or []:
                if not isinstance(entry, dict) or "name" not in entry:
                    raise InputError(f"{candidate}: every entry of 'sequences' needs a 'name'")
                seqs[str(entry["name"])] = {
                    "attributes": [str(a) for a in entry.get("attributes") or []],
                    "eval_t": bool(entry.get("eval_t", False)),
                    "set": None if entry.get("set") is None else str(entry["set"]),
                }
            attrs = [str(a) for a in data.get("attributes") or []]
            if not attrs:
                attrs = sorted({a for info in seqs.values() for a in info["attributes"]})
            return {"attributes": attrs, "sequences": seqs, "file": candidate}
    return {}


def _read_imageset(root: Path, split: str, subdirs: Sequence[str]) -> list[str] | None:
    """Sequence names of ``ImageSets/[sub/]<split>.txt``: one name per line, or DAVIS-2016 path pairs."""
    for sub in subdirs:
        path = root / "ImageSets" / sub / f"{split}.txt" if sub else root / "ImageSets" / f"{split}.txt"
        if not path.is_file():
            continue
        names: list[str] = []
        for line in path.read_text(encoding="utf-8").splitlines():
            token = line.strip().split()[0] if line.strip() else ""
            if not token:
                continue
            name = Path(token).parent.name if "/" in token else token
            if name not in names:
                names.append(name)
        return names
    return None


def _select(available: Sequence[str], wanted: Sequence[str] | None, where: Path) -> list[str]:
    if wanted is None:
        return list(available)
    missing = [s for s in wanted if s not in available]
    if missing:
        shown = ", ".join(repr(s) for s in missing[:5]) + (" ..." if len(missing) > 5 else "")
        hint = nearest(missing[0], list(available))
        raise InputError(f"{where}: no ground truth for sequence(s) {shown}"
                         f"{f' (did you mean {hint!r}?)' if hint else ''}")
    return list(dict.fromkeys(wanted))


# ---------------------------------------------------------------------------------------------------------------
# DAVIS
# ---------------------------------------------------------------------------------------------------------------
def davis_annotations(name: str, root: Path, resolution: str) -> Path:
    """The annotation folder of a DAVIS root (``davis2016``: ``Annotations/<resolution>``; ``davis2017``:
    ``Annotations_unsupervised/<resolution>``, else ``Annotations/<resolution>``); an :class:`InputError` naming
    the missing folder and the resolutions that exist when there is none."""
    root = Path(root)
    ann_dir = root / ("Annotations" if name == "davis2016" else "Annotations_unsupervised") / resolution
    if name != "davis2016" and not ann_dir.is_dir() and (root / "Annotations" / resolution).is_dir():
        log.warning("%s: no Annotations_unsupervised/%s; using Annotations/%s (the semi-supervised objects)",
                    root, resolution, resolution)
        ann_dir = root / "Annotations" / resolution
    if not ann_dir.is_dir():
        found = [p.name for p in (ann_dir.parent.iterdir() if ann_dir.parent.is_dir() else []) if p.is_dir()]
        hint = f"resolutions here: {', '.join(sorted(found))}" if found else f"no {ann_dir.parent.name}/ folder in {root}"
        raise InputError(f"{ann_dir}: no such folder, so {name} cannot be scored at {resolution} ({hint})")
    return ann_dir


def _load_davis(name: str, root: Path, sequences, resolution: str, split: str | None) -> Dataset:
    set_dirs = ("", resolution, "2016") if name == "davis2016" else ("2017", "", resolution)
    ann_dir = davis_annotations(name, root, resolution)
    info = read_davis_info(root)
    seq_info = info.get("sequences", {})
    on_disk = [p.name for p in _subdirs(ann_dir)]
    if sequences is not None:
        names = _select(on_disk, sequences, ann_dir)
    elif split is not None:
        names = [s for s, meta in seq_info.items() if meta["set"] == split]
        if not names:
            names = _read_imageset(root, split, set_dirs) or []
        if not names:
            raise InputError(f"{root}: no sequences for split {split!r} (neither db_info.yml nor ImageSets lists it)")
        names = _select(on_disk, names, ann_dir)
    else:
        order = {s: k for k, s in enumerate(seq_info)}
        names = sorted(on_disk, key=lambda s: (order.get(s, len(order)), natural_key(s)))
    if not names:
        raise InputError(f"{ann_dir}: no sequence folders")
    out = []
    for seq in names:
        folder = ann_dir / seq
        files = [p for p in list_images(folder) if p.suffix.lower() == ".png"]
        if not files:
            raise InputError(f"{folder}: no ground-truth .png masks for sequence {seq!r}")
        by_stem = _unique_stems(folder, files)
        frames = tuple(by_stem)
        meta = seq_info.get(seq)
        if name == "davis2016":
            scored = frames[1:-1]
            if not scored:
                raise InputError(f"{folder}: sequence {seq!r} has {len(frames)} frame(s); DAVIS-2016 scores frames "
                                 "1..n-2 and needs at least 3")
            mode = GT_BINARY
            eval_t = meta["eval_t"] if meta is not None else True
        else:
            scored = frames
            mode = GT_LABELS
            eval_t = False
        out.append(SequenceGT(
            name=seq, frames=frames, scored=scored, gt={s: (by_stem[s],) for s in frames}, gt_mode=mode,
            attributes=tuple(meta["attributes"]) if meta else (), eval_t=eval_t,
        ))
    notes = () if seq_info or name != "davis2016" else (
        "no db_info.yml: attributes unknown and T computed for every sequence",)
    return Dataset(name=name, root=root, sequences=tuple(out), attributes=tuple(info.get("attributes", ())),
                   resolution=resolution, notes=notes)


# ---------------------------------------------------------------------------------------------------------------
# SegTrack-v2
# ---------------------------------------------------------------------------------------------------------------
def _load_segtrack(root: Path, sequences) -> Dataset:
    gt_dir = root / "GroundTruth"
    if not gt_dir.is_dir():
        raise InputError(f"{gt_dir}: no such folder; expected SegTrack-v2 GroundTruth/<sequence>/ under --root")
    on_disk = [p.name for p in _subdirs(gt_dir)]
    names = _select(on_disk, sequences, gt_dir)
    if not names:
        raise InputError(f"{gt_dir}: no sequence folders")
    out = []
    for seq in names:
        folder = gt_dir / seq
        objects = []
        direct = list_images(folder)
        if direct:
            objects.append((folder, _unique_stems(folder, direct)))
        for sub in _subdirs(folder):
            files = list_images(sub)
            if files:
                objects.append((sub, _unique_stems(sub, files)))
        if not objects:
            raise InputError(f"{folder}: no ground-truth masks for sequence {seq!r}")
        stems = sorted({s for _, by_stem in objects for s in by_stem}, key=natural_key)
        gt = {s: tuple(by_stem[s] for _, by_stem in objects if s in by_stem) for s in stems}
        out.append(SequenceGT(name=seq, frames=tuple(stems), scored=tuple(stems), gt=gt, gt_mode=GT_UNION))
    return Dataset(name="segtrackv2", root=root, sequences=tuple(out))


# ---------------------------------------------------------------------------------------------------------------
# FBMS-59
# ---------------------------------------------------------------------------------------------------------------
_GT_SUFFIX = re.compile(r"_gt$", re.IGNORECASE)
_TRAILING_INT = re.compile(r"(\d+)$")


def _fbms_sequence_dirs(root: Path, split: str | None) -> list[Path]:
    groups = {"train": "Trainingset", "training": "Trainingset", "trainingset": "Trainingset",
              "test": "Testset", "testset": "Testset"}
    parents = [root]
    present = [g for g in ("Trainingset", "Testset") if (root / g).is_dir()]
    if present:
        if split is not None:
            group = groups.get(split.lower())
            if group is None or group not in present:
                raise InputError(f"{root}: no FBMS split {split!r} (found: {', '.join(present)})")
            parents = [root / group]
        else:
            parents = [root / g for g in present]
    dirs = []
    for parent in parents:
        dirs.extend(d for d in _subdirs(parent) if (d / "GroundTruth").is_dir())
    return dirs


def _load_fbms(root: Path, sequences, split: str | None) -> Dataset:
    dirs = _fbms_sequence_dirs(root, split)
    if not dirs:
        raise InputError(f"{root}: no FBMS-59 sequences (folders <sequence>/ with a GroundTruth/ sub-folder)")
    by_name: dict[str, Path] = {}
    for d in dirs:
        if d.name in by_name:
            raise InputError(f"{d}: sequence name {d.name!r} appears twice (also {by_name[d.name]}); pick a split")
        by_name[d.name] = d
    names = _select(list(by_name), sequences, root)
    out = []
    for seq in names:
        folder = by_name[seq]
        frame_files = list_images(folder)
        frames = _stems(frame_files)
        gt_files = [p for p in list_images(folder / "GroundTruth") if "prob" not in p.name.lower()]
        if not gt_files:
            raise InputError(f"{folder / 'GroundTruth'}: no ground-truth images for sequence {seq!r}")
        by_int: dict[int, str] = {}
        for stem in frames:
            match = _TRAILING_INT.search(stem)
            if match:
                by_int.setdefault(int(match.group(1)), stem)
        gt: dict[str, tuple[Path, ...]] = {}
        for path in gt_files:
            stem = _GT_SUFFIX.sub("", path.stem)
            if frames:
                if stem not in frames:
                    match = _TRAILING_INT.search(stem)
                    frame = by_int.get(int(match.group(1))) if match else None
                    if frame is None:
                        raise InputError(f"{path}: ground truth matches no frame of sequence {seq!r} in {folder}")
                    stem = frame
            if stem in gt:
                raise InputError(f"{path}: a second ground-truth file for frame {stem!r} (also {gt[stem][0].name})")
            gt[stem] = (path,)
        if not frames:
            frames = sorted(gt, key=natural_key)
        scored = tuple(s for s in frames if s in gt)
        out.append(SequenceGT(name=seq, frames=tuple(frames), scored=scored, gt=gt, gt_mode=GT_BORDER_BACKGROUND))
    return Dataset(name="fbms59", root=root, sequences=tuple(out),
                   notes=("FBMS-59: all regions but the one covering most of the image border are foreground",))


# ---------------------------------------------------------------------------------------------------------------
# Generic frames folder + masks folder
# ---------------------------------------------------------------------------------------------------------------
def _load_folders(root: Path, sequences, frames_root: str | Path | None) -> Dataset:
    direct = list_images(root)
    if direct:
        groups = [(root.name, root, direct)]
    else:
        groups = [(d.name, d, list_images(d)) for d in _subdirs(root)]
        groups = [g for g in groups if g[2]]
    if not groups:
        raise InputError(f"{root}: no ground-truth masks (images directly inside, or in <sequence>/ sub-folders)")
    on_disk = [g[0] for g in groups]
    names = _select(on_disk, sequences, root)
    frames_root = None if frames_root is None else Path(frames_root).expanduser()
    if frames_root is not None and not frames_root.is_dir():
        raise InputError(f"{frames_root}: frames folder does not exist")
    out = []
    for seq, folder, files in groups:
        if seq not in names:
            continue
        by_stem = _unique_stems(folder, files)
        if frames_root is not None:
            frame_dir = frames_root if direct else frames_root / seq
            frame_files = list_images(frame_dir) if frame_dir.is_dir() else []
            if not frame_files:
                raise InputError(f"{frame_dir}: no frames for sequence {seq!r}")
            frames = _stems(frame_files)
            extra = [s for s in by_stem if s not in set(frames)]
            if extra:
                raise InputError(f"{folder / by_stem[extra[0]].name}: ground truth for frame {extra[0]!r}, which is "
                                 f"not among the frames in {frame_dir}")
        else:
            frames = list(by_stem)
        scored = tuple(s for s in frames if s in by_stem)
        out.append(SequenceGT(name=seq, frames=tuple(frames), scored=scored,
                              gt={s: (by_stem[s],) for s in scored}, gt_mode=GT_BINARY))
    order = {s: k for k, s in enumerate(names)}
    out.sort(key=lambda s: order[s.name])
    return Dataset(name="folders", root=root, sequences=tuple(out))


# ---------------------------------------------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------------------------------------------
def load_dataset(
    dataset: str,
    root: str | Path,
    *,
    sequences: Sequence[str] | None = None,
    resolution: str = "480p",
    split: str | None = None,
    frames: str | Path | None = None,
) -> Dataset:
    """Load a data set's ground-truth index (no masks are read).

    Parameters
    ----------
    dataset : str
        ``davis2016``, ``davis2017``, ``segtrackv2``, ``fbms59`` or ``folders`` (aliases such as ``DAVIS-2016``
        are accepted).
    root : path
        DAVIS: the folder holding ``Annotations/<resolution>/`` (2017: ``Annotations_unsupervised/``) and
        ``db_info.yml``; SegTrack-v2: the folder holding ``GroundTruth/``; FBMS-59: the folder of sequence
        folders (or holding ``Trainingset/`` and ``Testset/``); ``folders``: a folder of ground-truth masks, or
        of ``<sequence>/`` folders of masks.
    sequences : list of str, optional
        Only these sequences, in this order.
    resolution : str
        DAVIS annotation resolution folder.
    split : str, optional
        DAVIS: a ``set`` of ``db_info.yml`` or an ``ImageSets`` list (``train``, ``val``); FBMS-59: ``train`` or
        ``test``. Default: every sequence found.
    frames : path, optional
        ``folders`` only: the frames folder (or folder of ``<sequence>/`` frame folders) that orders the frames.
    """
    name = canonical_dataset(dataset)
    root = _check_root(root, name)
    if sequences is not None:
        sequences = [str(s) for s in sequences]
        if not sequences:
            raise InputError("no sequences selected (empty --sequences)")
    if frames is not None and name != "folders":
        raise InputError(f"a frames folder is only used with the 'folders' dataset, not {name!r}")
    if name in ("davis2016", "davis2017"):
        return _load_davis(name, root, sequences, resolution, split)
    if name == "segtrackv2":
        return _load_segtrack(root, sequences)
    if name == "fbms59":
        return _load_fbms(root, sequences, split)
    return _load_folders(root, sequences, frames)


def limit_frames(dataset: Dataset, max_frames: int) -> Dataset:
    """``dataset`` with each sequence cut to its first ``max_frames`` frames (a run with ``input.max_frames``
    processed only those): ``scored`` keeps the scored frames among them. A data set indexed without its frames
    (FBMS-59 without a frames folder) knows only its annotated frames, and those are what is counted."""
    sequences = []
    for seq in dataset.sequences:
        kept = set(seq.frames[:max_frames])
        sequences.append(replace(seq, frames=seq.frames[:max_frames], scored=tuple(f for f in seq.scored if f in kept)))
    return replace(dataset, sequences=tuple(sequences))


# ---------------------------------------------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ResultFiles:
    """Where a sequence's result masks are: ``folder`` and one file per scored frame."""

    sequence: str
    folder: Path
    files: Mapping[str, Path]


def _candidate_dirs(results: Path, seq: str, single: bool) -> list[Path]:
    dirs = [results / seq / "masks", results / seq]
    if single:
        dirs += [results / "masks", results]
    return dirs


def locate_results(dataset: Dataset, results: str | Path) -> dict[str, ResultFiles]:
    """Find every scored frame's result mask; a missing sequence or frame is an :class:`InputError` naming them.

    A sequence's results are in ``RESULTS/<seq>/masks/`` or ``RESULTS/<seq>/`` (the first that exists); a
    frame's file is ``<frame>.png`` (other lossless image formats are accepted too). With a single-sequence
    ``folders`` data set, ``RESULTS/masks/`` and ``RESULTS/`` are tried as well.
    """
    results = Path(results).expanduser()
    if not results.is_dir():
        raise InputError(f"{results}: results folder does not exist")
    single = dataset.name == "folders" and len(dataset.sequences) == 1
    found: dict[str, ResultFiles] = {}
    problems: list[str] = []
    for seq in dataset.sequences:
        folder = next((d for d in _candidate_dirs(results, seq.name, single) if d.is_dir()), None)
        if folder is None:
            problems.append(f"sequence {seq.name!r} (no folder {results / seq.name / 'masks'} or "
                            f"{results / seq.name})")
            continue
        names = {p.name: p for p in folder.iterdir() if p.suffix.lower() in MASK_SUFFIXES}
        files: dict[str, Path] = {}
        missing: list[str] = []
        for frame in seq.scored:
            path = next((names[frame + sfx] for sfx in RESULT_SUFFIXES if frame + sfx in names), None)
            if path is None:
                path = next((names[frame + sfx.upper()] for sfx in RESULT_SUFFIXES if frame + sfx.upper() in names),
                            None)
            if path is None:
                missing.append(frame)
            else:
                files[frame] = path
        if missing:
            shown = ", ".join(missing[:5]) + (f" and {len(missing) - 5} more" if len(missing) > 5 else "")
            problems.append(f"sequence {seq.name!r} frame(s) {shown} ({len(missing)} of {len(seq.scored)} scored "
                            f"frames missing in {folder})")
        found[seq.name] = ResultFiles(seq.name, folder, files)
    if problems:
        head = "missing results: " + "; ".join(problems[:4])
        if len(problems) > 4:
            head += f"; and {len(problems) - 4} more sequence(s)"
        raise InputError(head)
    return found
