"""Helpers for the evaluation tests: mask writers in every PNG flavour and synthetic DAVIS-style trees."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from eponet.core.io import DAVIS_PALETTE


def save_mask(path: Path, mask: np.ndarray, flavour: str = "grey255") -> Path:
    """Write a binary or label mask as a PNG of the given flavour.

    ``grey255`` (0/255 grey), ``grey01`` (0/1 grey), ``rgb`` (white on black), ``palette`` (DAVIS palette,
    labels kept), ``greyalpha`` (grey + alpha, as DAVIS-2016 ``bear/00077.png``), ``pgm`` (grey PGM, labels kept).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    mask = np.asarray(mask)
    if flavour == "grey255":
        Image.fromarray(((mask > 0) * 255).astype(np.uint8), mode="L").save(path)
    elif flavour == "grey01":
        Image.fromarray((mask > 0).astype(np.uint8), mode="L").save(path)
    elif flavour == "rgb":
        rgb = np.repeat(((mask > 0) * 255).astype(np.uint8)[..., None], 3, axis=2)
        Image.fromarray(rgb, mode="RGB").save(path)
    elif flavour == "palette":
        img = Image.fromarray(mask.astype(np.uint8), mode="P")
        img.putpalette(DAVIS_PALETTE.reshape(-1).tolist())
        img.save(path)
    elif flavour == "greyalpha":
        grey = ((mask > 0) * 255).astype(np.uint8)
        la = np.stack([grey, np.full_like(grey, 255)], axis=2)
        Image.fromarray(la, mode="LA").save(path)
    elif flavour == "pgm":
        Image.fromarray(mask.astype(np.uint8), mode="L").save(path)
    else:
        raise ValueError(flavour)
    return path


def moving_square(n_frames: int, shape=(48, 64), size=14, step=2, start=(10, 8)) -> list[np.ndarray]:
    """A square moving right by ``step`` pixels a frame."""
    out = []
    for t in range(n_frames):
        m = np.zeros(shape, np.uint8)
        r, c = start[0], start[1] + step * t
        m[r : r + size, c : c + size] = 1
        out.append(m)
    return out


def make_davis2016(root: Path, sequences: dict[str, list[np.ndarray]], info: dict | None = None,
                   resolution: str = "480p") -> Path:
    """A DAVIS-2016 tree: ``Annotations/<res>/<seq>/%05d.png`` (0/255 grey) and optionally ``db_info.yml``."""
    import yaml

    for seq, masks in sequences.items():
        for t, m in enumerate(masks):
            save_mask(root / "Annotations" / resolution / seq / f"{t:05d}.png", m)
    if info is not None:
        (root / "db_info.yml").write_text(yaml.safe_dump(info), encoding="utf-8")
    return root


def write_results(results: Path, sequences: dict[str, list[np.ndarray]], *, layout: str = "masks",
                  flavour: str = "palette", names: list[str] | None = None) -> Path:
    """Results as eponet writes them (``<seq>/masks/<frame>.png``) or flat (``<seq>/<frame>.png``)."""
    for seq, masks in sequences.items():
        folder = results / seq / "masks" if layout == "masks" else results / seq
        for t, m in enumerate(masks):
            stem = names[t] if names else f"{t:05d}"
            save_mask(folder / f"{stem}.png", m, flavour)
    return results
