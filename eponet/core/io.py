"""File formats: frames, videos, Middlebury ``.flo``, DAVIS palette PNG masks, atomic writes."""

from __future__ import annotations

import contextlib
import errno
import os
import re
import tempfile
from pathlib import Path
from typing import Iterator

import numpy as np

from .errors import InputError, OutputError

__all__ = [
    "IMAGE_SUFFIXES",
    "VIDEO_SUFFIXES",
    "LIST_SUFFIXES",
    "is_pattern",
    "FLO_TAG",
    "DAVIS_PALETTE",
    "natural_key",
    "list_images",
    "read_image",
    "read_mask",
    "write_mask_png",
    "read_flo",
    "write_flo",
    "atomic_path",
    "honour_umask",
    "atomic_write_bytes",
    "save_npy",
    "NO_SPACE_ERRNOS",
    "is_no_space",
    "no_space_error",
]

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".ppm", ".pgm", ".tif", ".tiff")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")
#: ``input.path`` as a text file with one of these suffixes lists a corpus: one video file or frame folder a line,
#: relative to the list's folder (blank lines and lines starting with ``#`` are skipped).
LIST_SUFFIXES = (".txt",)
FLO_TAG = 202021.25
#: Flow values at or above this magnitude mean "unknown" in the Middlebury format.
FLO_UNKNOWN = 1e9


def _davis_palette() -> np.ndarray:
    """The DAVIS palette (256 RGB triples; index 1 = (128, 0, 0)), as shipped with the DAVIS toolkit."""
    return np.loadtxt(Path(__file__).resolve().parent.parent / "data" / "davis_palette.txt", dtype=np.uint8)


DAVIS_PALETTE = _davis_palette()


def is_pattern(path: str | Path) -> bool:
    """Whether ``input.path`` is a glob (it holds ``*``, ``?`` or ``[``) rather than one file or folder."""
    return any(char in str(path) for char in "*?[")


def natural_key(name: str) -> list:
    """Sort key that orders ``frame2`` before ``frame10``."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name)]


def list_images(folder: str | Path) -> list[Path]:
    """Image files directly inside ``folder`` in natural order."""
    folder = Path(folder)
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
    return sorted(files, key=lambda p: natural_key(p.name))


def read_image(path: str | Path) -> np.ndarray:
    """Read an image as uint8 RGB ``(H, W, 3)``; a corrupt or unreadable file is an :class:`InputError`."""
    import cv2

    path = Path(path)
    data = np.fromfile(str(path), np.uint8) if path.is_file() else None
    image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data is not None and data.size else None
    if image is None:
        raise InputError(f"{path}: cannot read image (missing, empty or corrupt file)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def read_mask(path: str | Path, *, keep_labels: bool = False) -> np.ndarray:
    """Read a mask PNG of any flavour as uint8 ``(H, W)``.

    Grey, grey+alpha, RGB and palette PNGs, 0/255 or 0/1 are all read correctly. With ``keep_labels=False``
    the result is binary {0, 1} (anything non-zero is foreground); with ``keep_labels=True`` palette indices
    (or grey levels) are kept as object ids, e.g. for DAVIS-2017 (255 = void).
    """
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    try:
        with Image.open(path) as image:
            image.load()
            if image.mode == "P":
                labels = np.asarray(image, dtype=np.uint8)
            elif image.mode in ("L", "LA", "I", "I;16", "1"):
                labels = np.asarray(image.convert("L") if image.mode != "1" else image.convert("L"), dtype=np.uint8)
            else:
                rgb = np.asarray(image.convert("RGB"), dtype=np.uint8)
                if keep_labels:
                    # map each distinct non-black colour to an id in order of first palette appearance
                    flat = rgb.reshape(-1, 3).astype(np.int64)
                    code = (flat[:, 0] << 16) | (flat[:, 1] << 8) | flat[:, 2]
                    pal = DAVIS_PALETTE.astype(np.int64)
                    pal_code = (pal[:, 0] << 16) | (pal[:, 1] << 8) | pal[:, 2]
                    lookup = {int(c): i for i, c in enumerate(pal_code)}
                    uniq, inv = np.unique(code, return_inverse=True)
                    ids = np.array([lookup.get(int(c), k + 1 if c else 0) for k, c in enumerate(uniq)], np.uint8)
                    labels = ids[inv].reshape(rgb.shape[:2])
                else:
                    labels = (rgb.max(axis=2) > 0).astype(np.uint8)
    except (OSError, UnidentifiedImageError, ValueError) as exc:
        raise InputError(f"{path}: cannot read mask ({exc.__class__.__name__}: {exc})") from None
    if keep_labels:
        return labels
    return (labels > 0).astype(np.uint8)


def write_mask_png(path: str | Path, mask: np.ndarray) -> None:
    """Write uint8 labels ``(H, W)`` (0 = background, 1 = foreground, ...) as an indexed PNG with the DAVIS
    palette, atomically."""
    from PIL import Image

    if mask.ndim != 2:
        raise ValueError(f"mask: expected (H, W), got shape {mask.shape}")
    image = Image.fromarray(np.asarray(mask, np.uint8), mode="P")
    image.putpalette(DAVIS_PALETTE.reshape(-1).tolist())
    with atomic_path(path) as tmp:
        image.save(tmp, format="PNG")


def read_flo(path: str | Path, expected_shape: tuple[int, int] | None = None) -> np.ndarray:
    """Read a Middlebury ``.flo`` file as float32 ``(H, W, 2)``; unknown values (>= 1e9) become NaN.

    ``expected_shape`` ``(H, W)``, if given, must match. Errors name the file.
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: cannot read flow file ({exc.strerror or exc})") from None
    if len(raw) < 12:
        raise InputError(f"{path}: not a .flo file (only {len(raw)} bytes)")
    tag = np.frombuffer(raw, "<f4", 1, 0)[0]
    width, height = (int(v) for v in np.frombuffer(raw, "<i4", 2, 4))
    if tag != np.float32(FLO_TAG):
        raise InputError(f"{path}: not a .flo file (bad tag {tag!r}, expected {FLO_TAG})")
    if not (1 <= width <= 99999 and 1 <= height <= 99999):
        raise InputError(f"{path}: .flo header has an invalid size {width}x{height}")
    need = 12 + width * height * 8
    if len(raw) != need:
        raise InputError(f"{path}: .flo file is truncated or padded ({len(raw)} bytes, expected {need} for {width}x{height})")
    flow = np.frombuffer(raw, "<f4", width * height * 2, 12).reshape(height, width, 2).astype(np.float32)
    if expected_shape is not None and (height, width) != tuple(expected_shape):
        raise InputError(f"{path}: flow is {width}x{height}, expected {expected_shape[1]}x{expected_shape[0]} (the frame size)")
    unknown = np.abs(flow) >= FLO_UNKNOWN
    if unknown.any():
        flow[unknown.any(axis=2)] = np.nan
    return flow


def write_flo(path: str | Path, flow: np.ndarray) -> None:
    """Write float ``(H, W, 2)`` flow as Middlebury ``.flo`` (NaN written as the 'unknown' value 1e10)."""
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ValueError(f"flow: expected (H, W, 2), got shape {flow.shape}")
    height, width = flow.shape[:2]
    data = np.where(np.isfinite(flow), flow, 1e10).astype("<f4")
    header = np.array([FLO_TAG], "<f4").tobytes() + np.array([width, height], "<i4").tobytes()
    atomic_write_bytes(path, header + data.tobytes())


_UMASK = os.umask(0)
os.umask(_UMASK)


def honour_umask(path: str | Path) -> None:
    """Give a file or folder made by :mod:`tempfile` (0600 / 0700) the permissions the umask gives new ones."""
    os.chmod(path, (0o777 if os.path.isdir(path) else 0o666) & ~_UMASK)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[str]:
    """Yield a temporary file name beside ``path``; on success rename it onto ``path``, else remove it."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".tmp" + path.suffix, dir=path.parent)
        os.close(fd)
        honour_umask(tmp)
    except OSError as exc:
        raise OutputError(f"{path.parent}: cannot write output ({exc.strerror or exc})", errno=exc.errno) from None
    try:
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


#: ``errno`` values of a write that failed because the disk (or the user's quota) is full.
NO_SPACE_ERRNOS = (errno.ENOSPC, errno.EDQUOT)


def is_no_space(exc: BaseException) -> bool:
    """Whether ``exc`` (an ``OSError``, PyAV's error or an :class:`OutputError`) says the disk is full."""
    return getattr(exc, "errno", None) in NO_SPACE_ERRNOS


def no_space_error(out_dir: str | Path, doing: str) -> OutputError:
    """The one line of a full output disk, naming ``out_dir`` and what was being written (``doing``).

    >>> print(no_space_error("runs/dog", "writing dog frame 00012"))
    runs/dog: no space left on the output disk (writing dog frame 00012); free some space or set output.dir to another disk and run again (finished sequences are kept and skipped)
    """
    return OutputError(f"{out_dir}: no space left on the output disk ({doing}); free some space or set output.dir to "
                       "another disk and run again (finished sequences are kept and skipped)", errno=errno.ENOSPC)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temp file, then rename)."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            handle.write(data)


def save_npy(path: str | Path, array: np.ndarray) -> None:
    """``np.save`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            np.save(handle, array)
