import numpy as np

from eponet.core.cache import Cache, array_digest, content_key


def test_content_key_changes_with_any_part():
    base = dict(stage="flow", plugin="dis", version="1", params={"preset": "medium"}, upstream="abc")
    key = content_key(**base)
    assert key == content_key(**dict(base))
    for field, value in [("plugin", "farneback"), ("params", {"preset": "fast"}), ("upstream", "abd"), ("version", "2")]:
        assert content_key(**{**base, field: value}) != key


def test_array_digest_sees_content_shape_and_dtype():
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    assert array_digest(a) == array_digest(a.copy())
    assert array_digest(a) != array_digest(a.reshape(4, 3))
    assert array_digest(a) != array_digest(a.astype(np.float64))
    b = a.copy()
    b[0, 0] = 1e-3
    assert array_digest(a) != array_digest(b)


def test_round_trip_and_disabled(tmp_path):
    cache = Cache(tmp_path)
    cache.save("flow", "ab" * 32, {"x": np.ones(3)}, {"note": "hi"})
    arrays, meta = cache.load("flow", "ab" * 32)
    np.testing.assert_array_equal(arrays["x"], np.ones(3))
    assert meta == {"note": "hi"}
    assert not list(tmp_path.rglob("*.tmp*"))
    off = Cache(tmp_path, enabled=False)
    assert off.load("flow", "ab" * 32) is None


def test_corrupt_entry_is_a_miss(tmp_path):
    cache = Cache(tmp_path)
    cache.save("flow", "cd" * 32, {"x": np.ones(3)})
    path = next(tmp_path.rglob("*.npz"))
    path.write_bytes(b"garbage")
    assert cache.load("flow", "cd" * 32) is None


def test_code_fingerprint_covers_the_stage_module_and_algorithm_code_only(monkeypatch, tmp_path):
    from eponet.core import cache as cache_module

    dis = cache_module.code_fingerprint("eponet.plugins.flow.dis")
    assert dis == cache_module.code_fingerprint("eponet.plugins.flow.dis")
    assert dis != cache_module.code_fingerprint("eponet.plugins.flow.farneback")
    # the training, evaluation and CLI code is not part of any stage's fingerprint
    assert "training" not in cache_module.ALGORITHM_CODE and "evaluation" not in cache_module.ALGORITHM_CODE
    assert "geometry" in cache_module.ALGORITHM_CODE
    assert "nets" not in cache_module.ALGORITHM_CODE and "fusion" not in cache_module.ALGORITHM_CODE


def _entry(cache, stage, key, size, age):
    """Store an entry of about ``size`` bytes whose mtime is ``age`` seconds ago."""
    import os
    import time

    cache.save(stage, key, {"x": np.zeros(size, dtype=np.uint8)})
    path = cache._path(stage, key)
    os.utime(path, (time.time() - age, time.time() - age))
    return path


def test_stale_temp_files_are_removed_when_the_cache_opens_but_a_live_writers_are_kept(tmp_path):
    import os
    import time

    folder = tmp_path / "flow" / "ab"
    folder.mkdir(parents=True)
    stale, live = folder / ".abab.x1.tmp.npz", folder / ".abab.x2.tmp.npz"
    stale.write_bytes(b"half")
    live.write_bytes(b"half")
    two_hours_ago = time.time() - 7200
    os.utime(stale, (two_hours_ago, two_hours_ago))
    Cache(tmp_path, enabled=False)
    assert stale.exists()  # a disabled cache touches nothing
    Cache(tmp_path)
    assert not stale.exists() and live.exists()


def test_prune_removes_old_entries_then_the_least_recently_used_down_to_a_size(tmp_path):
    cache = Cache(tmp_path)
    old = _entry(cache, "flow", "aa" * 32, 1000, age=10 * 86400)
    a = _entry(cache, "rigidity", "bb" * 32, 1000, age=3 * 86400)
    b = _entry(cache, "flow", "cc" * 32, 1000, age=2 * 86400)
    c = _entry(cache, "appearance", "dd" * 32, 1000, age=86400)
    assert [e.path for e in cache.entries()] == [old, a, b, c]
    assert {e.stage for e in cache.entries()} == {"flow", "rigidity", "appearance"}
    removed = cache.prune(older_than=7 * 86400)
    assert [e.path for e in removed] == [old] and not old.exists() and not old.parent.exists()
    assert cache.load("rigidity", "bb" * 32) is not None  # a hit makes it the most recently used
    size = sum(e.size for e in cache.entries())
    removed = cache.prune(max_size=size - 1)
    assert [e.path for e in removed] == [b] and a.exists() and c.exists()
    assert cache.prune(max_size=0) and cache.entries() == []


_WRITER = """
import logging, sys, time
from pathlib import Path
import numpy as np
from eponet.core.cache import Cache

root, writer, go = sys.argv[1], int(sys.argv[2]), Path(sys.argv[3])
warnings = []
logging.getLogger("eponet.core.cache").addHandler(type("H", (logging.Handler,), {"emit": lambda s, r: warnings.append(r)})())
cache = Cache(root)
while not go.exists():
    time.sleep(0.001)
for _ in range(150):
    cache.save("flow", "ef" * 32, {"x": np.full(2**16, writer, np.int32)}, {"writer": writer})
sys.exit(3 if warnings else 0)
"""


def test_two_processes_writing_one_key_leave_a_whole_entry_at_every_moment(tmp_path):
    """The cache may be shared storage used by several workers: writers of one key never tear an entry (each
    writes its own temp file and renames it into place) and never fail each other."""
    import subprocess
    import sys

    go = tmp_path / "go"
    writers = [subprocess.Popen([sys.executable, "-c", _WRITER, str(tmp_path / "cache"), str(k), str(go)])
               for k in (1, 2)]
    cache = Cache(tmp_path / "cache")
    path = cache._path("flow", "ef" * 32)
    go.touch()
    seen = set()
    while any(w.poll() is None for w in writers):
        if path.exists():  # once there, the entry is always whole: one writer's array with that writer's meta
            loaded = cache.load("flow", "ef" * 32)
            assert loaded is not None, "an entry was read half-written"
            arrays, meta = loaded
            assert arrays["x"].shape == (2**16,) and set(np.unique(arrays["x"])) == {meta["writer"]}
            seen.add(meta["writer"])
    assert [w.wait() for w in writers] == [0, 0]  # neither writer logged a failed write
    assert seen and cache.load("flow", "ef" * 32)[1]["writer"] in (1, 2)
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temp file left


def test_a_third_party_plugins_fingerprint_covers_its_packages_files(monkeypatch, tmp_path):
    """A plugin outside eponet is fingerprinted by every module file of its top-level package (the plugin module
    may import its helpers), so an edit in place (``pip install -e``) changes the code part of its cache keys."""
    import sys
    import types

    from eponet.core.cache import code_fingerprint

    package = tmp_path / "kit_fingerprint_plugin"
    (package / "ops").mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "stage.py").write_text("from .ops.scale import SCALE\n")
    (package / "ops" / "__init__.py").write_text("")
    (package / "ops" / "scale.py").write_text("SCALE = 1.0\n")
    (package / "README.txt").write_text("not code")
    (tmp_path / "kit_single_module_plugin.py").write_text("SCALE = 1.0\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(sys.modules, "kit_module_without_file", types.ModuleType("kit_module_without_file"))

    def fingerprint(module):
        code_fingerprint.cache_clear()  # computed once per process: each call here stands for a new process
        return code_fingerprint(module)

    algorithm_only = fingerprint(None)
    before = fingerprint("kit_fingerprint_plugin.stage")
    assert before not in (algorithm_only, fingerprint("eponet.plugins.flow.dis"))
    assert fingerprint("kit_fingerprint_plugin.ops") == before  # one package, one fingerprint
    (package / "README.txt").write_text("edited, still not code")
    assert fingerprint("kit_fingerprint_plugin.stage") == before
    (package / "ops" / "scale.py").write_text("SCALE = 2.0\n")  # a helper module, not the stage's own
    edited = fingerprint("kit_fingerprint_plugin.stage")
    assert edited != before
    single = fingerprint("kit_single_module_plugin")
    (tmp_path / "kit_single_module_plugin.py").write_text("SCALE = 2.0\n")
    assert fingerprint("kit_single_module_plugin") not in (single, algorithm_only)
    assert fingerprint("kit_module_without_file") == algorithm_only
    assert fingerprint("kit_no_such_module") == algorithm_only


def test_factory_module_sees_through_partials():
    import functools

    from eponet.core.cache import factory_module
    from eponet.plugins.flow.dis import DisFlow

    assert factory_module(DisFlow) == "eponet.plugins.flow.dis"
    assert factory_module(functools.partial(DisFlow, preset="fast")) == "eponet.plugins.flow.dis"


def test_a_full_cache_disk_is_one_warning_and_the_run_goes_on(tmp_path, monkeypatch, caplog):
    import contextlib
    import errno
    import logging

    from eponet.core import cache as cache_module

    @contextlib.contextmanager
    def full_disk(path):
        raise OSError(errno.ENOSPC, "No space left on device")
        yield

    cache = Cache(tmp_path)
    cache.save("flow", "aa" * 32, {"x": np.zeros(3)})
    monkeypatch.setattr(cache_module, "atomic_path", full_disk)
    with caplog.at_level(logging.WARNING, logger="eponet.core.cache"):
        for key in ("bb", "cc", "dd"):
            cache.save("flow", key * 32, {"x": np.zeros(3)})
    assert caplog.messages == [f"cache {tmp_path}: no space left on its disk; this run stores no more results there"]
    assert cache.load("flow", "aa" * 32) is not None and cache.load("flow", "bb" * 32) is None  # reads go on


def test_remove_an_entry(tmp_path):
    cache = Cache(tmp_path)
    cache.save("rigidity", "ab" * 32 + "-state", {"x": np.zeros(3)})
    assert cache.exists("rigidity", "ab" * 32 + "-state")
    cache.remove("rigidity", "ab" * 32 + "-state")
    cache.remove("rigidity", "ab" * 32 + "-state")  # gone already: nothing to do
    assert not cache.exists("rigidity", "ab" * 32 + "-state")
