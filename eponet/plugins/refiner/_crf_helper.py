"""The ``densecrf`` refiner's helper process: ``python -m eponet.plugins.refiner._crf_helper`` reads pickled
argument tuples of :func:`eponet.plugins.refiner.densecrf._crf_margin` from stdin and writes each answer,
``("ok", margin)`` or ``("error", message)``, pickled to stdout, until stdin closes (also when the parent dies)."""

from __future__ import annotations

import pickle
import sys


def main() -> int:
    from eponet.plugins.refiner.densecrf import _crf_margin

    source, sink = sys.stdin.buffer, sys.stdout.buffer
    while True:
        try:
            args = pickle.load(source)
        except (EOFError, pickle.UnpicklingError):  # stdin closed, or cut off mid-request: the parent ended
            return 0
        try:
            answer = ("ok", _crf_margin(*args))
        except Exception as exc:  # noqa: BLE001 - handed to the parent, which raises it
            answer = ("error", f"{exc.__class__.__name__}: {exc}")
        try:
            pickle.dump(answer, sink, protocol=pickle.HIGHEST_PROTOCOL)
            sink.flush()
        except BrokenPipeError:  # the parent ended while this frame was being refined: nothing to answer
            return 0


if __name__ == "__main__":
    raise SystemExit(main())
