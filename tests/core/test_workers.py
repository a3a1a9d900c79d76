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


_PARENT = """
import multiprocessing, sys, time
from eponet.core.workers import exit_with_parent

def child(path):
    exit_with_parent(interval=0.05)
    open(path, "w").write("started")
    time.sleep(60)

if __name__ == "__main__":
    process = multiprocessing.get_context("spawn").Process(target=child, args=(sys.argv[1],))
    process.start()
    print(process.pid, flush=True)
    time.sleep(60)
"""


def _running(pid: int) -> bool:
    """Whether ``pid`` is a live process (a zombie, ended and not yet reaped, is not)."""
    from pathlib import Path

    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def test_a_worker_ends_when_the_run_that_started_it_is_killed(tmp_path):
    """SIGKILL of the run's process, which no handler sees, leaves no worker computing (and writing) on."""
    import os
    import subprocess
    import sys
    import time
    from pathlib import Path

    import pytest

    if not Path("/proc/self/stat").exists():
        pytest.skip("needs /proc to tell a live process from an ended one")
    script, started = tmp_path / "parent.py", tmp_path / "started"
    script.write_text(_PARENT)
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(root), os.environ.get("PYTHONPATH")]))}
    parent = subprocess.Popen([sys.executable, str(script), str(started)], stdout=subprocess.PIPE, text=True, env=env)
    try:
        child = int(parent.stdout.readline())
        deadline = time.monotonic() + 60
        while not started.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert started.exists() and _running(child)
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 10
    while _running(child) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _running(child)


def _descendants(pid: int) -> set[int]:
    """The live processes below ``pid`` (Linux: /proc/<pid>/task/*/children)."""
    from pathlib import Path

    found, todo = set(), [pid]
    while todo:
        for tasks in Path(f"/proc/{todo.pop()}/task").glob("*/children"):
            try:
                children = {int(c) for c in tasks.read_text().split()}
            except OSError:
                continue
            todo += sorted(children - found)
            found |= children
    return {p for p in found if _running(p)}


def test_sigterm_stops_a_run_and_its_workers_with_one_line(tmp_path):
    """SIGTERM to the run's process alone (``kill``, ``timeout``, a scheduler) stops it as Ctrl-C does: exit status
    143, one line, its workers and their children ended at once, nothing of the unfinished sequences written."""
    import os
    import signal
    import subprocess
    import sys
    import time
    from pathlib import Path

    import pytest

    from tests.conftest import textured_frames, write_frames

    if not Path("/proc/self/task").exists():
        pytest.skip("needs /proc to list a process's children")
    for name in ("a", "b"):
        write_frames(tmp_path / "davis" / "JPEGImages" / "480p" / name, textured_frames(150, (120, 160), seed=ord(name)))
    spec = tmp_path / "spec.yaml"
    spec.write_text(f"""
preset: geometry
input: {{path: {tmp_path / 'davis'}, scale: 1.0}}
output: {{dir: {tmp_path / 'out'}, save: [ed]}}
run: {{workers: 2}}
cache: {{enabled: false}}
""")
    root = Path(__file__).resolve().parents[2]
    process = subprocess.Popen([sys.executable, "-m", "eponet.run", str(spec), "-q"], cwd=root,
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while len(_descendants(process.pid)) < 2:  # the two workers (besides multiprocessing's tracker)
            assert process.poll() is None, process.stderr.read()
            assert time.monotonic() < deadline, "no workers after 120 s"
            time.sleep(0.05)
        time.sleep(1.0)  # into their sequences
        workers = _descendants(process.pid)
        os.kill(process.pid, signal.SIGTERM)
        _, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 143, stderr
    assert stderr.strip().splitlines() == ["error: terminated (SIGTERM)"]
    deadline = time.monotonic() + 10
    while any(_running(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not any(_running(p) for p in workers)
    assert not (tmp_path / "out" / "a").exists() and not (tmp_path / "out" / "b").exists()
