"""Every stage's output is checked against its kind's protocol: a violation is one line naming the kind, the
plugin and what was expected (stages deliberately broken, registered here)."""

import argparse
import math

import numpy as np
import pytest

from eponet.cli import guarded
from eponet.core.errors import StageError
from eponet.core.graph import KINDS, check_output, stage_kind
from eponet.core.hookspecs import StageSpec
from eponet.core.pipeline import Pipeline
from eponet.core.registry import Registry
from eponet.core.spec import parse_spec
from eponet.core.types import FlowPair, RigidityResult, TrackFrame, Trajectories
from tests.conftest import textured_frames, write_frames

SHAPE = (24, 32)


# -- stages that keep their protocols (cheap stand-ins for the real ones) ----------------------------------
class ZeroFlow:
    def estimate(self, video):
        zeros = np.zeros((video.num_frames - 1, *video.shape, 2), np.float32)
        return FlowPair(zeros, zeros.copy())


class ZeroDistance:
    def score(self, trajectories, flow, rng):
        return RigidityResult(ed=np.zeros(trajectories.labels.shape, np.float32))


class HalfSure:
    def predict(self, motion_images):
        return np.full((motion_images.shape[0], *motion_images.shape[2:]), 0.6, np.float32)


class NoFeatures:
    def features(self, video):
        h, w = video.shape
        return np.zeros((video.num_frames, 0, math.ceil(h / 8), math.ceil(w / 8)), np.float32)


class MotionOnly:
    def fuse(self, features, saliency):
        return saliency


class Threshold:
    def refine(self, frames, probability):
        return (probability > 0.5).astype(np.uint8)


def _dense():
    from eponet.plugins.trajectories.dense import DenseTrajectories

    class WholeVideo:  # the builder without stream(): its build() output is what the loop checks
        def build(self, flow):
            return DenseTrajectories().build(flow)

    return WholeVideo()


GOOD = {"flow": ZeroFlow, "trajectories": _dense, "rigidity": ZeroDistance, "motion_net": HalfSure,
        "appearance": NoFeatures, "fusion": MotionOnly, "refiner": Threshold}

#: kind -> (how its broken plugin spoils the good output, the error's tail)
BROKEN = {
    "flow": (lambda f: FlowPair(f.forward.astype(np.float64), f.backward.astype(np.float64)),
             "forward flow: expected dtype float32, got float64"),
    "trajectories": (lambda t: Trajectories(t.start, t.length, t.offsets, t.positions, t.labels.astype(np.int64)),
                     "labels: expected dtype int32, got int64"),
    "rigidity": (lambda r: RigidityResult(ed=r.ed - 1.0), "ed with values in [-1, -1], expected >= 0"),
    "motion_net": (lambda p: p * 2, "saliency with values in [1.2, 1.2], expected [0, 1]"),
    "appearance": (lambda f: f[:-1], "features: expected size 4 on axis 0 of [4, 'C', 'h', 'w'], got shape (3, 0, 3, 4)"),
    "fusion": (lambda p: p[:, :, :-1], "fused: expected size 32 on axis 2 of [4, 24, 32], got shape (4, 24, 31)"),
    "refiner": (lambda m: m.astype(np.float32) * 0.99, "masks: expected dtype uint8, got float32"),
}


def _broken(kind):
    spoil = BROKEN[kind][0]
    method = stage_kind(kind).method

    def factory():
        good = GOOD[kind]()
        stage = type(f"Broken{kind.title()}", (), {})()
        setattr(stage, method, lambda *args: spoil(getattr(good, method)(*args)))
        return stage

    return factory


def _registry():
    registry = Registry.load(entry_points=False)
    for kind in KINDS:
        registry.add(StageSpec(kind=kind, name="good", factory=GOOD[kind], package="tests"))
        registry.add(StageSpec(kind=kind, name="broken", factory=_broken(kind), package="tests"))
    return registry


def _spec(tmp_path, broken):
    write_frames(tmp_path / "clip", textured_frames(4, SHAPE))
    stages = {kind: {"plugin": "broken" if kind == broken else "good"} for kind in KINDS}
    return parse_spec({"preset": "geometry", "input": {"path": str(tmp_path / "clip"), "scale": 1.0},
                       "stages": stages, "output": {"dir": str(tmp_path / "out"), "save": ["masks"]},
                       "run": {"workers": 1, "chunk": 4}, "cache": {"enabled": False}}, registry=_registry())


def test_the_good_stand_ins_run(tmp_path):
    Pipeline(_spec(tmp_path, None)).run()
    assert len(list((tmp_path / "out" / "clip" / "masks").iterdir())) == 4


@pytest.mark.parametrize("kind", KINDS)
def test_a_stage_breaking_its_protocol_is_one_line_naming_kind_plugin_and_expectation(tmp_path, kind):
    with pytest.raises(StageError) as caught:
        Pipeline(_spec(tmp_path, kind)).run()
    assert str(caught.value) == f"clip: stage {kind} (plugin 'broken') returned {BROKEN[kind][1]}"
    assert not (tmp_path / "out" / "clip").exists()  # nothing half-written


def test_on_the_command_line_a_float_refiner_is_one_line_and_exit_1(tmp_path, capsys):
    """It used to write masks of value 254 and exit 0."""
    spec = _spec(tmp_path, "refiner")
    code = guarded(lambda args: Pipeline(spec).run() and 0, argparse.Namespace(verbose=False))
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert err.splitlines() == ["error: clip: stage refiner (plugin 'broken') returned masks: expected dtype uint8, "
                                "got float32"]


def _frame(**change):
    fields = {"t": 1, "ids": np.arange(4, dtype=np.int32), "positions": np.zeros((4, 2), np.float32),
              "labels": np.zeros((2, 2), np.int32)}
    return TrackFrame(**{**fields, **change})


@pytest.mark.parametrize("value, problem", [
    (_frame(), None),
    (_frame(labels=np.full((2, 2), -1, np.int32)), "labels with values in [-1, -1], expected >= 0"),
    (_frame(positions=np.zeros((3, 2), np.float32)), "positions: expected size 4 on axis 0 of [4, 2], got shape (3, 2)"),
    ((np.zeros((2, 2), np.int32),), "a tuple, expected Trajectories (build) or a TrackFrame (a stream's first / push)"),
])
def test_a_stream_frame_of_trajectories_is_checked(value, problem):
    expected = f"stage trajectories (plugin 'p') returned {problem}" if problem else None
    assert check_output("trajectories", "p", value, frames=None, shape=(2, 2)) == expected


@pytest.mark.parametrize("kind, value, problem", [
    ("flow", FlowPair(np.full((2, 2, 2, 2), np.nan, np.float32), np.zeros((2, 2, 2, 2), np.float32)),
     "forward flow with NaN or infinite values, expected finite values"),
    ("rigidity", RigidityResult(np.zeros((2, 2, 2), np.float32), per_trajectory=np.zeros(3, np.float32)),
     "per_trajectory: expected size 5 on axis 0 of [5], got shape (3,)"),
    ("rigidity", RigidityResult(np.full((2, 2, 2), np.inf, np.float32)),
     "ed with NaN or infinite values, expected finite values"),
    ("rigidity", (np.ones(5), np.ones(5, np.int32), [{"frames": [0, 1, 2], "model": "trifocal"}]), None),
    ("rigidity", (np.full(5, np.nan), np.ones(5, np.int32), []), "sums with NaN or infinite values, expected finite "
     "values"),
    ("rigidity", (np.ones(5), np.ones(4, np.int32), []), "counts: expected size 5 on axis 0 of [5], got shape (4,)"),
    ("rigidity", (np.ones(5), np.ones(5, np.int32), [{"model": "trifocal"}]),
     "records that are not a list of dicts with frames, expected one per frame group"),
    ("rigidity", (np.ones(5), np.ones(5, np.int32)), "a tuple, expected (sums, counts, records) from score_groups"),
    ("motion_net", [[[0.5]]], "saliency as a list, expected a numpy float32 array [2, 2, 2]"),
    ("motion_net", np.full((2, 2, 2), np.nan, np.float32), "saliency with NaN or infinite values, expected finite values"),
    ("refiner", np.full((2, 2, 2), 255, np.uint8), "masks with values in [255, 255], expected <= 1"),
    ("refiner", np.ones((2, 2, 2), np.uint8), None),
    ("fusion", np.ones((2, 2, 2), np.float32), None),
])
def test_outputs_are_checked_against_their_protocol(kind, value, problem):
    expected = f"stage {kind} (plugin 'p') returned {problem}" if problem else None
    assert check_output(kind, "p", value, frames=2, shape=(2, 2), trajectories=5) == expected
