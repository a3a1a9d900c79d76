"""Shared fixtures: the real-data folder and small synthetic inputs."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    """``$EPONET_SHARED_DATA`` or ``<repo>/../shared/data``."""
    return Path(os.environ.get("EPONET_SHARED_DATA") or REPO.parent / "shared" / "data")


@pytest.fixture
def one_torch_thread():
    """torch on one thread for the test (restored after): small networks run faster and deterministically."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def shared_data() -> Path:
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"real data not available at {path} (set EPONET_SHARED_DATA)")
    return path


def textured_frames(count: int = 5, size: tuple[int, int] = (48, 64), shift: tuple[float, float] = (1.0, 0.5),
                    seed: int = 0) -> np.ndarray:
    """``count`` RGB frames (F, H, W, 3) of a smooth random texture whose content moves by ``shift`` (dx, dy)
    pixels per frame (so the true forward flow is ``shift`` everywhere away from the borders)."""
    rng = np.random.default_rng(seed)
    height, width = size
    base = cv2.GaussianBlur(rng.uniform(0, 255, (height * 2, width * 2, 3)).astype(np.float32), (0, 0), 2.0)
    frames = []
    for t in range(count):
        matrix = np.float32([[1, 0, -width / 2 + shift[0] * t], [0, 1, -height / 2 + shift[1] * t]])
        frames.append(cv2.warpAffine(base, matrix, (width, height), flags=cv2.INTER_LINEAR))
    return np.clip(np.stack(frames), 0, 255).astype(np.uint8)


def write_video(path: Path, frames: np.ndarray, fps: float = 10) -> Path:
    """RGB frames (F, H, W, 3) as an MJPG ``.avi`` at ``fps`` (a codec every OpenCV build writes)."""
    height, width = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (width, height))
    for frame in frames:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()
    return path


def write_frames(folder: Path, frames: np.ndarray, suffix: str = ".png", start: int = 0) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for t, frame in enumerate(frames):
        path = folder / f"{start + t:05d}{suffix}"
        cv2.imwrite(str(path), cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        paths.append(path)
    return paths


@pytest.fixture
def frames_dir(tmp_path) -> Path:
    """A folder of 5 small translating frames."""
    folder = tmp_path / "clip"
    write_frames(folder, textured_frames())
    return folder


def assert_shipped_weights(name: str, kind: str):
    """A built-in weights entry exists for ``kind``, is small (< 20 MB), matches its catalogue checksum and has
    its model card (``<name>.md``) beside it; returns the entry."""
    from eponet.weights import builtin_weights, sha256_of

    entry = builtin_weights()[name]
    assert entry.kind == kind
    assert entry.file.stat().st_size < 20 * 2**20
    assert sha256_of(entry.file) == entry.sha256
    assert (entry.file.parent / f"{name}.md").is_file()
    return entry
