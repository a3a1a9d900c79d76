"""Progress bars (tqdm) that stay silent when output is not a terminal or the user asked for quiet."""

from __future__ import annotations

import sys
from typing import Iterable, TypeVar

__all__ = ["set_quiet", "track", "progress_enabled"]

T = TypeVar("T")
_QUIET = False


def set_quiet(quiet: bool) -> None:
    """Silence (or re-enable) every progress bar of this process."""
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
