import numpy as np
from threadpoolctl import threadpool_info, threadpool_limits

from eponet.core.pipeline import Pipeline
from eponet.core.spec import parse_spec
from eponet.core.workers import BLAS_THREADS, blas_threads_limited, worker_count


def _blas_threads() -> set[int]:
    return {info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"}


def test_blas_is_held_to_its_threads_in_the_block_and_restored_after_it():
    assert _blas_threads()  # numpy's BLAS is found
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()  # 2 where the machine has 2 cores
        with blas_threads_limited():
            assert _blas_threads() == {BLAS_THREADS}
            assert np.allclose(np.linalg.eigh(np.eye(27))[0], 1.0)
        assert _blas_threads() == before


def test_an_in_process_run_computes_its_geometry_with_one_blas_thread(frames_dir, tmp_path, monkeypatch):
    spec = parse_spec({"preset": "geometry", "input": {"path": str(frames_dir), "scale": 0.5},
                       "output": {"dir": str(tmp_path / "out"), "save": []}, "run": {"workers": 1},
                       "cache": {"enabled": False}})
    pipeline = Pipeline(spec)
    seen = []
    score = pipeline.stages["rigidity"].score_groups  # (what the run loop calls)
    monkeypatch.setattr(pipeline.stages["rigidity"], "score_groups",
                        lambda *a, **k: seen.append(_blas_threads()) or score(*a, **k))
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        pipeline.run()
        assert _blas_threads() == before  # restored after the run
    assert seen and all(threads == {BLAS_THREADS} for threads in seen)


def test_auto_is_one_worker_per_core_and_at_most_one_per_sequence(monkeypatch):
    monkeypatch.setattr("os.cpu_count", lambda: 4)
    assert worker_count("auto", 10) == 4 and worker_count("auto", 2) == 2 and worker_count(3, 1) == 1
