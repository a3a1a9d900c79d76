"""A video's geometry resumes from its last checkpoint: after a run is stopped in the middle of a video, the next
run takes the ED maps it finished from the cache, restores the scorer's state and computes exactly what an
uninterrupted run computes."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from eponet.core import rigidity_stream
from eponet.core.pipeline import Pipeline
from eponet.core.spec import parse_spec
from tests.conftest import textured_frames, write_frames


def _long_clip(folder: Path, count: int) -> Path:
    """A background moving 1 px right and 0.5 px down, and an 8x8 patch moving 3 px a frame (wrapping round)."""
    frames = textured_frames(count, (48, 64), shift=(1.0, 0.5), seed=0)
    patch = np.random.default_rng(5).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    for t, frame in enumerate(frames):
        x = 4 + (3 * t) % 48
        frame[18:26, x : x + 8] = patch
    write_frames(folder, frames)
    return folder


def _geometry_spec(path, out, cache, **rigidity):
    return parse_spec({"preset": "geometry", "input": {"path": str(path), "scale": 1.0},
                       "stages": {"rigidity": {"max_points": 150, **rigidity}},
                       "output": {"dir": str(out), "save": ["ed"]}, "run": {"chunk": 4, "lag": 6, "workers": 1},
                       "cache": {"dir": str(cache)}})


def _files(folder: Path, part: str = "") -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name != "run.json" and part in p.as_posix()}


class _Stop(KeyboardInterrupt):
    """Ctrl-C in the middle of a video."""


def _counting(pipeline, calls: list, stop_after: int | None = None):
    """Count the rigidity stage's windows (the run loop calls ``score_groups``); raise after ``stop_after`` of
    them (a run stopped half-way)."""
    stage = pipeline.stages["rigidity"]
    score = stage.score_groups

    def counted(*args, **kwargs):
        if stop_after is not None and len(calls) == stop_after:
            raise _Stop()
        calls.append(1)
        return score(*args, **kwargs)

    stage.score_groups = counted
    return pipeline


@pytest.mark.parametrize("sampling", ["guided", "uniform"])
def test_a_stopped_video_resumes_from_its_checkpoint_with_identical_maps(tmp_path, monkeypatch, sampling):
    monkeypatch.setattr(rigidity_stream, "CHECKPOINT_SECONDS", 0.0)  # a checkpoint after every block
    clip = _long_clip(tmp_path / "clip", 30)
    clean_calls: list = []
    _counting(Pipeline(_geometry_spec(clip, tmp_path / "clean", tmp_path / "cache-clean", sampling=sampling)),
              clean_calls).run()
    reference = _files(tmp_path / "clean")
    assert len(reference) == 30

    spec = _geometry_spec(clip, tmp_path / "out", tmp_path / "cache", sampling=sampling)
    with pytest.raises(_Stop):
        _counting(Pipeline(spec), [], stop_after=4).run()
    [state] = (tmp_path / "cache" / "rigidity").rglob("*-state.npz")
    assert not list((tmp_path / "cache" / "rigidity").rglob("*-index.npz"))

    resumed_calls: list = []
    manifest = _counting(Pipeline(spec), resumed_calls).run()
    entry = manifest["sequences"]["clip"]
    assert entry["frames_from_cache"]["rigidity"] >= 8  # the blocks finished before the stop
    assert "rigidity" not in entry["cached"]  # the rest was computed
    assert len(resumed_calls) < len(clean_calls) - 2
    assert _files(tmp_path / "out") == reference  # byte-identical ED maps
    assert not state.exists()  # the index replaced the checkpoint
    # the same video again, into another folder: every map from the cache
    again = Pipeline(_geometry_spec(clip, tmp_path / "again", tmp_path / "cache", sampling=sampling)).run()
    assert "rigidity" in again["sequences"]["clip"]["cached"] and _files(tmp_path / "again") == reference


def test_a_checkpoint_that_does_not_fit_is_ignored(tmp_path, monkeypatch):
    """A checkpoint from another layout (or a plugin whose state changed) is recomputed, not trusted."""
    monkeypatch.setattr(rigidity_stream, "CHECKPOINT_SECONDS", 0.0)
    monkeypatch.setattr(rigidity_stream, "CHECKPOINT_VERSION", 99)
    clip = _long_clip(tmp_path / "clip", 16)
    Pipeline(_geometry_spec(clip, tmp_path / "clean", tmp_path / "cache-clean")).run()
    spec = _geometry_spec(clip, tmp_path / "out", tmp_path / "cache")
    with pytest.raises(_Stop):
        _counting(Pipeline(spec), [], stop_after=3).run()
    monkeypatch.setattr(rigidity_stream, "CHECKPOINT_VERSION", 1)
    manifest = Pipeline(spec).run()
    assert "rigidity" not in manifest["sequences"]["clip"]["frames_from_cache"]
    assert _files(tmp_path / "out") == _files(tmp_path / "clean")


def test_state_with_other_than_arrays_and_plain_values_is_not_checkpointed():
    class Odd:
        def __init__(self):
            self.ids = np.arange(3)
            self.callback = len  # (not print: other tests may replace it)

    arrays: dict = {}
    with pytest.raises(rigidity_stream._NotCheckpointable, match="Odd.callback is a builtin_function_or_method"):
        rigidity_stream._flatten(Odd(), "state", arrays)
    fresh = type("Plain", (), {})()
    fresh.t, fresh.next_id, fresh.pos = 3, np.int64(7), np.zeros((2, 2), np.float32)
    saved = rigidity_stream._flatten(fresh, "state", arrays)
    back = type("Plain", (), {})()
    back.t, back.next_id, back.pos = 0, np.int64(0), np.ones((1, 2), np.float32)
    rigidity_stream._unflatten(back, "state", arrays, json.loads(json.dumps(saved)))
    assert back.t == 3 and type(back.next_id) is np.int64 and back.next_id == 7 and back.pos.shape == (2, 2)


_KILLABLE_RUN = ("import sys; from eponet.core import rigidity_stream; rigidity_stream.CHECKPOINT_SECONDS = 0.0; "
                 "from eponet.cli import run_main; sys.exit(run_main(sys.argv[1:]))")


def _epo_spec_file(path: Path, clip: Path, out: Path, cache: Path) -> Path:
    path.write_text(f"""
preset: epo
input: {{path: {clip}, scale: 1.0}}
stages:
  rigidity: {{max_points: 150}}
  motion_net: {{weights: epo-davis, device: cpu}}
  refiner: {{plugin: threshold}}
output: {{dir: {out}, save: [masks, ed]}}
run: {{chunk: 4, lag: 6, workers: 1}}
cache: {{dir: {cache}}}
""")
    return path


def _checkpointed_blocks(cache: Path) -> int:
    for path in (cache / "rigidity").rglob("*-state.npz"):
        try:
            with np.load(path) as data:
                return int(json.loads(str(data["__meta__"]))["blocks"])
        except (OSError, ValueError, KeyError):  # being replaced
            pass
    return 0


@pytest.mark.slow
def test_sigkill_in_the_middle_of_a_long_video_then_rerun_gives_identical_outputs(tmp_path):
    from eponet.core.spec import load_spec

    clip = _long_clip(tmp_path / "clip", 64)
    reference = Pipeline(load_spec(_epo_spec_file(tmp_path / "clean.yaml", clip, tmp_path / "clean",
                                                  tmp_path / "cache-clean"))).run()
    assert reference["sequences"]["clip"]["frames"] == 64
    spec = _epo_spec_file(tmp_path / "spec.yaml", clip, tmp_path / "out", tmp_path / "cache")
    process = subprocess.Popen([sys.executable, "-c", _KILLABLE_RUN, str(spec), "-q"], cwd=Path(__file__).parents[2],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 600
    try:
        while _checkpointed_blocks(tmp_path / "cache") < 4:
            assert process.poll() is None, f"the run ended before it could be killed: {process.stderr.read()!r}"
            assert time.monotonic() < deadline, "no checkpoint after 600 s"
            time.sleep(0.05)
        os.kill(process.pid, signal.SIGKILL)
    finally:
        process.wait(timeout=60)
    assert process.returncode == -signal.SIGKILL
    assert not (tmp_path / "out" / "clip").exists() and not (tmp_path / "out" / "run.json").exists()

    manifest = Pipeline(load_spec(spec)).run()  # the same spec again
    entry = manifest["sequences"]["clip"]
    assert entry["frames"] == 64 and "resumed" not in entry
    assert entry["frames_from_cache"]["rigidity"] >= 16  # at least the 4 blocks checkpointed before the kill
    assert entry["frames_from_cache"]["flow"] >= 16
    for part in ("/masks/", "/ed/"):
        expected = _files(tmp_path / "clean", part)
        assert len(expected) == 64 and _files(tmp_path / "out", part) == expected
    leftovers = [p for p in (tmp_path / "out").rglob("*") if p.name.startswith(".") or ".tmp" in p.name
                 or p.name.endswith(".partial")]
    assert leftovers == [] and sorted(p.name for p in (tmp_path / "out").iterdir()) == ["clip", "run.json"]
