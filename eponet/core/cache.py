"""Content-addressed cache of intermediate results (flow, trajectories, ED, motion images, features)."""

from __future__ import annotations

import functools
import importlib.util
import hashlib
import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .io import atomic_path, is_no_space

__all__ = ["Cache", "CacheEntry", "content_key", "array_digest", "code_fingerprint", "STALE_TEMP_SECONDS"]

log = logging.getLogger(__name__)

#: A cache temp file (``.<key>.*.tmp.npz``) older than this was left by a killed writer and is removed when a cache
#: opens or is pruned; a younger one may belong to a live writer and is left alone.
STALE_TEMP_SECONDS = 3600


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


@dataclass(frozen=True)
class CacheEntry:
    """One stored entry: its stage kind, file, size in bytes and mtime (the time it was last written or read)."""

    stage: str
    path: Path
    size: int
    mtime: float


class Cache:
    """Arrays stored as ``<root>/<stage>/<key[:2]>/<key>.npz``, written atomically; a corrupt entry is a
    miss. With ``enabled=False`` nothing is read or written. A hit refreshes the entry's mtime, so that
    :meth:`prune` removes the least recently used entries first."""

    def __init__(self, root: str | Path, enabled: bool = True):
        self.root = Path(root)
        self.enabled = enabled
        self.hits: list[str] = []
        self.full = False  # a write found the disk full: no more writes
        if enabled:
            self.remove_stale_temps()

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
        try:
            os.utime(path)
        except OSError:  # a read-only cache still serves hits
            pass
        return arrays, meta

    def exists(self, stage: str, key: str) -> bool:
        """Whether an entry is stored (without reading it); always ``False`` when disabled."""
        return self.enabled and self._path(stage, key).is_file()

    def save(self, stage: str, key: str, arrays: dict[str, np.ndarray], meta: dict | None = None) -> None:
        if not self.enabled or self.full:
            return
        path = self._path(stage, key)
        try:
            with atomic_path(path) as tmp:
                with open(tmp, "wb") as handle:
                    np.savez(handle, __meta__=np.array(json.dumps(meta or {})), **arrays)
        except Exception as exc:  # the cache is an optimisation: a full disk must not fail the run
            if is_no_space(exc):  # said once; the run goes on without storing more
                self.full = True
                log.warning("cache %s: no space left on its disk; this run stores no more results there", self.root)
            else:
                log.warning("could not write cache entry %s (%s)", path, exc)

    def remove(self, stage: str, key: str) -> None:
        """Remove an entry if it is there (a checkpoint superseded by the complete result)."""
        if self.enabled:
            try:
                self._path(stage, key).unlink(missing_ok=True)
            except OSError as exc:
                log.warning("could not remove cache entry %s (%s)", self._path(stage, key), exc)

    # -- maintenance (``eponet cache info | prune``) ----------------------------------------------
    def entries(self) -> list[CacheEntry]:
        """Every stored entry, oldest first (temp files of writers are not entries)."""
        found = []
        for path in self.root.glob("*/*/*.npz"):
            if path.name.startswith("."):
                continue
            try:
                stat = path.stat()
            except OSError:  # removed meanwhile
                continue
            found.append(CacheEntry(path.parent.parent.name, path, stat.st_size, stat.st_mtime))
        return sorted(found, key=lambda entry: (entry.mtime, str(entry.path)))

    def remove_stale_temps(self, max_age: float = STALE_TEMP_SECONDS) -> int:
        """Remove temp files older than ``max_age`` seconds (left by killed writers); returns the bytes freed."""
        freed = 0
        now = time.time()
        for path in self.root.glob("*/*/.*.tmp.npz"):
            try:
                stat = path.stat()
                if now - stat.st_mtime > max_age:
                    path.unlink()
                    freed += stat.st_size
            except OSError:
                continue
        return freed

    def prune(self, *, older_than: float | None = None, max_size: int | None = None) -> list[CacheEntry]:
        """Remove entries not used for ``older_than`` seconds, then the least recently used ones until the
        entries take at most ``max_size`` bytes, and stale temp files; returns the entries removed."""
        self.remove_stale_temps()
        entries = self.entries()
        now = time.time()
        cut = sum(1 for e in entries if older_than is not None and now - e.mtime > older_than)  # oldest first
        total = sum(e.size for e in entries[cut:])
        while max_size is not None and cut < len(entries) and total > max_size:
            total -= entries[cut].size
            cut += 1
        doomed = entries[:cut]
        removed = []
        for entry in doomed:
            try:
                entry.path.unlink()
                removed.append(entry)
            except OSError as exc:
                log.warning("could not remove cache entry %s (%s)", entry.path, exc)
            try:
                entry.path.parent.rmdir()  # the key's folder, once empty
            except OSError:
                pass
        return removed
