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
