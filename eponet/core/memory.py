"""How much memory the run loop holds, and the warning when a run would need more than this machine likely has.

The loop holds a window of frames per sequence (:mod:`eponet.core.stream`): :func:`memory_estimate` puts a number on
it. In one process the next sequence's flow and geometry run beside a sequence's networks
(:meth:`eponet.core.pipeline.Pipeline.run`), so its window counts too.
"""

from __future__ import annotations

import logging

from .inputs import SequenceSource, processing_size
from .motion import ED_WINDOW
from .spec import Spec

__all__ = ["memory_estimate", "memory_warning", "warn_about_memory", "needs_full_frames", "MEMORY_WARNING_BYTES",
           "BYTES_PER_PROCESSING_PIXEL", "BYTES_PER_INPUT_PIXEL"]

log = logging.getLogger(__name__)

#: Bytes the loop holds per frame in flight, per pixel of the processing size (flow both ways, trajectory
#: records, ED, motion image and the rigidity's window temporaries) and per pixel of the input size (the frame,
#: the probability and the mask, when a refiner or a picture output needs full-size frames). Measured: peak
#: RSS less that of a 3-frame run (0.38 GB), ``epo`` preset with the ``threshold`` refiner, 90 frames, chunk 16,
#: lag 30: 0.17, 0.79 and 0.66 GB for 320x240 at scale 0.5, 640x480 at 0.5 and 320x240 at 1; these constants
#: give 0.19, 0.77 and 0.63 GB.
BYTES_PER_PROCESSING_PIXEL = 100
BYTES_PER_INPUT_PIXEL = 8


def memory_estimate(size: tuple[int, int], shape: tuple[int, int], *, chunk: int, lag: int, frames: int = 0,
                    full_frames: bool = True, ed_window: int | None = ED_WINDOW) -> int:
    """About how many bytes the run loop holds at its peak for one sequence of input ``size`` ``(H, W)`` processed
    at ``shape`` ``(h, w)``: ``chunk + lag + ed_window // 2`` frames in flight (``frames``, when given, if the
    video is shorter; every frame with ``ed_window=None``, the whole video's ED scale), each costing :data:`BYTES_PER_PROCESSING_PIXEL` per processing pixel and, with
    ``full_frames``, :data:`BYTES_PER_INPUT_PIXEL` per input pixel. Libraries and networks (about 0.4 GB) come on top.

    >>> round(memory_estimate((3000, 4000), (1500, 2000), chunk=16, lag=30) / 2**30, 1)
    28.0
    """
    if ed_window is None:
        if not frames:
            raise ValueError("memory_estimate: ed_window=None holds the whole video: give its number of frames")
        return memory_estimate(size, shape, chunk=frames, lag=0, frames=frames, full_frames=full_frames, ed_window=1)
    in_flight = chunk + lag + ed_window // 2
    if frames:
        in_flight = min(in_flight, frames)
    per_frame = shape[0] * shape[1] * BYTES_PER_PROCESSING_PIXEL
    if full_frames:
        per_frame += size[0] * size[1] * BYTES_PER_INPUT_PIXEL
    return in_flight * per_frame


#: A sequence whose estimated run-loop peak (:func:`memory_estimate`) is above this is warned
#: about before it runs (README, "run:"); it still runs.
MEMORY_WARNING_BYTES = 8 * 2**30


def needs_full_frames(spec: Spec) -> bool:
    """Whether the loop keeps the input-size frames (for the refiner or a picture output)."""
    return "refiner" in spec.stages or bool({"panels", "overlay"} & set(spec.output.save))


def _estimate(spec: Spec, source: SequenceSource | None) -> int | None:
    """:func:`memory_estimate` of ``source`` under ``spec`` (``None`` when it cannot be known before decoding)."""
    if source is None or source.size is None:
        return None
    if spec.run.ed_window is None and not source.count:
        return None  # the whole video in flight, of a length not known before it is decoded
    size = tuple(source.size)
    return memory_estimate(size, processing_size(size, spec.input.scale), chunk=spec.run.chunk, lag=spec.run.lag,
                           frames=source.count, full_frames=needs_full_frames(spec), ed_window=spec.run.ed_window)


def memory_warning(spec: Spec, source: SequenceSource, alongside: SequenceSource | None = None) -> str | None:
    """One line when the run loop's estimated peak memory for ``source`` is above :data:`MEMORY_WARNING_BYTES`;
    ``alongside``: the sequence whose flow and geometry run beside it (the next one of a run in one process)."""
    estimate = _estimate(spec, source)
    if estimate is None:
        return None
    beside = _estimate(spec, alongside) or 0
    if estimate + beside <= MEMORY_WARNING_BYTES:
        return None
    size = tuple(source.size)
    shape = processing_size(size, spec.input.scale)
    with_next = f" with the next sequence ({alongside.name}) beside it" if beside else ""
    return (f"{source.name}: frames of {size[1]}x{size[0]} px (processed at {shape[1]}x{shape[0]}) need about "
            f"{(estimate + beside) / 2**30:.1f} GiB in the run loop{with_next} (run.chunk {spec.run.chunk}, run.lag "
            f"{spec.run.lag}), above the {MEMORY_WARNING_BYTES / 2**30:g} GiB warning bound; a lower input.scale, "
            "run.chunk or run.lag uses less")


def warn_about_memory(spec: Spec, sources: list[SequenceSource], *, overlap: bool = False) -> None:
    """Log :func:`memory_warning` of every sequence (``overlap``: each with the next one beside it)."""
    for k, source in enumerate(sources):
        nxt = sources[k + 1] if overlap and k + 1 < len(sources) else None
        warning = memory_warning(spec, source, nxt)
        if warning:
            log.warning(warning)
