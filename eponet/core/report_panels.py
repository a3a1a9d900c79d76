"""Panels drawn for the HTML report of a run that did not save ``panels`` (from its masks, saliency, ED, frames)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .errors import EponetError
from .imaging import heat_map, overlay_mask
from .inputs import discover_sequences, iter_frames
from .io import natural_key, read_mask
from .outputs import ED_PANEL_FLOOR_PX, PANEL_HEIGHT, titled

__all__ = ["DrawnPanels", "draw_panels", "pick_frames"]

log = logging.getLogger(__name__)

#: The saved maps panels are drawn from: (folder in the sequence's folder, file pattern, name in the report).
_MAPS = (("masks", "*.png", "masks"), ("saliency", "*.png", "saliency"), ("ed", "*.npy", "ED"))


@dataclass
class DrawnPanels:
    """``images``: ``(stem, uint8 RGB (TITLE_HEIGHT + PANEL_HEIGHT, W, 3))`` per frame; ``maps``: the names of the
    maps they show; ``with_frames``: whether the input frames could be read (else the maps alone)."""

    images: list[tuple[str, np.ndarray]]
    maps: list[str]
    with_frames: bool


def pick_frames(stems: list, count: int) -> list:
    """``count`` of ``stems``, evenly spaced, first and last included (all of them when there are fewer).

    >>> pick_frames(["00000", "00001", "00002", "00003", "00004"], 3)
    ['00000', '00002', '00004']
    """
    if count >= len(stems):
        return list(stems)
    if count <= 1:
        return list(stems[:count])
    picks = np.round(np.linspace(0, len(stems) - 1, count)).astype(int)
    return [stems[k] for k in dict.fromkeys(picks.tolist())]


def draw_panels(folder: Path, inputs: dict, count: int) -> DrawnPanels | None:
    """Panels of ``count`` frames of the sequence in ``folder`` (a run's ``<output.dir>/<sequence>``): the input
    frame (read again from ``inputs``, the run's resolved ``input:`` section), the ED heat map (0 to the frame's own
    95th percentile, at least :data:`~eponet.core.outputs.ED_PANEL_FLOOR_PX`), saliency (0-1) and the mask over the
    frame, each titled as :func:`eponet.core.outputs.panel` titles its tiles; ``None`` when nothing was saved."""
    folder = Path(folder)
    saved = {what: {p.stem: p for p in (folder / what).glob(pattern)} for what, pattern, _ in _MAPS}
    stems = sorted(set().union(*saved.values()), key=natural_key)
    if not stems:
        return None
    chosen = pick_frames(stems, count)
    frames = _input_frames(inputs, folder.name, chosen)
    images = []
    for stem in chosen:
        image = _panel(frames.get(stem), *(saved[what].get(stem) for what, _, _ in _MAPS))
        if image is not None:
            images.append((stem, image))
    return DrawnPanels(images, [name for what, _, name in _MAPS if saved[what]], bool(frames))


def _panel(frame, mask_file, saliency_file, ed_file) -> np.ndarray | None:
    try:
        mask = read_mask(mask_file) if mask_file else None
        saliency = cv2.imread(str(saliency_file), cv2.IMREAD_GRAYSCALE) if saliency_file else None
        ed = np.load(ed_file) if ed_file else None
    except (EponetError, OSError, ValueError) as exc:
        log.warning("report: cannot read a saved map (%s)", exc)
        return None
    shape = next((m.shape[:2] for m in (mask, saliency, ed) if m is not None), None)
    if frame is not None and frame.shape[:2] != shape:
        frame = None  # the input changed since the run
    tiles = [(frame, "frame", False)] if frame is not None else []
    if ed is not None:
        top = max(ED_PANEL_FLOOR_PX, float(np.percentile(np.nan_to_num(ed), 95)))
        tiles.append((heat_map(ed, vmax=top), f"ED 0-{top:.1f} px", True))
    if saliency is not None:
        tiles.append((heat_map(saliency.astype(np.float32) / 255, vmax=1.0), "saliency 0-1", True))
    if mask is not None:
        tiles.append((overlay_mask(frame if frame is not None else np.zeros(mask.shape + (3,), np.uint8), mask), "mask",
                      False))
    if not tiles:
        return None
    return np.concatenate([titled(cv2.resize(tile, (max(1, round(tile.shape[1] * PANEL_HEIGHT / tile.shape[0])),
                                                    PANEL_HEIGHT), interpolation=cv2.INTER_AREA), title, color_bar=bar)
                           for tile, title, bar in tiles], axis=1)


def _input_frames(inputs: dict, name: str, stems: list[str]) -> dict[str, np.ndarray]:
    """The input frames ``stems`` of sequence ``name`` (uint8 RGB at the input size), ``{}`` when unreadable."""
    if not inputs.get("path"):
        return {}
    path, wanted, found = Path(inputs["path"]), set(stems), {}
    try:
        davis = (path / "JPEGImages").is_dir()
        sources = discover_sequences(path, sequences=[name] if davis else None,
                                     resolution=inputs.get("resolution") or "480p")
        source = next((s for s in sources if s.name == name), None)
        if source is None:
            return {}
        for stem, frame, _ in iter_frames(source, scale=1.0, max_frames=inputs.get("max_frames"), keep_full=False):
            if stem in wanted:
                found[stem] = frame
                if len(found) == len(wanted):
                    break
    except (EponetError, OSError, ValueError) as exc:
        log.warning("report: %s: input frames not readable (%s); panels without them", name, exc)
        return {}
    return found
