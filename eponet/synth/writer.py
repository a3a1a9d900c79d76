"""Write synthetic clips in the DAVIS layout, with ground-truth flow, occlusions and cameras beside it.

Layout under the output folder (``<res>`` is ``<H>p``, e.g. ``240p``; frames are ``00000``, ``00001``, ...)::

    JPEGImages/<res>/<seq>/<frame>.jpg                 RGB frames
    Annotations/<res>/<seq>/<frame>.png                union of the objects, DAVIS palette, 0 = bg, 1 = fg
    Annotations_unsupervised/<res>/<seq>/<frame>.png   object ids as DAVIS-2017 unsupervised, 0 = bg, k = object k
    Flow/<res>/<seq>/forward/<frame>.flo               frame t -> t+1 on the grid of frame t (named after t)
    Flow/<res>/<seq>/backward/<frame>.flo              frame t+1 -> t on the grid of frame t+1 (named after t)
    Flow/<res>/<seq>/occlusions.npz                    forward, backward: bool (F-1, H, W), True where the
                                                       flow's target is hidden or outside the frame
    Cameras/<res>/<seq>.npz                            K (3, 3), R (F, 3, 3), t (F, 3) world-to-camera,
                                                       static_camera, [depth float32 (F, H, W), camera z]
    ImageSets/all.txt, ImageSets/train.txt             sequence names, one per line (DAVIS-2017 style; every
                                                       sequence is in the ``train`` set of db_info.yml)
    db_info.yml                                        DAVIS-style: attributes, num_frames, set, eval_t, year

Every file is written atomically, so an interrupted run never leaves a truncated file.
"""

from __future__ import annotations

import dataclasses
import logging
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Iterable

import numpy as np

from ..core.errors import OutputError
from ..core.io import atomic_path, atomic_write_bytes, write_flo, write_mask_png
from .clip import Clip, check_size, generate_clip
from .scene import SceneConfig
from .textures import folder_photos

__all__ = ["ATTRIBUTES", "check_writable", "frame_name", "resolution_name", "sequence_seed", "write_clip", "write_index",
           "write_dataset", "write_jpeg"]

log = logging.getLogger(__name__)

#: The DAVIS attributes this generator can assign (see :func:`eponet.synth.clip.clip_attributes`).
ATTRIBUTES = ("DB", "FM", "OCC", "OV")


def _eponet_version() -> str:
    try:
        from importlib.metadata import version

        return version("eponet")
    except Exception:  # not installed (e.g. run from a source tree)
        return "unknown"


def frame_name(t: int) -> str:
    return f"{t:05d}"


def resolution_name(height: int) -> str:
    return f"{height}p"


def sequence_seed(seed: int, index: int) -> int:
    """The clip seed of sequence ``index`` of a data set made with ``seed`` (independent of how many)."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1, np.uint64)[0] >> np.uint64(1))


def write_jpeg(path: Path, rgb: np.ndarray, quality: int) -> None:
    """Write RGB uint8 ``(H, W, 3)`` as a JPEG of ``quality`` (1-100), atomically."""
    import cv2

    ok, data = cv2.imencode(".jpg", rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise OutputError(f"{path}: JPEG encoding failed")
    atomic_write_bytes(path, data.tobytes())


def _write_npz(path: Path, compressed: bool, **arrays) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as handle:
            (np.savez_compressed if compressed else np.savez)(handle, **arrays)


def write_clip(
    out_dir: str | Path,
    name: str,
    clip: Clip,
    *,
    flow: bool = True,
    depth: bool = True,
    objects: bool = True,
    jpeg_quality: int = 90,
    on_frame=None,
) -> dict:
    """Write one clip as sequence ``name`` (see the module doc for the layout); return its ``db_info`` entry.

    ``flow=False`` skips the ``.flo`` files and occlusions, ``depth=False`` the depth in the camera file,
    ``objects=False`` the per-object id masks. ``on_frame`` is called once per frame written.
    """
    out = Path(out_dir)
    H = clip.frames.shape[1]
    res = resolution_name(H)
    F = clip.num_frames
    for t in range(F):
        stem = frame_name(t)
        write_jpeg(out / "JPEGImages" / res / name / f"{stem}.jpg", clip.frames[t], jpeg_quality)
        write_mask_png(out / "Annotations" / res / name / f"{stem}.png", clip.masks[t])
        if objects:
            write_mask_png(out / "Annotations_unsupervised" / res / name / f"{stem}.png", clip.object_ids[t])
        if flow and t < F - 1:
            base = out / "Flow" / res / name
            write_flo(base / "forward" / f"{stem}.flo", clip.forward[t])
            write_flo(base / "backward" / f"{stem}.flo", clip.backward[t])
        if on_frame is not None:
            on_frame()
    if flow:
        _write_npz(out / "Flow" / res / name / "occlusions.npz", True, forward=clip.occlusion_forward, backward=clip.occlusion_backward)
    arrays = dict(K=clip.K, R=clip.R, t=clip.t, static_camera=np.array(clip.static_camera))
    if depth:
        arrays["depth"] = clip.depth
    # depth barely compresses (float32) and zlib would cost more than rendering: stored uncompressed
    _write_npz(out / "Cameras" / res / f"{name}.npz", False, **arrays)
    return {
        "name": name,
        "attributes": list(clip.attributes),
        "num_frames": F,
        "set": "train",
        "eval_t": True,
        "year": 2016,
        "static_camera": bool(clip.static_camera),
        "num_objects": int(clip.num_objects),
        "seed": None if clip.seed is None else int(clip.seed),
    }


def write_index(out_dir: str | Path, entries: Iterable[dict], *, extra: dict | None = None) -> None:
    """Write ``ImageSets/all.txt``, ``ImageSets/train.txt`` and a DAVIS-style ``db_info.yml`` listing ``entries`` (from
    :func:`write_clip`). ``year: 2016`` marks DAVIS-2016-style binary annotations; ``extra`` goes under the
    ``generator`` key (seed, size, settings, version) so the data set records how it was made."""
    import yaml

    out = Path(out_dir)
    entries = list(entries)
    names = "".join(f"{e['name']}\n" for e in entries).encode()
    atomic_write_bytes(out / "ImageSets" / "all.txt", names)
    atomic_write_bytes(out / "ImageSets" / "train.txt", names)
    info = {
        "attributes": list(ATTRIBUTES),
        "sets": ["train"],
        "years": [2016],
        "sequences": entries,
    }
    if extra:
        info["generator"] = extra
    atomic_write_bytes(out / "db_info.yml", yaml.safe_dump(info, sort_keys=False).encode())


def check_writable(out: Path) -> None:
    """Create the folder ``out`` if needed and check that files can be written in it (:class:`OutputError` if not)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{out}: cannot create the output folder ({exc.strerror or exc})") from None
    if not out.is_dir():
        raise OutputError(f"{out}: the output path exists and is not a folder")
    probe = out / ".eponet-write-test"
    try:
        atomic_write_bytes(probe, b"")
        probe.unlink()
    except OSError as exc:
        raise OutputError(f"{out}: the output folder is not writable ({exc.strerror or exc})") from None


def write_dataset(
    out_dir: str | Path,
    sequences: int,
    frames: int,
    size: tuple[int, int],
    seed: int,
    backgrounds: str | Path | None = None,
    config: SceneConfig | None = None,
    progress: bool = True,
    *,
    flow: bool = True,
    depth: bool = True,
    jpeg_quality: int = 90,
) -> list[dict]:
    """Generate ``sequences`` clips of ``frames`` frames at ``size = (W, H)`` and write them in the DAVIS
    layout under ``out_dir`` (sequences ``rbsf-0000``, ...). Deterministic: the same arguments give
    bit-identical files. ``backgrounds``: a folder of photographs for the background surfaces. Returns the
    ``db_info`` entries.
    """
    from tqdm import tqdm

    from eponet.core.progress import progress_enabled

    W, H = check_size(size)
    if isinstance(sequences, bool) or not isinstance(sequences, (int, np.integer)) or sequences < 1:
        raise ValueError(f"sequences: expected a positive integer, got {sequences!r}")
    if not (1 <= int(jpeg_quality) <= 100):
        raise ValueError(f"jpeg_quality: expected 1..100, got {jpeg_quality!r}")
    config = config or SceneConfig()
    if backgrounds is not None:
        config = dataclasses.replace(config, backgrounds=str(Path(backgrounds).resolve()))
    if config.backgrounds is not None:
        folder_photos(config.backgrounds)  # fail early on an empty or missing folder
    out = Path(out_dir)
    check_writable(out)

    entries = []
    # files of clip i are encoded and written on a second thread while clip i+1 is rendered (encoders and
    # file writes release the GIL); the files do not depend on the timing
    with tqdm(total=int(sequences) * int(frames), disable=not progress or not progress_enabled(), unit="frame", desc="make-rbsf") as bar, \
            ThreadPoolExecutor(max_workers=1, thread_name_prefix="make-rbsf-writer") as pool:
        pending = None
        for index in range(int(sequences)):
            name = f"rbsf-{index:04d}"
            clip_seed = sequence_seed(seed, index)
            clip = generate_clip(clip_seed, frames, (W, H), config)
            if pending is not None:
                entries.append(pending.result())  # at most one clip waits, so memory stays bounded
            pending = pool.submit(
                write_clip, out, name, clip, flow=flow, depth=depth, jpeg_quality=jpeg_quality, on_frame=bar.update
            )
            log.debug("generated %s (seed %d, attributes %s)", name, clip_seed, clip.attributes)
        entries.append(pending.result())
    settings = {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}
    settings = {k: (list(v) if isinstance(v, tuple) else v) for k, v in settings.items()}
    write_index(
        out,
        entries,
        extra={"name": "eponet make-rbsf", "version": _eponet_version(), "seed": int(seed), "size": [W, H], "frames": int(frames), "config": settings},
    )
    return entries
