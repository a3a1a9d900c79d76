"""Flow stage ``flo``: precomputed flow read from Middlebury ``.flo`` files."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eponet.core.errors import InputError
from eponet.core.imaging import resize_flow
from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.io import read_flo
from eponet.core.params import Param
from eponet.core.types import FlowPair, Video

__all__ = ["FloFlow"]


class FloFlow:
    """Reads ``forward/<stem>.flo`` and ``backward/<stem>.flo`` for every frame but the last, from
    ``<path>/<sequence>/`` if that folder exists, else from ``<path>/``. Files are at the input frame size and
    follow eponet's naming: ``forward/<stem_t>.flo`` maps t -> t+1, ``backward/<stem_t>.flo`` maps t+1 -> t."""

    def __init__(self, *, path: str):
        self.path = Path(path)

    def estimate(self, video: Video) -> FlowPair:
        root = self.path / video.name if (self.path / video.name).is_dir() else self.path
        if not root.is_dir():
            raise InputError(f"stages.flow.path: flow folder {self.path} does not exist")
        fields = {}
        for direction in ("forward", "backward"):
            stack = []
            for stem in video.stems[:-1]:
                file = root / direction / f"{stem}.flo"
                if not file.is_file():
                    raise InputError(f"{file}: missing flow file for frame {stem} of {video.name}")
                flow = read_flo(file, expected_shape=video.size)
                if not np.isfinite(flow).all():
                    raise InputError(f"{file}: flow has unknown (NaN or >= 1e9) values")
                stack.append(resize_flow(flow, video.shape))
            fields[direction] = np.stack(stack)
        return FlowPair(fields["forward"], fields["backward"])


@hookimpl
def eponet_stages():
    return [
        StageSpec(
            kind="flow",
            name="flo",
            factory=FloFlow,
            params=(Param("path", "path", None, "folder holding forward/ and backward/ .flo files (or <sequence>/forward/...)", required=True),),
            doc="precomputed Middlebury .flo files (e.g. from RAFT or the original Full Flow pipeline)",
        )
    ]
