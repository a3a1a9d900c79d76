"""Writers for a sequence's outputs (masks, saliency, ED, flow, motion images, overlay, panels)."""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .errors import OutputError
from .imaging import flow_to_color, heat_map, overlay_mask, resize_flow, resize_map
from .io import atomic_path, save_npy, write_flo, write_mask_png
from .progress import track
from .types import FlowPair, Video

__all__ = ["SequenceOutputs", "write_sequence", "OVERLAY_FPS", "PANEL_HEIGHT"]

OVERLAY_FPS = 24
#: Height in pixels of each tile of ``panels/<frame>.png``.
PANEL_HEIGHT = 240


@dataclass
class SequenceOutputs:
    """What a sequence produced. Maps are at the processing resolution unless stated."""

    video: Video
    flow: FlowPair | None = None
    ed: np.ndarray | None = None  # (F, h, w) float32, pixels of the processing resolution
    motion_images: np.ndarray | None = None  # (F, 3, h, w) float32
    saliency: np.ndarray | None = None  # (F, H, W) float32 at the input size
    masks: np.ndarray | None = None  # (F, H, W) uint8 at the input size


def write_sequence(result: SequenceOutputs, out_dir: Path, save: tuple[str, ...]) -> Path:
    """Write what ``save`` lists into ``out_dir/<sequence>/`` atomically (a temporary folder, renamed at
    the end, replacing an earlier result)."""
    video = result.video
    out_dir = Path(out_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{video.name}.", suffix=".partial", dir=out_dir))
    except OSError as exc:
        raise OutputError(f"output.dir: cannot write to {out_dir} ({exc.strerror or exc})") from None
    try:
        _write_items(result, tmp, save)
        final = out_dir / video.name
        if final.exists():
            shutil.rmtree(final)
        tmp.rename(final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


def _write_items(result: SequenceOutputs, folder: Path, save: tuple[str, ...]) -> None:
    video = result.video
    size = video.size
    factor = size[1] / video.shape[1]  # processing px -> input px
    stems = video.stems
    for t in track(range(video.num_frames), desc=f"{video.name}: writing", total=video.num_frames):
        stem = stems[t]
        if "masks" in save:
            write_mask_png(folder / "masks" / f"{stem}.png", result.masks[t])
        if "saliency" in save:
            _write_png(folder / "saliency" / f"{stem}.png", np.round(np.clip(result.saliency[t], 0, 1) * 255).astype(np.uint8))
        if "ed" in save:
            save_npy(folder / "ed" / f"{stem}.npy", (resize_map(result.ed[t], size) * factor).astype(np.float32))
        if "motion_images" in save:
            save_npy(folder / "motion_images" / f"{stem}.npy", result.motion_images[t].astype(np.float32))
        if "flow" in save and t < video.num_frames - 1:
            write_flo(folder / "flow" / "forward" / f"{stem}.flo", resize_flow(result.flow.forward[t], size))
            write_flo(folder / "flow" / "backward" / f"{stem}.flo", resize_flow(result.flow.backward[t], size))
        if "panels" in save:
            _write_png(folder / "panels" / f"{stem}.png", _panel(result, t), rgb=True)
    if "overlay" in save:
        _write_overlay(folder / "overlay.mp4", video, result.masks)


def _write_png(path: Path, image: np.ndarray, rgb: bool = False) -> None:
    with atomic_path(path) as tmp:
        data = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if rgb else image
        ok, encoded = cv2.imencode(".png", data)
        if not ok:
            raise OutputError(f"{path}: PNG encoding failed")
        encoded.tofile(tmp)


def _panel(result: SequenceOutputs, t: int) -> np.ndarray:
    """Frame, flow in colour, ED heat map, saliency, mask side by side (like Fig. 4 of the paper)."""
    video = result.video
    frame = video.full_frames[t] if video.full_frames is not None else video.frames[t]
    tiles = [frame]
    if result.flow is not None:
        flow = result.flow.forward[min(t, len(result.flow.forward) - 1)]
        tiles.append(flow_to_color(flow if t < len(result.flow.forward) else -result.flow.backward[-1]))
    if result.ed is not None:
        tiles.append(heat_map(result.ed[t], vmax=float(np.percentile(result.ed, 99)) or None))
    if result.saliency is not None:
        tiles.append(heat_map(result.saliency[t], vmax=1.0))
    if result.masks is not None:
        tiles.append(overlay_mask(frame, result.masks[t]))
    height = min(PANEL_HEIGHT, frame.shape[0])
    resized = [cv2.resize(tile, (int(round(tile.shape[1] * height / tile.shape[0])), height), interpolation=cv2.INTER_AREA)
               for tile in tiles]
    return np.concatenate(resized, axis=1)


def _write_overlay(path: Path, video: Video, masks: np.ndarray) -> None:
    frames = video.full_frames if video.full_frames is not None else video.frames
    height, width = frames.shape[1:3]
    with atomic_path(path) as tmp:
        writer = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*"mp4v"), OVERLAY_FPS, (width, height))
        if not writer.isOpened():
            raise OutputError(f"{path}: OpenCV cannot open an mp4 writer")
        try:
            for frame, mask in zip(frames, masks):
                writer.write(cv2.cvtColor(overlay_mask(frame, mask), cv2.COLOR_RGB2BGR))
        finally:
            writer.release()
