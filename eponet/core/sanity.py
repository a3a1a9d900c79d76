"""Checks of what a sequence's run produced that are not errors but limits of the method, warned about once
per sequence with the frames they concern and recorded in ``run.json``.

- **Nothing moves**: the camera is still and nothing moves in front of it (the frame's flow stays below
  :data:`STILL_FLOW_PX` at the 99th percentile). The rigidity stages take the static model there (the ED of a
  still pixel is its flow, about 0), so the ED maps are near 0 and the masks come out (nearly) empty: that is the
  documented answer, not a failure.
- **The mask covers (nearly) the whole frame** (more than :data:`COVER_FRACTION` of it): the method fits the
  camera's motion on the background, and a frame with no background left has nothing to fit it on; masks
  there are unreliable. (An object that fills the whole view and moves as one is, to epipolar geometry, the
  camera's motion: it gets an empty mask and cannot be told apart.)
"""

from __future__ import annotations

import logging

import numpy as np

__all__ = ["STILL_FLOW_PX", "COVER_FRACTION", "SequenceChecks", "frame_ranges"]

log = logging.getLogger(__name__)

#: A frame whose flow (forward, processing-size pixels) is below this at the 99th percentile is still.
STILL_FLOW_PX = 0.25
#: A mask covering more than this fraction of its frame leaves no background for the rigidity model.
COVER_FRACTION = 0.9


def frame_ranges(frames: list[int]) -> str:
    """Sorted frame indices as compact ranges: ``[0, 1, 2, 5, 7, 8]`` -> ``'0-2, 5, 7-8'``."""
    parts, start = [], None
    for i, t in enumerate(frames):
        if start is None:
            start = t
        if i + 1 == len(frames) or frames[i + 1] != t + 1:
            parts.append(f"{start}" if start == t else f"{start}-{t}")
            start = None
    return ", ".join(parts)


class SequenceChecks:
    """Watches a sequence's frames as they are written (:meth:`observe`) and warns at the end
    (:meth:`finish`), which returns the ``run.json`` record: ``{"still_frames": [...], "covered_frames": [...],
    "mask_coverage": mean}`` (only the keys that apply)."""

    def __init__(self, name: str):
        self.name = name
        self.still: list[int] = []
        self.covered: list[int] = []
        self.coverage: list[float] = []

    def observe(self, t: int, flow: np.ndarray | None, mask: np.ndarray | None) -> None:
        """``flow`` float (h, w, 2) in pixels (the frame's motion), ``mask`` (H, W), non-zero = object."""
        if flow is not None:  # still: under 1% of the pixels move by STILL_FLOW_PX or more (no sort of the map)
            moving = np.count_nonzero(flow[..., 0] ** 2 + flow[..., 1] ** 2 >= STILL_FLOW_PX ** 2)
            if moving < 0.01 * flow[..., 0].size:
                self.still.append(int(t))
        if mask is not None:
            fraction = float(np.count_nonzero(mask)) / mask.size
            self.coverage.append(fraction)
            if fraction > COVER_FRACTION:
                self.covered.append(int(t))

    def finish(self) -> dict:
        record: dict = {}
        if self.still:
            log.warning("%s: frames %s: nothing moves (flow below %.2f px): the static model leaves the ED near 0 "
                        "and the masks (nearly) empty there", self.name, frame_ranges(self.still), STILL_FLOW_PX)
            record["still_frames"] = self.still
        if self.covered:
            log.warning("%s: frames %s: the mask covers more than %d%% of the frame: with no background left to "
                        "fit the camera's motion on, the masks there are unreliable", self.name,
                        frame_ranges(self.covered), round(100 * COVER_FRACTION))
            record["covered_frames"] = self.covered
        if self.coverage:
            record["mask_coverage"] = round(float(np.mean(self.coverage)), 4)
        return record
