"""Input discovery and loading: a folder of frames, a video file, a DAVIS-layout root, or a corpus (a list file
or a glob of videos and frame folders)."""

from __future__ import annotations

import glob
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .errors import InputError
from .io import IMAGE_SUFFIXES, LIST_SUFFIXES, VIDEO_SUFFIXES, is_pattern, list_images, natural_key, read_image
from .registry import nearest
from .types import MIN_FRAMES, MIN_SIDE, Video

__all__ = ["SequenceSource", "discover_sequences", "iter_frames", "load_video", "video_from_frames", "processing_size"]


#: A video whose decoder stops more than this many frames before the header's frame count is cut short (container
#: headers are approximate; a truncated file or a corrupt frame mid-file ends decoding early).
VIDEO_COUNT_SLACK = 2


@dataclass
class SequenceSource:
    """Where one sequence's frames come from: image ``files`` or one ``video`` file."""

    name: str
    files: list[Path] | None = None
    video: Path | None = None
    size: tuple[int, int] | None = None  # (H, W) of the input frames
    count: int = 0
    fps: float | None = None  # a video file's frame rate (its header's); None for frames or an unknown rate
    error: str | None = None  # a corpus entry that cannot run (missing, unreadable): the one-line reason
    # a sequence cut short by a corrupt frame after the first MIN_FRAMES (or a video whose decoder stopped well
    # before its header's count): the one-line reason naming that frame; the frames before it are processed
    stopped: str | None = None

    @property
    def stems(self) -> list[str]:
        if self.files is not None:
            return [f.stem for f in self.files]
        return [f"{t:05d}" for t in range(self.count)]


def processing_size(size: tuple[int, int], scale: float) -> tuple[int, int]:
    """Processing ``(H, W)`` for input ``size`` ``(H, W)`` and ``scale`` (at least ``MIN_SIDE`` px a side)."""
    return max(MIN_SIDE, int(round(size[0] * scale))), max(MIN_SIDE, int(round(size[1] * scale)))


def _check_size(where, size: tuple[int, int]) -> None:
    if min(size) < MIN_SIDE:
        raise InputError(f"{where}: frames are {size[1]}x{size[0]} px; the pipeline needs frames of at least "
                         f"{MIN_SIDE}x{MIN_SIDE} px")


def discover_sequences(
    path: Path, *, sequences: list[str] | None = None, resolution: str = "480p", max_frames: int | None = None,
    isolate: bool = False,
) -> list[SequenceSource]:
    """Find the sequences under ``path`` and check them (frame count, readable headers, equal sizes).

    ``path`` is a folder of frames, a video file, a DAVIS-layout root, a list file (:data:`LIST_SUFFIXES`) or a
    glob; each entry of a list or a glob is a video file or a frame folder. An entry that is missing or fails its
    checks raises :class:`InputError`, or, with ``isolate``, comes back as a source whose ``error`` says why
    (so that a run processes the others).
    """
    if is_pattern(path):
        matches = sorted(glob.glob(str(path), recursive=True), key=natural_key)
        if not matches:
            raise InputError(f"input.path: no file or folder matches {path}")
        return _corpus([(f"input.path: {path}: match {m}", Path(m)) for m in matches], sequences, max_frames, isolate)
    path = Path(path)
    if not path.exists():
        raise InputError(f"input.path: {path} does not exist")
    if path.is_file() and path.suffix.lower() in LIST_SUFFIXES:
        return _corpus(_list_entries(path), sequences, max_frames, isolate)
    if path.is_file():
        if sequences:
            raise InputError(f"input.sequences: only a DAVIS-layout root has sequences; {path} is a single video")
        return [_check_video(path, max_frames)]
    if (path / "JPEGImages").is_dir():
        root = path / "JPEGImages" / resolution
        if not root.is_dir():
            found = sorted(p.name for p in (path / "JPEGImages").iterdir() if p.is_dir())
            raise InputError(f"input.resolution: {root} does not exist; resolutions here: {', '.join(found) or 'none'}")
        available = sorted((p.name for p in root.iterdir() if p.is_dir()), key=natural_key)
        names = sequences or available
        for name in names:
            if name not in available:
                hint = nearest(name, available)
                raise InputError(
                    f"input.sequences: no sequence {name!r} in {root}{f' (did you mean {hint!r}?)' if hint else ''}"
                )
        if not names:
            raise InputError(f"input.path: {root} holds no sequence folders")
        return [_check_frames(root / name, name, max_frames) for name in names]
    if sequences:
        raise InputError(f"input.sequences: only a DAVIS-layout root (with JPEGImages/) has sequences; {path} is a folder of frames")
    return [_check_frames(path, path.name, max_frames)]


def _list_entries(path: Path) -> list[tuple[str, Path]]:
    """``(where, entry)`` for each line of a list file: paths relative to the list's folder."""
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"input.path: {path}: cannot read the list ({getattr(exc, 'strerror', None) or exc})") from None
    entries = []
    for number, line in enumerate(lines, start=1):
        line = line.strip()
        if line and not line.startswith("#"):
            entries.append((f"{path}: line {number}", path.parent / line))
    if not entries:
        raise InputError(f"input.path: {path} lists no videos or frame folders")
    return entries


def _corpus(entries: list[tuple[str, Path]], sequences: list[str] | None, max_frames: int | None,
            isolate: bool) -> list[SequenceSource]:
    """The sequences of a list or a glob: a video's name is its file's stem, a frame folder's its own name."""
    named: dict[str, tuple[str, Path]] = {}
    for where, entry in entries:
        name = entry.stem if entry.suffix.lower() in VIDEO_SUFFIXES or entry.is_file() else entry.name
        if name in named:
            raise InputError(f"{where}: {entry} and {named[name][1]} would both be sequence {name!r} "
                             f"(one output folder each); rename one")
        named[name] = (where, entry)
    for name in sequences or []:
        if name not in named:
            hint = nearest(name, list(named))
            raise InputError(f"input.sequences: no sequence {name!r} in the corpus"
                             f"{f' (did you mean {hint!r}?)' if hint else ''}")
    found = []
    for name in sequences or list(named):
        where, entry = named[name]
        try:
            if not entry.exists():
                raise InputError(f"{where}: {entry} does not exist")
            found.append(_check_frames(entry, name, max_frames) if entry.is_dir() else _check_video(entry, max_frames))
        except InputError as exc:
            if not isolate:
                raise
            found.append(SequenceSource(name=name, video=entry, error=str(exc)))
    return found


def _check_frames(folder: Path, name: str, max_frames: int | None) -> SequenceSource:
    from PIL import Image, UnidentifiedImageError

    files = list_images(folder)
    if not files:
        accepted = ", ".join(IMAGE_SUFFIXES)
        others = sorted((p.name for p in folder.iterdir() if not p.name.startswith(".")), key=natural_key)
        if not others:
            raise InputError(f"{folder}: empty folder, expected image frames ({accepted})")
        listing = ", ".join(others[:3]) + (f" and {len(others) - 3} more" if len(others) > 3 else "")
        raise InputError(f"{folder}: no image frames (it holds {listing}); accepted extensions: {accepted}")
    files = files[:max_frames] if max_frames else files
    if len(files) < MIN_FRAMES:
        raise InputError(f"{folder}: {len(files)} frame(s), the pipeline needs at least {MIN_FRAMES} (triplets)")
    size = None
    stopped = None
    for k, file in enumerate(files):
        try:
            with Image.open(file) as image:
                width, height = image.size
        except (OSError, UnidentifiedImageError):
            reason = f"{file}: cannot read image (not an image or corrupt)"
            if k < MIN_FRAMES:
                raise InputError(reason) from None
            files, stopped = files[:k], reason  # the frames before it still run (see SequenceSource.stopped)
            break
        if size is None:
            size = (height, width)
            _check_size(file, size)
        elif (height, width) != size:
            raise InputError(f"{file}: frame is {width}x{height} but the first frame {files[0].name} is {size[1]}x{size[0]}")
    return SequenceSource(name=name, files=files, size=size, count=len(files), stopped=stopped)


def _check_video(path: Path, max_frames: int | None) -> SequenceSource:
    if path.suffix.lower() in IMAGE_SUFFIXES:
        raise InputError(f"{path}: a single image; input.path must be a video, a folder of frames or a DAVIS root")
    capture = cv2.VideoCapture(str(path))
    try:
        ok, frame = capture.read() if capture.isOpened() else (False, None)
        if not ok or frame is None:
            kind = "video" if path.suffix.lower() in VIDEO_SUFFIXES else "file"
            raise InputError(f"{path}: not a readable video ({kind} could not be decoded by OpenCV)")
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        fps = float(capture.get(cv2.CAP_PROP_FPS))
    finally:
        capture.release()
    if max_frames:
        count = min(count, max_frames) if count > 0 else max_frames
    if 0 < count < MIN_FRAMES:
        raise InputError(f"{path}: {count} frame(s), the pipeline needs at least {MIN_FRAMES} (triplets)")
    _check_size(path, frame.shape[:2])
    fps = fps if np.isfinite(fps) and 0 < fps <= 1000 else None  # headers without a rate report 0 (or junk)
    return SequenceSource(name=path.stem, video=path, size=frame.shape[:2], count=count, fps=fps)


def iter_frames(source: SequenceSource, *, scale: float, max_frames: int | None = None, keep_full: bool = True):
    """Decode a sequence lazily: yields ``(stem, frame, full)`` per frame, ``frame`` uint8 RGB at the processing
    size (``scale``), ``full`` at the input size (``None`` unless ``keep_full``). One frame is decoded at a time.

    Raises :class:`InputError` naming the file and frame for a corrupt frame among the first ``MIN_FRAMES``, a
    frame whose size differs from the first's, or a video with fewer than ``MIN_FRAMES`` decodable frames (a
    video's header frame count is never trusted: frames are read until the decoder stops). A corrupt frame
    after those, or a video whose decoder stops more than :data:`VIDEO_COUNT_SLACK` frames before its header's
    count, ends the sequence there: ``source.stopped`` says why, naming the frame, and the frames before it
    have been yielded.
    """
    size = source.size
    shape = None
    count = 0
    for stem, full, where in _decoded(source, max_frames):
        if full is None:  # a corrupt frame (``where`` says why) after MIN_FRAMES good ones: the sequence ends here
            source.stopped = where
            return
        if size is None:
            size = full.shape[:2]
        if full.shape[:2] != tuple(size):
            raise InputError(f"{where}: frame {stem} is {full.shape[1]}x{full.shape[0]} but the first frame is "
                             f"{size[1]}x{size[0]}")
        shape = shape or processing_size(size, scale)
        frame = _resized(full, shape)
        count += 1
        yield stem, frame, (full if keep_full else None)
    if count < MIN_FRAMES:
        raise InputError(f"{source.video or source.name}: {count} decodable frame(s), the pipeline needs at least "
                         f"{MIN_FRAMES}")


def _resized(frame: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A frame at the processing size ``shape`` ``(h, w)`` (area interpolation)."""
    if frame.shape[:2] == tuple(shape):
        return frame
    return cv2.resize(frame, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def _decoded(source: SequenceSource, max_frames: int | None):
    if source.files is not None:
        for k, file in enumerate(source.files[:max_frames] if max_frames else source.files):
            try:
                image = read_image(file)
            except InputError as exc:
                if k < MIN_FRAMES:
                    raise
                yield file.stem, None, str(exc)
                return
            yield file.stem, image, file
        return  # (a list cut by the header check at an unreadable file has ``source.stopped`` set already)
    capture = cv2.VideoCapture(str(source.video))
    try:
        t = 0
        while max_frames is None or t < max_frames:
            ok, frame = capture.read()
            if not ok or frame is None:
                announced = min(source.count, max_frames or source.count)
                if t >= MIN_FRAMES and t < announced - VIDEO_COUNT_SLACK:  # a few frames short is normal
                    yield f"{t:05d}", None, (f"{source.video}: the decoder stopped at frame {t} of the {announced} "
                                             "the header announces (a corrupt or truncated file?)")
                break
            yield f"{t:05d}", cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), f"{source.video} frame {t}"
            t += 1
    finally:
        capture.release()


def load_video(source: SequenceSource, *, scale: float, max_frames: int | None = None, keep_full: bool = True) -> Video:
    """Decode a whole sequence into memory (:func:`iter_frames` collected); ``frames`` are at the processing
    resolution (``scale``). The run loop streams instead; this is for tools that need the whole video, so a
    sequence cut short (``source.stopped``) is an :class:`InputError` here."""
    stems, frames, full = [], [], []
    for stem, frame, whole in iter_frames(source, scale=scale, max_frames=max_frames, keep_full=True):
        stems.append(stem)
        frames.append(frame)
        full.append(whole)
    if source.stopped:
        raise InputError(source.stopped)
    sources = [str(f) for f in source.files[: len(stems)]] if source.files is not None else [str(source.video)]
    size = full[0].shape[:2]
    return Video(
        name=source.name,
        frames=np.stack(frames),
        stems=stems,
        size=(int(size[0]), int(size[1])),
        sources=sources,
        full_frames=np.stack(full) if keep_full else None,
    )


def video_from_frames(frames, *, name: str = "video", scale: float, max_frames: int | None = None,
                      keep_full: bool = True) -> Video:
    """A :class:`Video` of in-memory frames: a list of uint8 RGB ``(H, W, 3)`` arrays or one ``(F, H, W, 3)``
    array, checked as a folder of frames is (at least ``MIN_FRAMES``, sides of at least ``MIN_SIDE``, one size).

    >>> video = video_from_frames(np.zeros((4, 32, 48, 3), np.uint8), scale=0.5)
    >>> video.num_frames, video.shape, video.size
    (4, (16, 24), (32, 48))
    """
    frames = list(frames[:max_frames] if max_frames else frames)
    for t, frame in enumerate(frames):
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
            raise InputError(f"{name}: frame {t} is a {frame.dtype.name} array of shape {frame.shape}; expected "
                             f"uint8 RGB frames (H, W, 3), e.g. a (F, H, W, 3) uint8 array")
        if frame.shape != np.shape(frames[0]):
            raise InputError(f"{name}: frame {t} is {frame.shape[1]}x{frame.shape[0]} but the first frame is "
                             f"{np.shape(frames[0])[1]}x{np.shape(frames[0])[0]}")
        frames[t] = frame
    if len(frames) < MIN_FRAMES:
        raise InputError(f"{name}: {len(frames)} frame(s), the pipeline needs at least {MIN_FRAMES} (triplets)")
    size = frames[0].shape[:2]
    _check_size(name, size)
    shape = processing_size(size, scale)
    return Video(name=name, frames=np.stack([_resized(f, shape) for f in frames]),
                 stems=[f"{t:05d}" for t in range(len(frames))], size=(int(size[0]), int(size[1])),
                 full_frames=np.stack(frames) if keep_full else None)
