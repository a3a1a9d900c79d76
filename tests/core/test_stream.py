"""The streaming run loop computes what a whole-video composition of the same stages computes."""

import json
import threading
import time
import zlib

import numpy as np
import pytest

from eponet.core.errors import StageError
from eponet.core.inputs import discover_sequences, load_video
from eponet.core.motion import motion_images, normalise_ed
from eponet.core.pipeline import Pipeline
from eponet.core.spec import parse_spec
from eponet.core.stream import SequenceStream
from tests.conftest import textured_frames, write_frames


def _clip(folder, count=14, seed=0):
    """Textured frames with a background moving 1 px right, 0.5 px down and an 8x8 patch moving 3 px a frame."""
    frames = textured_frames(count, (48, 64), shift=(1.0, 0.5), seed=seed)
    patch = np.random.default_rng(seed + 5).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    for t, frame in enumerate(frames):
        x = 6 + 3 * t
        frame[18:26, x : x + 8] = patch[:, : max(0, min(8, 64 - x))]
    write_frames(folder, frames)
    return folder


def _spec(path, out, *, rigidity=None, run=None, preset="geometry", stages=None, save=("ed",)):
    return parse_spec({"preset": preset, "input": {"path": str(path), "scale": 1.0},
                       "stages": {"rigidity": {"plugin": "trifocal", "max_points": 300, **(rigidity or {})},
                                  **(stages or {})},
                       "output": {"dir": str(out), "save": list(save)}, "run": run or {},
                       "cache": {"enabled": False}})


def _whole_video(spec, video):
    """The reference: every stage called once on the whole video (what Pipeline.process did before streaming)."""
    pipeline = Pipeline(spec)
    stages = pipeline.stages
    flow = stages["flow"].estimate(video)
    tracks = stages["trajectories"].build(flow)
    rng = np.random.default_rng([spec.seed, zlib.crc32(video.name.encode())])
    ed = stages["rigidity"].score(tracks, flow, rng).ed
    return flow, ed, motion_images(flow, normalise_ed(ed, saturate=False))


@pytest.mark.parametrize("sampling", ["uniform", "guided"])
def test_one_window_equals_the_whole_video(tmp_path, sampling):
    """Bit for bit with plain means (the preset's shrunk means: up to float32 rounding, see below)."""
    folder = _clip(tmp_path / "clip")
    spec = _spec(folder, tmp_path / "out", rigidity={"sampling": sampling, "prior_groups": 0},
                 run={"chunk": 32, "lag": 32})
    video = load_video(discover_sequences(folder)[0], scale=1.0)
    flow, ed, images = _whole_video(spec, video)
    result = Pipeline(spec).process(video)
    np.testing.assert_array_equal(result.flow.forward, flow.forward)
    np.testing.assert_array_equal(result.flow.backward, flow.backward)
    np.testing.assert_array_equal(result.ed, ed)
    np.testing.assert_array_equal(result.motion_images, images)


@pytest.mark.parametrize("ed_window", [3, None])
def test_the_ed_scale_window_is_the_specs(tmp_path, ed_window):
    """``run.ed_window``: each frame's ED scale over that many frames around it (``null``: the whole video), as
    :func:`normalise_ed` computes it on the whole video's ED maps."""
    frames = textured_frames(14, (48, 64), shift=(1.0, 0.5), seed=0)
    patch = np.random.default_rng(5).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    for t, frame in enumerate(frames):  # a large patch, still for 7 frames, then moving 4 px a frame
        x = 6 + 4 * max(0, t - 7)
        frame[16:32, x : x + 16] = patch
    folder = tmp_path / "clip"
    write_frames(folder, frames)
    spec = _spec(folder, tmp_path / "out", run={"chunk": 4, "lag": 4, "ed_window": ed_window})
    video = load_video(discover_sequences(folder)[0], scale=1.0)
    result = Pipeline(spec).process(video)
    expected = motion_images(result.flow, normalise_ed(result.ed, window=ed_window, saturate=False))
    np.testing.assert_allclose(result.motion_images, expected, rtol=1e-6)
    default = Pipeline(_spec(folder, tmp_path / "out2", run={"chunk": 4, "lag": 4})).process(video)
    difference = np.abs(default.motion_images - result.motion_images).max()
    if ed_window is None:  # the default window (61 frames) spans these 14: the whole video's scale
        assert difference == 0
    else:  # 3 frames see the patch still or moving, not both
        assert difference > 1e-3


def test_chunks_carry_trajectories_and_means_across_windows(tmp_path):
    """Chunks of 4 frames: flow pairs, trajectories and (with uniform sampling, the same draws in the same order)
    every group's model are those of the whole video; each trajectory's mean over windows equals its mean
    over the video up to the order in which its distances are summed (the run loop accumulates each window's
    float64 sums and counts, ``RigidityStage.score_groups``)."""
    folder = _clip(tmp_path / "clip")
    spec = _spec(folder, tmp_path / "out", rigidity={"sampling": "uniform"}, run={"chunk": 4, "lag": 14})
    video = load_video(discover_sequences(folder)[0], scale=1.0)
    flow, ed, images = _whole_video(spec, video)
    result = Pipeline(spec).process(video)
    np.testing.assert_array_equal(result.flow.forward, flow.forward)
    np.testing.assert_allclose(result.ed, ed, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(result.motion_images, images, rtol=1e-5, atol=1e-6)
    assert ed.max() > 1.0  # the patch is there: not a trivially zero map


@pytest.mark.parametrize("sampling", ["guided", "area"])
def test_guided_sampling_carries_its_memory_across_windows(tmp_path, monkeypatch, sampling):
    """Guided sampling weighs each trajectory by its distances in earlier groups: with the stage's history
    carried from window to window, chunks of 4 frames sample and fit every group as the whole video does.
    Without it (each window starting afresh) the maps differ: the test can tell. Area sampling is guided
    sampling with one more weight."""
    from eponet.geometry.rigidity import RigidityStage

    folder = _clip(tmp_path / "clip")
    spec = _spec(folder, tmp_path / "out", rigidity={"sampling": sampling, "max_points": 200},
                 run={"chunk": 4, "lag": 14})
    video = load_video(discover_sequences(folder)[0], scale=1.0)
    _, ed, _ = _whole_video(spec, video)
    np.testing.assert_allclose(Pipeline(spec).process(video).ed, ed, rtol=1e-5, atol=1e-6)
    monkeypatch.delattr(RigidityStage, "new_history")  # a stage without a memory
    assert not np.allclose(Pipeline(spec).process(video).ed, ed, rtol=1e-5, atol=1e-6)


def test_a_short_lag_changes_only_what_it_cuts_off(tmp_path):
    """With lag 2, a frame is painted before the trajectories covering it have ended; the patch still stands out
    and the maps stay close to the whole video's. Plain means: shrunk ones move toward the median of the
    trajectories in flight, which is not the whole video's."""
    folder = _clip(tmp_path / "clip")
    spec = _spec(folder, tmp_path / "out", rigidity={"sampling": "uniform", "prior_groups": 0},
                 run={"chunk": 4, "lag": 2})
    video = load_video(discover_sequences(folder)[0], scale=1.0)
    _, ed, _ = _whole_video(spec, video)
    streamed = Pipeline(spec).process(video).ed
    assert streamed.shape == ed.shape
    np.testing.assert_allclose(streamed[-3:], ed[-3:], rtol=1e-5, atol=1e-6)  # the end: all trajectories final
    patch = streamed[5, 19:25, 22:28].mean()
    assert patch > 3 * np.median(streamed[5])


def test_fusion_windows_are_stitched_as_the_whole_video_is():
    from eponet.fusion.windows import window_starts, window_weights

    for frames in (5, 12, 31, 32, 33, 40, 57, 100):
        for window, overlap in ((8, 2), (8, 3), (6, 0), (32, 8)):
            starts = window_starts(frames, window, overlap)
            length = frames if len(starts) == 1 else window
            weights = window_weights(starts, length, frames, "centre")
            owner = np.full(frames, -1)
            for k, start in enumerate(starts):
                previous = starts[k - 1] if k else None
                nxt = starts[k + 1] if k + 1 < len(starts) else None
                owned = SequenceStream._owned(start, length, previous, nxt, next_is_last=k + 2 == len(starts))
                assert not (owner[start : start + length][owned] >= 0).any()
                owner[start : start + length][owned] = k
            expected = np.full(frames, -1)
            for k, start in enumerate(starts):
                expected[start : start + length][weights[k] > 0] = k
            np.testing.assert_array_equal(owner, expected, err_msg=f"{frames} frames, window {window}, {overlap}")


def test_a_stage_without_its_method_is_one_line_naming_plugin_and_method(tmp_path, monkeypatch):
    folder = _clip(tmp_path / "clip", count=4)
    spec = _spec(folder, tmp_path / "out")

    class NoScore:
        pass

    monkeypatch.setattr(spec.stages["rigidity"], "build", lambda: NoScore())
    with pytest.raises(StageError, match=r"^stages.rigidity: plugin 'trifocal' does not implement the rigidity "
                                         r"protocol: it has no method score\(\)"):
        Pipeline(spec)


def _files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
            and p.name != "run.json"}


def _three_sequences(root):
    for k, name in enumerate(("a", "b", "c")):
        _clip(root / "JPEGImages" / "480p" / name, count=6, seed=k)
    return root


def _epo(root, out, workers=1):
    return parse_spec({"preset": "epo", "input": {"path": str(root), "scale": 1.0},
                       "stages": {"rigidity": {"max_points": 300}, "refiner": {"plugin": "threshold"},
                                  "motion_net": {"device": "cpu"}},
                       "output": {"dir": str(out), "save": ["masks", "saliency", "ed"]},
                       "run": {"workers": workers, "chunk": 4}, "cache": {"enabled": False}})


def test_interrupted_run_resumes_with_identical_outputs(tmp_path, monkeypatch):
    root = _three_sequences(tmp_path / "davis")
    Pipeline(_epo(root, tmp_path / "whole")).run()
    reference = _files(tmp_path / "whole")
    assert len([k for k in reference if k.startswith("b/masks/")]) == 6

    pipeline = Pipeline(_epo(root, tmp_path / "out"))
    original = pipeline.finish_sequence
    calls = []

    def killed_after_the_first(opened):  # at the second sequence's turn, its front already running ahead
        calls.append(opened.source.name)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return original(opened)

    monkeypatch.setattr(pipeline, "finish_sequence", killed_after_the_first)
    with pytest.raises(KeyboardInterrupt):
        pipeline.run()
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a", "run.json"]  # nothing half-written
    # the fronts of b and c, opened ahead, were stopped
    assert not [t.name for t in threading.enumerate() if t.name.startswith("eponet-")]
    processed = []
    again = Pipeline(_epo(root, tmp_path / "out"))
    resumed_original = again.finish_sequence
    monkeypatch.setattr(again, "finish_sequence",
                        lambda opened: processed.append(opened.source.name) or resumed_original(opened))
    manifest = again.run()
    assert processed == ["b", "c"] and manifest["sequences"]["a"]["resumed"] is True
    assert _files(tmp_path / "out") == reference
    run = json.loads((tmp_path / "out" / "run.json").read_text())
    from eponet.core.registry import get_registry
    from eponet.weights import builtin_weights

    names = get_registry().resolve_preset("epo")["motion_net"]["weights"]
    expected = [builtin_weights()[n].sha256 for n in ([names] if isinstance(names, str) else names)]
    recorded = run["weights_sha256"]["motion_net"]
    assert ([recorded] if isinstance(recorded, str) else recorded) == expected  # every weights file used, verified
    assert run["resolved"]["motion_net"]["precision"] in ("float32", "bfloat16")  # what `auto` became, if asked


def test_next_sequence_overlaps_this_one_but_each_stage_sees_one_sequence_at_a_time(tmp_path, monkeypatch):
    root = _three_sequences(tmp_path / "davis")
    calls = []
    timed = SequenceStream._timed

    def recorded(self, kind, compute):
        start = time.perf_counter()
        try:
            return timed(self, kind, compute)
        finally:
            calls.append((kind, self.name, start, time.perf_counter()))

    monkeypatch.setattr(SequenceStream, "_timed", recorded)
    Pipeline(_epo(root, tmp_path / "out")).run()
    for kind in ("flow", "trajectories", "rigidity", "motion_net", "refiner"):
        spans = sorted((start, end, name) for k, name, start, end in calls if k == kind)
        assert [name for _, _, name in spans] == sorted(name for _, _, name in spans), kind  # a..., b..., c...
        assert all(end <= following for (_, end, _), (following, _, _) in zip(spans, spans[1:])), kind  # one at a time
    for earlier, later in (("a", "b"), ("b", "c")):  # the next video's flow ran before this one's networks were done
        assert min(s for k, n, s, _ in calls if k == "flow" and n == later) < \
            max(e for k, n, _, e in calls if k == "motion_net" and n == earlier)


def test_masks_do_not_depend_on_the_number_of_workers(tmp_path):
    root = _three_sequences(tmp_path / "davis")
    one = Pipeline(_epo(root, tmp_path / "one", workers=1)).run()
    two = Pipeline(_epo(root, tmp_path / "two", workers=2)).run()
    assert one["workers"] == 1 and two["workers"] == 2
    masks = {k: v for k, v in _files(tmp_path / "one").items() if "/masks/" in k}
    assert len(masks) == 18 and masks == {k: v for k, v in _files(tmp_path / "two").items() if "/masks/" in k}


def test_core_imports_nothing_from_geometry_evaluation_or_weights():
    import re
    from pathlib import Path

    core = Path(__file__).resolve().parents[2] / "eponet" / "core"
    pattern = re.compile(r"^\s*(from|import)\s+(eponet\.|\.\.)(geometry|evaluation|weights)\b", re.M)
    offenders = [p.name for p in core.glob("*.py") if pattern.search(p.read_text())]
    assert offenders == []


def test_plugins_command_prints_the_graph():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "eponet", "plugins", "rigidity"], capture_output=True, text=True).stdout
    assert "protocol RigidityModel.score(); consumes trajectories, flow; produces ed; context groups; cached" in out


def test_shrunk_means_in_one_window_equal_the_whole_videos(tmp_path):
    """``prior_groups``: the stream shrinks each trajectory's mean toward the median of the means in flight; with
    one window every trajectory is in flight, so the maps are the whole video's (up to float32 rounding of the
    window's means), and they differ from the plain means' (the test can tell)."""
    folder = _clip(tmp_path / "clip")
    spec = _spec(folder, tmp_path / "out", rigidity={"prior_groups": 3.0}, run={"chunk": 32, "lag": 32})
    video = load_video(discover_sequences(folder)[0], scale=1.0)
    _, ed, _ = _whole_video(spec, video)
    streamed = Pipeline(spec).process(video).ed
    np.testing.assert_allclose(streamed, ed, rtol=1e-5, atol=1e-6)
    plain = Pipeline(_spec(folder, tmp_path / "out2", rigidity={"prior_groups": 0}, run={"chunk": 32, "lag": 32}))
    plain = plain.process(video).ed
    assert np.abs(plain - streamed).max() > 0.1
