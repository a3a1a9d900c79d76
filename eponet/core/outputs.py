"""Writers for a sequence's outputs (masks, saliency, ED, flow, motion images, overlay, panels)."""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .errors import OutputError
from .imaging import flow_to_color, heat_map, overlay_mask, resize_flow, resize_map
from .motion import ED_TARGET
from .io import atomic_path, honour_umask, save_npy, write_flo, write_mask_png
from .progress import track
from .types import FlowPair, Video

__all__ = ["SequenceOutputs", "SequenceWriter", "write_sequence", "remove_partials", "OVERLAY_FPS", "PANEL_HEIGHT"]

OVERLAY_FPS = 24
#: Height in pixels of each tile of ``panels/<frame>.png``.
PANEL_HEIGHT = 240


@dataclass
class SequenceOutputs:
    """What a sequence produced, whole (:meth:`eponet.core.pipeline.Pipeline.process`). Maps are at the
    processing resolution unless stated."""

    video: Video
    flow: FlowPair | None = None
    ed: np.ndarray | None = None  # (F, h, w) float32, pixels of the processing resolution
    motion_images: np.ndarray | None = None  # (F, 3, h, w) float32
    saliency: np.ndarray | None = None  # (F, H, W) float32 at the input size
    masks: np.ndarray | None = None  # (F, H, W) uint8 at the input size


class SequenceWriter:
    """Writes a sequence's outputs frame by frame as the frames complete, each file atomically, into a hidden
    ``out_dir/.<name>.*.partial`` folder that :meth:`close` renames to ``out_dir/<name>`` (replacing an earlier
    result) and :meth:`abort` removes: a sequence folder under ``output.dir`` is always complete.

    The ED panel of a frame is scaled by the ED scale of the frames around it (the motion net's, the 95th
    percentile over :data:`eponet.core.motion.ED_WINDOW` frames), not by the whole video's.
    """

    def __init__(self, out_dir: Path, name: str, save: tuple[str, ...], size: tuple[int, int], shape: tuple[int, int]):
        self.out_dir, self.name, self.save = Path(out_dir), name, tuple(save)
        self.size, self.shape = size, shape
        self.factor = size[1] / shape[1]  # processing px -> input px
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            self.folder = Path(tempfile.mkdtemp(prefix=f".{name}.", suffix=".partial", dir=self.out_dir))
            honour_umask(self.folder)  # it becomes the sequence's folder
        except OSError as exc:
            raise OutputError(f"output.dir: cannot write to {self.out_dir} ({exc.strerror or exc})") from None
        self._overlay = None
        self._overlay_tmp = None
        self._previous = None  # the frame before, for the last frame's flow files (none: F-1 pairs)

    def write(self, item) -> None:
        """Write the outputs of one finished frame (a :class:`eponet.core.stream.FrameItem`)."""
        folder, save, stem, size = self.folder, self.save, item.stem, self.size
        try:
            if "masks" in save:
                write_mask_png(folder / "masks" / f"{stem}.png", item.mask)
            if "saliency" in save:
                _write_png(folder / "saliency" / f"{stem}.png", np.round(np.clip(item.probability, 0, 1) * 255).astype(np.uint8))
            if "ed" in save:
                save_npy(folder / "ed" / f"{stem}.npy", (resize_map(item.ed, size) * self.factor).astype(np.float32))
            if "motion_images" in save:
                save_npy(folder / "motion_images" / f"{stem}.npy", item.motion_image.astype(np.float32))
            if "flow" in save and item.forward is not None:
                write_flo(folder / "flow" / "forward" / f"{stem}.flo", resize_flow(item.forward, size))
                write_flo(folder / "flow" / "backward" / f"{stem}.flo", resize_flow(item.backward, size))
            if "panels" in save:
                _write_png(folder / "panels" / f"{stem}.png", _panel(item), rgb=True)
            if "overlay" in save:
                self._write_overlay_frame(item)
        except OSError as exc:  # e.g. the disk is full
            raise OutputError(f"{folder.parent / self.name}: cannot write frame {stem} ({exc.strerror or exc})") from None

    def _write_overlay_frame(self, item) -> None:
        frame = item.full if item.full is not None else item.frame
        if self._overlay is None:
            self._overlay_tmp = self.folder / ".overlay.tmp.mp4"
            height, width = frame.shape[:2]
            self._overlay = cv2.VideoWriter(str(self._overlay_tmp), cv2.VideoWriter_fourcc(*"mp4v"), OVERLAY_FPS,
                                            (width, height))
            if not self._overlay.isOpened():
                raise OutputError(f"{self.folder.parent / self.name / 'overlay.mp4'}: OpenCV cannot open an mp4 writer")
        self._overlay.write(cv2.cvtColor(overlay_mask(frame, item.mask), cv2.COLOR_RGB2BGR))

    def close(self) -> Path:
        """Finish the sequence: the folder becomes ``out_dir/<name>``."""
        try:
            if self._overlay is not None:
                self._overlay.release()
                os.replace(self._overlay_tmp, self.folder / "overlay.mp4")
                self._overlay = None
            final = self.out_dir / self.name
            if final.exists():
                shutil.rmtree(final)
            self.folder.rename(final)
        except OSError as exc:
            self.abort()
            raise OutputError(f"{self.out_dir / self.name}: cannot finish the outputs ({exc.strerror or exc})") from None
        return final

    def abort(self) -> None:
        if self._overlay is not None:
            self._overlay.release()
            self._overlay = None
        shutil.rmtree(self.folder, ignore_errors=True)


def remove_partials(out_dir: Path) -> None:
    """Remove what runs that were killed left half-written: ``.<name>.*.partial`` folders and temp files of the
    run record (``.run.*.tmp.json``)."""
    out_dir = Path(out_dir)
    if out_dir.is_dir():
        for path in out_dir.glob(".*.partial"):
            shutil.rmtree(path, ignore_errors=True)
        for path in out_dir.glob(".run.*.tmp.json"):
            path.unlink(missing_ok=True)


def write_sequence(result: SequenceOutputs, out_dir: Path, save: tuple[str, ...]) -> Path:
    """Write a whole :class:`SequenceOutputs` (what :meth:`~eponet.core.pipeline.Pipeline.process` returns)
    through a :class:`SequenceWriter`."""
    from .motion import ed_scales
    from .stream import FrameItem

    video = result.video
    writer = SequenceWriter(out_dir, video.name, save, video.size, video.shape)
    scales = ed_scales(result.ed) if result.ed is not None else None
    try:
        for t in track(range(video.num_frames), desc=f"{video.name}: writing", total=video.num_frames):
            last = t == video.num_frames - 1
            item = FrameItem(t, video.stems[t], video.frames[t],
                             video.full_frames[t] if video.full_frames is not None else None)
            if result.flow is not None:
                item.forward = None if last else result.flow.forward[t]
                item.backward = None if last else result.flow.backward[t]
                item.motion_flow = -result.flow.backward[-1] if last else result.flow.forward[t]
            if result.ed is not None:
                item.ed, item.ed_scale = result.ed[t], float(scales[t])
            if result.motion_images is not None:
                item.motion_image = result.motion_images[t]
            if result.saliency is not None:
                item.probability = result.saliency[t]
            if result.masks is not None:
                item.mask = result.masks[t]
            writer.write(item)
        return writer.close()
    except BaseException:
        writer.abort()
        raise


def _write_png(path: Path, image: np.ndarray, rgb: bool = False) -> None:
    with atomic_path(path) as tmp:
        data = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if rgb else image
        ok, encoded = cv2.imencode(".png", data)
        if not ok:
            raise OutputError(f"{path}: PNG encoding failed")
        encoded.tofile(tmp)


def _panel(item) -> np.ndarray:
    """Frame, flow in colour, ED heat map, saliency, mask side by side (like Fig. 4 of the paper)."""
    frame = item.full if item.full is not None else item.frame
    tiles = [frame]
    if item.motion_flow is not None:
        tiles.append(flow_to_color(item.motion_flow))
    if item.ed is not None:
        tiles.append(heat_map(item.ed, vmax=(item.ed_scale / ED_TARGET) if item.ed_scale else None))
    if item.probability is not None:
        tiles.append(heat_map(item.probability, vmax=1.0))
    if item.mask is not None:
        tiles.append(overlay_mask(frame, item.mask))
    height = min(PANEL_HEIGHT, frame.shape[0])
    resized = [cv2.resize(tile, (int(round(tile.shape[1] * height / tile.shape[0])), height), interpolation=cv2.INTER_AREA)
               for tile in tiles]
    return np.concatenate(resized, axis=1)
