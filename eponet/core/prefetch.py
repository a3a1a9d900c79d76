"""Background threads of the run loop: an iterator run ahead of its consumer in a thread of its own.

The stream of one sequence (:mod:`eponet.core.stream`) runs its flow and its geometry in such threads, so that the
stages upstream work on the next chunk while those downstream work on this one (numpy, OpenCV and torch release
the GIL in their heavy loops); the run loop of several sequences starts the next sequence's front this way while
the current one finishes (:meth:`eponet.core.pipeline.Pipeline.run`).
"""

from __future__ import annotations

import queue
import threading
from typing import Iterator

__all__ = ["Prefetch", "Stopped", "wait_for"]


class _Stop:
    pass


class Stopped(RuntimeError):
    """Raised to the consumer of a :class:`Prefetch` whose thread was stopped before the end of its iterator (so
    that a consumer does not take a stopped producer for the end of the data, e.g. of a video)."""


class Prefetch:
    """Iterates ``iterator`` in a background thread, at most ``depth`` items ahead of the consumer. An exception
    upstream is raised to the consumer in order, and :class:`Stopped` if the thread was stopped before the end.
    The thread starts at the first ``next()`` (or at :meth:`start`, to run ahead before anything is asked);
    :meth:`close` stops it and closes ``iterator`` in its own thread, so that generators upstream run their
    ``finally`` blocks however the consumer ends."""

    def __init__(self, iterator: Iterator, depth: int, name: str):
        self._iterator = iterator
        self._channel: queue.Queue = queue.Queue(maxsize=max(1, depth))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._produce, name=f"eponet-{name}", daemon=True)
        self._started = False
        self._done = False

    def start(self) -> "Prefetch":
        if not self._started:
            self._started = True
            self._thread.start()
        return self

    def _put(self, item) -> bool:
        while not self._stop.is_set():
            try:
                self._channel.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def _produce(self) -> None:
        try:
            for item in self._iterator:
                if not self._put(item):
                    return
            self._put(_Stop)
        except BaseException as exc:  # handed to the consumer
            self._put(exc)
        finally:
            close = getattr(self._iterator, "close", None)
            if close is not None:
                try:
                    close()
                except Exception:  # pragma: no cover - a generator's own cleanup failing is not ours to raise
                    pass

    def __iter__(self) -> "Prefetch":
        return self

    def __next__(self):
        if self._done:
            raise StopIteration
        if self._stop.is_set():
            raise Stopped(f"{self._thread.name} was stopped before its end")
        self.start()
        while True:  # a producer stopped by close() puts nothing more: its consumer ends too
            try:
                item = self._channel.get(timeout=0.1)
                break
            except queue.Empty:
                if not self._thread.is_alive() and self._channel.empty():
                    item = Stopped(f"{self._thread.name} was stopped before its end")
                    break
        if item is _Stop:
            self._done = True
            self.close()
            raise StopIteration
        if isinstance(item, BaseException):
            self._done = True
            self.close()
            raise item
        return item

    def stop(self) -> None:
        """Tell the thread to end at its next item, without waiting for it; whoever asks for an item after this
        gets :class:`Stopped`."""
        self._stop.set()

    def close(self) -> None:
        """Stop the thread and wait a little for it."""
        self.stop()
        if self._started:
            self._thread.join(timeout=5)


def wait_for(event: threading.Event, cancelled: threading.Event, poll: float = 0.1) -> bool:
    """Wait until ``event`` is set (True), or until ``cancelled`` is (False)."""
    while not event.wait(poll):
        if cancelled.is_set():
            return False
    return True
