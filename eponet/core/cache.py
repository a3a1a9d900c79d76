"""Content-addressed cache of intermediate results (flow, trajectories, ED, motion images, features)."""

from __future__ import annotations

import functools
import importlib.machinery
import importlib.util
import hashlib
import json
import logging
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .io import atomic_path

__all__ = ["Cache", "CacheEntry", "content_key", "array_digest", "code_fingerprint", "factory_module",
           "STALE_TEMP_SECONDS"]

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
    """sha256 over eponet's algorithm code (:data:`ALGORITHM_CODE`) and the code of the stage whose factory lives in
    ``module``, so that a changed algorithm never reuses stale results while edits elsewhere (CLI, training,
    evaluation) keep the cache.

    A built-in stage's code is its module (e.g. ``eponet.plugins.rigidity.trifocal``). A third-party plugin's is
    every module file of its top-level package (``myplugin`` for ``myplugin.stages.flow``; the module itself when
    it is not in a package), since a plugin module may import its own helpers: an edited plugin (``pip install
    -e``) gets new keys even when its version stays the same. Computed once per process, from the files as they
    are then (the code the process imported)."""
    root = Path(__file__).resolve().parent.parent
    paths = []
    for name in ALGORITHM_CODE:
        target = root / name
        files = sorted(target.rglob("*.py")) if target.is_dir() else [target]
        paths += [(str(path.relative_to(root)), path) for path in files]
    if module:
        paths += _stage_sources(module, root)
    digest = hashlib.sha256()
    for label, path in paths:
        digest.update(label.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


#: Files that hold a module's code (``.py`` and compiled extensions), for a third-party plugin's fingerprint.
_MODULE_SUFFIXES = tuple(importlib.machinery.SOURCE_SUFFIXES + importlib.machinery.EXTENSION_SUFFIXES)


def _stage_sources(module: str, root: Path) -> list[tuple[str, Path]]:
    """``(label, file)`` of the code :func:`code_fingerprint` takes a stage in ``module`` to be: the imported module
    (or package) where it is loaded, else where the import system would find it; [] when it has no file (e.g. a
    module made at run time)."""
    builtin = module.split(".")[0] == "eponet"
    name = module if builtin else module.split(".")[0]
    loaded = sys.modules.get(name)
    if loaded is not None:
        origin, locations = getattr(loaded, "__file__", None), getattr(loaded, "__path__", None)
    else:
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            return []
        if spec is None:
            return []
        origin, locations = spec.origin, spec.submodule_search_locations
    if builtin or not locations:
        path = Path(origin) if origin else None
        if path is None or not path.is_file():
            return []
        return [(str(path.relative_to(root)) if path.is_relative_to(root) else path.name, path)]
    files = []
    for location in map(Path, list(locations)):
        files += sorted((str(path.relative_to(location.parent)), path) for path in location.rglob("*")
                        if path.suffix in _MODULE_SUFFIXES and "__pycache__" not in path.parts and path.is_file())
    return files


def factory_module(factory) -> str | None:
    """The module a stage factory (a class, a function or a ``functools.partial`` of one) is defined in."""
    return getattr(getattr(factory, "func", factory), "__module__", None)


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
        if not self.enabled:
            return
        path = self._path(stage, key)
        try:
            with atomic_path(path) as tmp:
                with open(tmp, "wb") as handle:
                    np.savez(handle, __meta__=np.array(json.dumps(meta or {})), **arrays)
        except Exception as exc:  # the cache is an optimisation: a full disk must not fail the run
            log.warning("could not write cache entry %s (%s)", path, exc)

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
