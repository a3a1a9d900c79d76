"""Writers for a sequence's outputs (masks, saliency, ED, flow, motion images, overlay, panels)."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np

from .errors import OutputError
from .imaging import flow_to_color, heat_map, overlay_mask, resize_flow, resize_map
from .io import atomic_path, honour_umask, is_no_space, no_space_error, save_npy, write_flo, write_mask_png
from .progress import track
from .types import FlowPair, Video

__all__ = ["SequenceOutputs", "SequenceWriter", "write_sequence", "remove_partials", "ed_at_input_size", "panel",
           "titled", "even_size",
           "OVERLAY_FPS", "PANEL_HEIGHT", "TITLE_HEIGHT", "ED_PANEL_FLOOR_PX"]

#: Frame rate of ``overlay.mp4`` when neither ``output.fps`` nor a video file's header gives one (frame folders).
OVERLAY_FPS = 24.0
#: Height in pixels of each tile of ``panels/<frame>.png`` (below its title strip).
PANEL_HEIGHT = 240
#: Height in pixels of the title strip above each panel tile.
TITLE_HEIGHT = 22
#: The ED tile's colour scale reaches at least this many pixels (of the input frame): a static clip's ED, flow
#: noise below 1 px, stays in the darkest third of the colours instead of being stretched to full range.
ED_PANEL_FLOOR_PX = 3.0


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

    ``overlay.mp4`` is H.264 (yuv420p, what browsers play) at ``fps`` (default :data:`OVERLAY_FPS`); see
    :func:`panel` for the panels.
    """

    def __init__(self, out_dir: Path, name: str, save: tuple[str, ...], size: tuple[int, int], shape: tuple[int, int],
                 *, fps: float | None = None):
        self.out_dir, self.name, self.save = Path(out_dir), name, tuple(save)
        self.size, self.shape, self.fps = size, shape, float(fps or OVERLAY_FPS)
        self.factor = size[1] / shape[1]  # processing px -> input px
        try:
            self.out_dir.mkdir(parents=True, exist_ok=True)
            self.folder = Path(tempfile.mkdtemp(prefix=f".{name}.", suffix=".partial", dir=self.out_dir))
            honour_umask(self.folder)  # it becomes the sequence's folder
        except OSError as exc:
            if is_no_space(exc):
                raise no_space_error(self.out_dir, f"starting {name}") from None
            raise OutputError(f"output.dir: cannot write to {self.out_dir} ({exc.strerror or exc})") from None
        self._overlay = None  # PyAV's (container, stream, VideoFrame), from the first overlay frame
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
                save_npy(folder / "ed" / f"{stem}.npy", ed_at_input_size(item.ed, size))
            if "motion_images" in save:
                save_npy(folder / "motion_images" / f"{stem}.npy", item.motion_image.astype(np.float32))
            if "flow" in save and item.forward is not None:
                write_flo(folder / "flow" / "forward" / f"{stem}.flo", resize_flow(item.forward, size))
                write_flo(folder / "flow" / "backward" / f"{stem}.flo", resize_flow(item.backward, size))
            if "panels" in save:
                _write_png(folder / "panels" / f"{stem}.png", panel(item, factor=self.factor), rgb=True)
            if "overlay" in save:
                self._write_overlay_frame(item)
        except (OSError, OutputError, *_ffmpeg_errors()) as exc:
            if is_no_space(exc):
                raise no_space_error(self.out_dir, f"writing {self.name} frame {stem}") from None
            if isinstance(exc, OutputError):
                raise
            raise OutputError(f"{folder.parent / self.name}: cannot write frame {stem} ({_reason(exc)})") from None

    def _write_overlay_frame(self, item) -> None:
        frame = even_size(overlay_mask(item.full if item.full is not None else item.frame, item.mask))
        if self._overlay is None:
            import av  # PyAV (FFmpeg) only for the overlay video: ~70 ms of start-up that other runs skip

            self._overlay_tmp = self.folder / ".overlay.tmp.mp4"
            container = av.open(str(self._overlay_tmp), "w")
            # the rate as a fraction: NTSC's 29.97 is 30000/1001
            stream = container.add_stream("libx264", rate=Fraction(self.fps).limit_denominator(1001))
            stream.height, stream.width = frame.shape[:2]
            stream.pix_fmt = "yuv420p"
            self._overlay = (container, stream, av.VideoFrame)
        container, stream, video_frame = self._overlay
        container.mux(stream.encode(video_frame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")))

    def _close_overlay(self, finish: bool) -> None:
        container, stream, _ = self._overlay
        self._overlay = None
        try:
            if finish:
                container.mux(stream.encode(None))  # flush the encoder's delayed frames
        finally:
            container.close()

    def close(self) -> Path:
        """Finish the sequence: the folder becomes ``out_dir/<name>``."""
        try:
            if self._overlay is not None:
                self._close_overlay(finish=True)
                os.replace(self._overlay_tmp, self.folder / "overlay.mp4")
            final = self.out_dir / self.name
            if final.exists():
                shutil.rmtree(final)
            self.folder.rename(final)
        except (OSError, *_ffmpeg_errors()) as exc:
            self.abort()
            if is_no_space(exc):
                raise no_space_error(self.out_dir, f"finishing {self.name}") from None
            raise OutputError(f"{self.out_dir / self.name}: cannot finish the outputs ({_reason(exc)})") from None
        return final

    def abort(self) -> None:
        if self._overlay is not None:
            try:
                self._close_overlay(finish=False)
            except (OSError, *_ffmpeg_errors()):
                pass  # the folder goes anyway
        shutil.rmtree(self.folder, ignore_errors=True)


def _ffmpeg_errors() -> tuple[type[Exception], ...]:
    """PyAV's error class once the overlay writer has imported it (none can be raised before)."""
    return (sys.modules["av"].FFmpegError,) if "av" in sys.modules else ()


def ed_at_input_size(ed: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """An ED map ``(h, w)`` in processing pixels at the input ``size`` ``(H, W)``, in input pixels (float32): what
    the ``ed/`` files hold."""
    return (resize_map(ed, size) * (size[1] / ed.shape[1])).astype(np.float32)


def remove_partials(out_dir: Path) -> None:
    """Remove what runs that were killed left half-written: ``.<name>.*.partial`` folders and temp files of the
    run record (``.run.*.tmp.json``)."""
    out_dir = Path(out_dir)
    if out_dir.is_dir():
        for path in out_dir.glob(".*.partial"):
            shutil.rmtree(path, ignore_errors=True)
        for path in out_dir.glob(".run.*.tmp.json"):
            path.unlink(missing_ok=True)


def write_sequence(result: SequenceOutputs, out_dir: Path, save: tuple[str, ...], *, fps: float | None = None) -> Path:
    """Write a whole :class:`SequenceOutputs` (what :meth:`~eponet.core.pipeline.Pipeline.process` returns)
    through a :class:`SequenceWriter` (``overlay.mp4`` at ``fps``, default :data:`OVERLAY_FPS`)."""
    from .motion import ed_scales
    from .stream import FrameItem

    video = result.video
    writer = SequenceWriter(out_dir, video.name, save, video.size, video.shape, fps=fps)
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


def _reason(exc: Exception) -> str:
    return str(getattr(exc, "strerror", None) or exc)  # OSError and PyAV's FFmpegError have a strerror


def _write_png(path: Path, image: np.ndarray, rgb: bool = False) -> None:
    with atomic_path(path) as tmp:
        data = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if rgb else image
        ok, encoded = cv2.imencode(".png", data)
        if not ok:
            raise OutputError(f"{path}: PNG encoding failed")
        encoded.tofile(tmp)


def panel(item, *, factor: float = 1.0) -> np.ndarray:
    """Frame, flow in colour, ED heat map, saliency, mask side by side (like Fig. 4 of the paper), each tile
    :data:`PANEL_HEIGHT` px high under a title naming the quantity and its scale (``factor``: input px per
    processing px, so that scales are in pixels of the input frame, as ``flow/`` and ``ed/`` are).

    - flow: hue is the direction, saturation the magnitude, full at the frame's 99th percentile (``flow max 12.0 px``);
    - ED: 0 to ``max(ED_PANEL_FLOOR_PX, s)`` px (``ED 0-4.2 px`` with a colour bar), ``s`` the 95th percentile of
      the ED of the frames around it (the motion net's scale, ``item.ed_scale``; else the frame's own): absolute
      pixels, so a static clip (ED below 1 px) stays dark and a moving object (several px) is bright;
    - saliency: 0-1 (colour bar); mask: tinted over the frame.
    """
    frame = item.full if item.full is not None else item.frame
    tiles = [(frame, "frame", False)]
    if item.motion_flow is not None:
        magnitude = np.hypot(item.motion_flow[..., 0], item.motion_flow[..., 1])
        top = max(float(np.percentile(magnitude, 99)), 1e-6)
        tiles.append((flow_to_color(item.motion_flow, max_magnitude=top), f"flow max {top * factor:.1f} px", False))
    if item.ed is not None:
        ed = np.nan_to_num(item.ed) * factor
        scale = item.ed_scale * factor if item.ed_scale else float(np.percentile(ed, 95))
        top = max(ED_PANEL_FLOOR_PX, scale)
        tiles.append((heat_map(ed, vmax=top), f"ED 0-{top:.1f} px", True))
    if item.probability is not None:
        tiles.append((heat_map(item.probability, vmax=1.0), "saliency 0-1", True))
    if item.mask is not None:
        tiles.append((overlay_mask(frame, item.mask), "mask", False))
    height = PANEL_HEIGHT
    return np.concatenate([titled(cv2.resize(tile, (max(1, int(round(tile.shape[1] * height / tile.shape[0]))), height),
                                             interpolation=cv2.INTER_AREA), title, color_bar=bar)
                           for tile, title, bar in tiles], axis=1)


def titled(tile: np.ndarray, title: str, *, color_bar: bool = False) -> np.ndarray:
    """Tile ``(H, W, 3)`` uint8 RGB under a black strip of :data:`TITLE_HEIGHT` px: ``title`` in white (shrunk to
    fit the width) and, with ``color_bar``, :func:`~eponet.core.imaging.heat_map`'s colours from 0 (left) to the
    top of the scale (right) under it. Returns ``(TITLE_HEIGHT + H, W, 3)``."""
    width = tile.shape[1]
    strip = np.zeros((TITLE_HEIGHT, width, 3), np.uint8)
    font, scale = cv2.FONT_HERSHEY_SIMPLEX, 0.42
    (text_width, _), _ = cv2.getTextSize(title, font, scale, 1)
    scale *= min(1.0, (width - 6) / max(text_width, 1))
    cv2.putText(strip, title, (3, 12 if color_bar else 15), font, scale, (255, 255, 255), 1, cv2.LINE_AA)
    if color_bar and width > 6:
        strip[15:20, 3:width - 3] = heat_map(np.tile(np.linspace(0, 1, width - 6, dtype=np.float32), (5, 1)), vmax=1.0)
    return np.concatenate([strip, tile])


def even_size(frame: np.ndarray) -> np.ndarray:
    """Frame ``(H, W, C)`` padded to even sides by copying its last row / column (H.264 in yuv420p, which browsers
    play, needs even sizes): a frame of 65x49 px becomes 66x50."""
    height, width = frame.shape[:2]
    if height % 2 == 0 and width % 2 == 0:
        return frame
    return cv2.copyMakeBorder(frame, 0, height % 2, 0, width % 2, cv2.BORDER_REPLICATE)
