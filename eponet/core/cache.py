"""Content-addressed cache of intermediate results (flow, trajectories, ED, motion images, features)."""

from __future__ import annotations

import functools
import importlib.util
import hashlib
import json
import logging
from pathlib import Path

import numpy as np

from .io import atomic_path

__all__ = ["Cache", "content_key", "array_digest", "code_fingerprint"]

log = logging.getLogger(__name__)


def array_digest(array: np.ndarray) -> str:
    """sha256 of an array's dtype, shape and bytes."""
    digest = hashlib.sha256(f"{array.dtype.str}{array.shape}".encode())
    digest.update(np.ascontiguousarray(array).data)
    return digest.hexdigest()


#: eponet's algorithm code that every cached built-in stage (flow, trajectories, rigidity, appearance) may depend
#: on, besides the stage's own module. The torch networks (``nets/``, ``fusion/``) are not here: no cached stage
#: runs them, so retraining or editing a network keeps the cached flow, ED and features.
ALGORITHM_CODE = ("geometry", "core/types.py", "core/imaging.py", "core/motion.py")


@functools.lru_cache(maxsize=None)
def code_fingerprint(module: str | None = None) -> str:
    """sha256 over the sources of a built-in stage's module (e.g. ``eponet.plugins.rigidity.trifocal``) and
    eponet's algorithm code (:data:`ALGORITHM_CODE`), so that a changed algorithm never reuses stale results
    while edits elsewhere (CLI, training, evaluation) keep the cache. Third-party plugins are keyed by their
    package version instead."""
    root = Path(__file__).resolve().parent.parent
    paths = []
    for name in ALGORITHM_CODE:
        target = root / name
        paths += sorted(target.rglob("*.py")) if target.is_dir() else [target]
    if module:
        spec = importlib.util.find_spec(module)
        if spec is not None and spec.origin:
            paths.append(Path(spec.origin))
    digest = hashlib.sha256()
    for path in paths:
        digest.update(str(path.relative_to(root) if path.is_relative_to(root) else path.name).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def content_key(**parts) -> str:
    """sha256 of the JSON form of ``parts`` (stage, plugin, version, parameters, upstream keys, input hash)."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()


class Cache:
    """Arrays stored as ``<root>/<stage>/<key[:2]>/<key>.npz``, written atomically; a corrupt entry is a
    miss. With ``enabled=False`` nothing is read or written."""

    def __init__(self, root: str | Path, enabled: bool = True):
        self.root = Path(root)
        self.enabled = enabled
        self.hits: list[str] = []

    def _path(self, stage: str, key: str) -> Path:
        return self.root / stage / key[:2] / f"{key}.npz"

    def load(self, stage: str, key: str) -> tuple[dict[str, np.ndarray], dict] | None:
        if not self.enabled:
            return None
        path = self._path(stage, key)
        if not path.is_file():
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {name: data[name] for name in data.files if name != "__meta__"}
                meta = json.loads(str(data["__meta__"])) if "__meta__" in data.files else {}
        except Exception as exc:  # a damaged entry is recomputed, never trusted
            log.warning("ignoring unreadable cache entry %s (%s)", path, exc)
            return None
        self.hits.append(stage)
        return arrays, meta

    def exists(self, stage: str, key: str) -> bool:
        """Whether an entry is stored (without reading it); always ``False`` when disabled."""
        return self.enabled and self._path(stage, key).is_file()

    def save(self, stage: str, key: str, arrays: dict[str, np.ndarray], meta: dict | None = None) -> None:
        if not self.enabled:
            return
        path = self._path(stage, key)
        try:
            with atomic_path(path) as tmp:
                with open(tmp, "wb") as handle:
                    np.savez(handle, __meta__=np.array(json.dumps(meta or {})), **arrays)
        except Exception as exc:  # the cache is an optimisation: a full disk must not fail the run
            log.warning("could not write cache entry %s (%s)", path, exc)
