"""Training data: motion images and ground-truth masks of DAVIS-layout sequences, computed once and cached."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import cv2
import numpy as np

from eponet.core.cache import Cache
from eponet.core.errors import InputError
from eponet.core.inputs import discover_sequences, load_video
from eponet.core.io import list_images, read_mask
from eponet.core.pipeline import Pipeline
from eponet.core.spec import Spec

__all__ = ["SequenceData", "davis_masks", "load_motion_sequences"]

log = logging.getLogger(__name__)


@dataclass
class SequenceData:
    """One training sequence at the processing resolution: motion images float16 ``(F, 3, H, W)``, masks
    uint8 ``(F, H, W)`` in {0, 1}, RGB frames uint8 ``(F, H, W, 3)`` (for appearance models) and, when asked
    for, the appearance stage's features float16 ``(F, C, h, w)``."""

    name: str
    motion: np.ndarray
    masks: np.ndarray
    frames: np.ndarray
    features: np.ndarray | None = None


def davis_masks(root: Path, resolution: str, name: str, stems: list[str], shape: tuple[int, int]) -> np.ndarray:
    """Ground-truth masks of a DAVIS-layout sequence at ``shape`` ``(H, W)``.

    Reads ``Annotations/<resolution>/<name>/`` if it exists, else the largest annotation resolution present
    (DAVIS-2016 has 480p masks for 240p frames) and resizes by area averaging, foreground where >= 0.5.
    A missing mask file is an :class:`InputError` naming it.
    """
    folder = root / "Annotations" / resolution / name
    if not folder.is_dir():
        options = sorted((p for p in (root / "Annotations").glob(f"*/{name}") if p.is_dir()),
                         key=lambda p: -int("".join(c for c in p.parent.name if c.isdigit()) or 0))
        if not options:
            raise InputError(f"{root / 'Annotations'}: no annotations for sequence {name}")
        folder = options[0]
    by_stem = {p.stem: p for p in list_images(folder)}
    masks = np.empty((len(stems),) + tuple(shape), np.uint8)
    for t, stem in enumerate(stems):
        if stem not in by_stem:
            raise InputError(f"{folder / (stem + '.png')}: missing ground-truth mask for frame {stem}")
        mask = read_mask(by_stem[stem]).astype(np.float32)
        if mask.shape != tuple(shape):
            mask = cv2.resize(mask, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)
        masks[t] = mask >= 0.5
    return masks


def load_motion_sequences(geometry: Spec, root: Path, *, resolution: str, sequences: list[str] | None,
                          exclude: list[str] = (), cache: Cache | None = None, features: bool = False,
                          compute_order: Callable[[int], Sequence[int]] | None = None) -> list[SequenceData]:
    """Run the geometry stages of ``geometry`` (a validated spec with flow, trajectories and rigidity) on each
    DAVIS-layout sequence under ``root`` and pair the motion images with the ground-truth masks; with
    ``features``, also the appearance stage of ``geometry`` (computed once, through the cache).

    ``compute_order(count)`` is the order in which to compute the ``count`` sequences (under DDP: this process's
    share first, so that the processes fill the cache side by side); the list keeps the sequences' own order."""
    pipeline = Pipeline(geometry, cache=cache)
    sources = [s for s in discover_sequences(root, sequences=sequences, resolution=resolution) if s.name not in exclude]
    order = list(compute_order(len(sources))) if compute_order else range(len(sources))
    out: list[SequenceData | None] = [None] * len(sources)
    for i in order:
        source = sources[i]
        video = load_video(source, scale=geometry.input.scale, keep_full=False)
        result = pipeline.process(video)
        masks = davis_masks(Path(root), resolution, video.name, video.stems, video.shape)
        appearance = pipeline.appearance_features(video).astype(np.float16) if features else None
        out[i] = SequenceData(video.name, result.motion_images.astype(np.float16), masks, video.frames, appearance)
        log.info("%s: %d frames of motion images", video.name, video.num_frames)
    return out
