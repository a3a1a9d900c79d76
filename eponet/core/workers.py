"""Worker processes of the run loop: one sequence per process (``run.workers``), each process building its
pipeline once, with its share of the cores for torch and OpenCV; an error comes back to the parent as one
line of eponet's own error type."""

from __future__ import annotations

import os
import threading
import time
from contextlib import contextmanager

from .cache import Cache
from .errors import EponetError, InputError, StageError
from .inputs import SequenceSource
from .progress import listening
from .spec import Spec

__all__ = ["worker_count", "run_in_workers", "limit_threads", "torch_threads", "torch_threads_limited",
           "blas_threads_limited", "exit_with_parent", "BLAS_THREADS"]

#: Threads of numpy's BLAS (OpenBLAS, MKL) in a run. The geometry's linear algebra is on small matrices (27 x 27
#: normal equations, batches of 3 x 3 and 9 x 9 systems), where BLAS threads cost more to wake than they save and
#: spin next to the run loop's other threads: measured on 2 cores with the other core busy, preset ``geometry`` on
#: 40 frames of 427x240, 8.9-10.4 s of CPU with one thread against 16.8-20.1 s with two (identical maps); a
#: 27 x 27 ``eigh`` 0.09 ms against 4.9 ms. Alone on a quiet machine the difference is small (README, "Speed").
BLAS_THREADS = 1


def worker_count(setting, sequences: int) -> int:
    """Worker processes for ``sequences`` sequences: ``auto`` is one per core (at most one per sequence)."""
    if setting == "auto":
        return max(1, min(os.cpu_count() or 1, sequences))
    return max(1, min(int(setting), max(sequences, 1)))


def torch_threads(cores: int, overlapped: bool) -> int:
    """torch threads of a process with ``cores`` cores (its share of the machine's): all of them, or half when the
    stages of a video overlap in threads (``run.threads``). torch's OpenMP threads spin while they wait for each
    other, so next to the flow and geometry threads a full share burns the cores it should leave them (measured on
    2 cores, one 300-frame video, preset ``epo``: 14.0 R per frame with 2 torch threads, 9.9 R with 1). OpenCV
    keeps the full share (its pool does not spin: 11.5 R with both at 1)."""
    cores = max(1, cores)
    return max(1, cores // 2) if overlapped else cores


@contextmanager
def torch_threads_limited(threads: int):
    """torch's thread count set to ``threads`` for the duration of the block, restored after it."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@contextmanager
def blas_threads_limited(threads: int = BLAS_THREADS):
    """numpy's BLAS limited to ``threads`` for the duration of the block (:data:`BLAS_THREADS`), restored after
    it (threadpoolctl, which also finds a BLAS that another package loaded)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=threads, user_api="blas"):
        yield


_WORKER = None  # the worker process's Pipeline

#: Seconds between a worker's checks that the process that started it is still there.
PARENT_CHECK_S = 0.5
#: The exit status of a worker whose parent is gone (128 + SIGTERM, as if the run's kill had reached it).
PARENT_GONE_EXIT = 143


def exit_with_parent(parent: int | None = None, interval: float = PARENT_CHECK_S) -> None:
    """End this process, within ``interval`` seconds, once its parent ``parent`` (a pid; default: the parent it has
    now) is gone.

    A run killed by a signal it cannot handle (SIGKILL, an out-of-memory kill) or by one whose default action ends
    it at once (SIGTERM from ``kill``, ``timeout`` or a batch scheduler, sent to the run's process alone) never
    stops its worker processes: they would go on computing and writing the outputs of a run that no longer
    exists, then wait forever to report them, each holding its pipeline's memory. A daemon thread polls
    ``os.getppid()`` (a process whose parent ends is handed to another) and ends the worker with ``os._exit``
    (no cleanup: its own children, the CRF helper, see their pipes close and end too). The re-run resumes from
    what was complete: each output file is written atomically, and a sequence counts as done only when the run
    recorded it."""
    parent = os.getppid() if parent is None else parent

    def watch():
        while True:
            if os.getppid() != parent:
                os._exit(PARENT_GONE_EXIT)
            time.sleep(interval)

    threading.Thread(target=watch, name="eponet-parent-watch", daemon=True).start()


def _start_worker(spec: Spec, cache_root: str, cache_enabled: bool, threads: int, reports, parent: int) -> None:
    global _WORKER
    exit_with_parent(parent)  # (the run's pid, not the worker's parent now: the run may be gone already)
    limit_threads(threads, overlapped=spec.run.threads)
    from .progress import forward_to, set_quiet

    from .pipeline import Pipeline

    set_quiet(True)  # the parent draws the bars and writes the lines
    forward_to(reports)
    _WORKER = Pipeline(spec, cache=Cache(cache_root, enabled=cache_enabled))


def limit_threads(threads: int, *, overlapped: bool = False) -> None:
    """Each worker gets its share of the cores, ``threads``, for OpenCV and torch (:func:`torch_threads`: half
    of it with ``overlapped`` stages), so that workers do not oversubscribe, and numpy's BLAS :data:`BLAS_THREADS`
    (for the life of the process: workers and Ray actors only run sequences)."""
    import cv2
    from threadpoolctl import threadpool_limits

    cv2.setNumThreads(threads)
    threadpool_limits(limits=BLAS_THREADS, user_api="blas")
    try:
        import torch

        torch.set_num_threads(torch_threads(threads, overlapped))
    except ImportError:  # pragma: no cover - torch is a dependency
        pass


def _work(source: SequenceSource):
    try:
        return "ok", _WORKER.run_sequence(source)
    except EponetError as exc:
        return "error", (exc.__class__.__name__, exc.exit_code, str(exc))
    except Exception as exc:  # reported in the parent as one line
        return "error", ("StageError", 1, f"{source.name}: {exc.__class__.__name__}: {exc}")


class _WorkerError(EponetError):
    def __init__(self, message: str, exit_code: int):
        super().__init__(message)
        self.exit_code = exit_code


def _rebuilt_error(name: str, exit_code: int, message: str) -> EponetError:
    """The worker's error, as its own type where that is one of eponet's (so callers can catch it)."""
    from . import errors

    cls = getattr(errors, name, None)
    if isinstance(cls, type) and issubclass(cls, EponetError) and cls is not errors.SpecError:
        try:
            error = cls(message)
            error.exit_code = exit_code
            return error
        except TypeError:
            pass
    return _WorkerError(message, exit_code)


def _end_workers(pool) -> None:
    """Terminate a process pool's workers (``terminate_workers`` where Python has it, 3.14; else each process)."""
    terminate = getattr(pool, "terminate_workers", None)
    if terminate is not None:
        terminate()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        if process.is_alive():
            process.terminate()


def run_in_workers(pipeline, sources: list[SequenceSource], workers: int, finished, isolate=None) -> None:
    """Run ``sources`` on ``workers`` spawned processes; ``finished(name, entry)`` for each sequence done. A
    sequence whose input or stage fails goes to ``isolate(name, reason, exit_code)`` when given (the others go
    on); any other failure, or any failure without ``isolate``, lets the running sequences finish, starts no
    more and is raised."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    threads = max(1, (os.cpu_count() or 1) // workers)
    context = multiprocessing.get_context("spawn")  # no fork of a process whose torch/OpenCV threads run
    cache = pipeline.cache
    reports = context.Queue()
    with listening(reports), ProcessPoolExecutor(
            workers, mp_context=context, initializer=_start_worker,
            initargs=(pipeline.spec, str(cache.root), cache.enabled, threads, reports, os.getpid())) as pool:
        futures = {pool.submit(_work, source): source for source in sources}
        error = None
        try:
            while futures:
                done, _ = wait(futures, return_when=FIRST_COMPLETED)
                for future in done:
                    source = futures.pop(future)
                    if future.cancelled():
                        continue
                    status, value = future.result()
                    if status == "ok":
                        finished(source.name, value)  # also after an error: what finished is kept
                        continue
                    failure = _rebuilt_error(*value)
                    if isolate is not None and isinstance(failure, (InputError, StageError)):
                        isolate(source.name, str(failure), failure.exit_code)
                    elif error is None:
                        error = failure
                        for other in futures:  # those not started yet; running ones finish
                            other.cancel()
        except BaseException:  # Ctrl-C or SIGTERM (eponet.cli.Terminated): the workers end now, not after their
            for future in futures:  # sequences (SIGTERM reached this process alone; Ctrl-C reached them too)
                future.cancel()
            _end_workers(pool)
            raise
        if error is not None:
            raise error


