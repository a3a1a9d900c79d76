"""Progress of a run: on a terminal, tqdm bars (one per sequence, one for the whole run with frames/s and ETA);
in a log, a periodic line per long sequence; nothing when quiet.

The run loop reports to :func:`current` (``start``, ``advance``, ``finish`` per sequence); a run installs its
:class:`RunProgress` with :meth:`RunProgress.active`, and worker processes forward their reports to the parent's
(:func:`forward_to` in the worker, :func:`listening` in the parent), which draws every bar and writes every line.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
from dataclasses import dataclass
from typing import Iterable, TypeVar

__all__ = ["set_quiet", "track", "progress_enabled", "RunProgress", "current", "forward_to", "listening",
           "redirect_logging", "format_eta", "PROGRESS_INTERVAL_S"]

log = logging.getLogger(__name__)

T = TypeVar("T")
_QUIET = False

#: Off a terminal, a sequence still running after this many seconds logs a line (frames done of total, frames/s,
#: ETA), and again every as many seconds: short sequences log only their line when they finish.
PROGRESS_INTERVAL_S = 30.0


def set_quiet(quiet: bool) -> None:
    """Silence (or re-enable) every progress bar and progress line of this process."""
    global _QUIET
    _QUIET = quiet


def progress_enabled() -> bool:
    """Whether progress bars are shown: not quiet, and stderr is a terminal."""
    return not _QUIET and sys.stderr.isatty()


def track(iterable: Iterable[T], desc: str, total: int | None = None) -> Iterable[T]:
    """Wrap ``iterable`` in a tqdm bar on stderr, unless quiet or stderr is not a TTY."""
    if not progress_enabled():
        return iterable
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, leave=False, dynamic_ncols=True)


def format_eta(seconds: float) -> str:
    """``seconds`` as ``42 s``, ``6 min 50 s`` or ``2 h 05 min``.

    >>> format_eta(41.6), format_eta(410), format_eta(7500)
    ('42 s', '6 min 50 s', '2 h 05 min')
    """
    seconds = int(round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60:02d} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60:02d} min"


@dataclass
class _Sequence:
    total: int
    started: float
    done: int = 0
    last_line: float = 0.0
    bar: object = None
    position: int = 0


class RunProgress:
    """What a run has done: frames per sequence and overall.

    ``total`` is the run's frame count (``None`` or 0: unknown, no ETA). With ``bars`` (default: stderr is a
    terminal and not quiet) it draws an overall bar (``overall``) and one bar per running sequence on ``file``;
    otherwise each sequence running for :data:`PROGRESS_INTERVAL_S` logs ``name: done/total frames, x frames/s,
    ETA ...`` every as many seconds (INFO, so ``-q`` hides it). Thread-safe: worker reports arrive on a thread."""

    def __init__(self, total: int | None = None, *, overall: bool = True, bars: bool | None = None, file=None,
                 interval: float | None = None, clock=time.monotonic):
        self.bars = progress_enabled() if bars is None else bars
        self.total = total or None
        self.file = file
        self.interval = interval
        self.clock = clock
        self.sequences: dict[str, _Sequence] = {}
        self.overall = None
        self._lock = threading.Lock()
        if self.bars and overall:
            self.overall = self._bar(total=self.total, desc="all", position=0)

    def _bar(self, **kwargs):
        from tqdm import tqdm

        return tqdm(unit="frame", dynamic_ncols=True, leave=False, file=self.file or sys.stderr, **kwargs)

    def start(self, name: str, total: int) -> None:
        with self._lock:
            entry = _Sequence(total=int(total or 0), started=self.clock())
            entry.last_line = entry.started
            if self.bars:
                used = {s.position for s in self.sequences.values()}
                entry.position = min(p for p in range(1, len(used) + 2) if p not in used)
                entry.bar = self._bar(total=entry.total or None, desc=name, position=entry.position)
            self.sequences[name] = entry

    def advance(self, name: str, frames: int = 1) -> None:
        with self._lock:
            entry = self.sequences.get(name)
            if entry is None:
                return
            entry.done += frames
            if entry.bar is not None:
                entry.bar.update(frames)
            if self.overall is not None:
                self.overall.update(frames)
            if self.bars or _QUIET:
                return
            now = self.clock()
            interval = PROGRESS_INTERVAL_S if self.interval is None else self.interval
            if now - entry.last_line >= interval:
                entry.last_line = now
                log.info("%s", self.line(name, now))

    def line(self, name: str, now: float | None = None) -> str:
        """``name: 120/1800 frames, 4.1 frames/s, ETA 6 min 50 s`` (without a known total: no ETA)."""
        entry = self.sequences[name]
        elapsed = max((self.clock() if now is None else now) - entry.started, 1e-9)
        rate = entry.done / elapsed
        if entry.total:
            eta = format_eta((entry.total - entry.done) / rate) if rate > 0 else "unknown"
            return f"{name}: {entry.done}/{entry.total} frames, {rate:.1f} frames/s, ETA {eta}"
        return f"{name}: {entry.done} frames, {rate:.1f} frames/s"

    def finish(self, name: str) -> None:
        with self._lock:
            entry = self.sequences.pop(name, None)
            if entry is not None and entry.bar is not None:
                entry.bar.close()

    def close(self) -> None:
        for name in list(self.sequences):
            self.finish(name)
        if self.overall is not None:
            self.overall.close()
            self.overall = None

    @contextlib.contextmanager
    def active(self):
        """Make this the process's :func:`current` reporter for the block (closed at its end)."""
        global _CURRENT
        previous, _CURRENT = _CURRENT, self
        try:
            yield self
        finally:
            _CURRENT = previous
            self.close()


_CURRENT = None


def current():
    """The reporter of the run in progress; outside a run, a fresh one without an overall bar (so that a
    sequence run on its own still shows its bar or its lines)."""
    global _CURRENT
    if _CURRENT is None:
        _CURRENT = RunProgress(overall=False)
    return _CURRENT


class _Forward:
    """A worker process's reporter: every report goes to the parent through ``channel``."""

    def __init__(self, channel):
        self.channel = channel

    def start(self, name: str, total: int) -> None:
        self.channel.put(("start", name, total))

    def advance(self, name: str, frames: int = 1) -> None:
        self.channel.put(("advance", name, frames))

    def finish(self, name: str) -> None:
        self.channel.put(("finish", name))


def forward_to(channel) -> None:
    """In a worker process: send this process's reports to ``channel`` (a multiprocessing queue the parent
    reads with :func:`listening`)."""
    global _CURRENT
    _CURRENT = _Forward(channel)


@contextlib.contextmanager
def listening(channel):
    """In the parent: pass the reports that arrive on ``channel`` to :func:`current`, on a thread, for the block."""
    reporter = current()

    def listen():
        while True:
            message = channel.get()
            if message is None:
                return
            method, *args = message
            getattr(reporter, method)(*args)

    thread = threading.Thread(target=listen, name="eponet-progress", daemon=True)
    thread.start()
    try:
        yield
    finally:
        channel.put(None)
        thread.join(timeout=5)


def redirect_logging():
    """For the command line: while bars are drawn, log lines are written above them instead of through them
    (tqdm's ``logging_redirect_tqdm``); a no-op off a terminal."""
    if not progress_enabled():
        return contextlib.nullcontext()
    from tqdm.contrib.logging import logging_redirect_tqdm

    return logging_redirect_tqdm()
