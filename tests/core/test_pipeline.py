import json

import numpy as np
import pytest

from eponet.core.cache import Cache
from eponet.core.errors import InputError
from eponet.core.io import read_flo
from eponet.core.pipeline import Pipeline
from eponet.core.spec import parse_spec
from tests.conftest import textured_frames, write_frames


def _spec(path, out, cache_dir, **stages):
    return parse_spec({
        "preset": "geometry",
        "input": {"path": str(path), "scale": 0.5},
        "stages": {"trajectories": None, "rigidity": None, **stages},
        "output": {"dir": str(out), "save": ["flow", "panels"]},
        "cache": {"dir": str(cache_dir)},
    })


def test_outputs_at_input_size_with_eponet_naming(frames_dir, tmp_path):
    manifest = Pipeline(_spec(frames_dir, tmp_path / "out", tmp_path / "cache")).run()
    seq = tmp_path / "out" / "clip"
    forward = sorted(p.name for p in (seq / "flow" / "forward").iterdir())
    backward = sorted(p.name for p in (seq / "flow" / "backward").iterdir())
    assert forward == backward == [f"{t:05d}.flo" for t in range(4)]  # F-1 pairs, named after frame t
    flow = read_flo(seq / "flow" / "forward" / "00002.flo")
    assert flow.shape == (48, 64, 2)  # input size, though processed at scale 0.5
    inner = flow[10:-10, 10:-10]
    assert abs(inner[..., 0].mean() - 1.0) < 0.2 and abs(inner[..., 1].mean() - 0.5) < 0.2  # vectors in input px
    back = read_flo(seq / "flow" / "backward" / "00002.flo")[10:-10, 10:-10]
    assert abs(back[..., 0].mean() + 1.0) < 0.2
    assert len(list((seq / "panels").iterdir())) == 5
    run = json.loads((tmp_path / "out" / "run.json").read_text())
    assert run["seed"] == 0 and run["plugins"]["flow"]["plugin"] == "dis"
    assert run["sequences"]["clip"]["processing_size"] == [24, 32] and "flow" in run["sequences"]["clip"]["timings_s"]
    assert {"numpy", "torch", "pluggy", "python"} <= set(run["libraries"])
    assert manifest["sequences"]["clip"]["frames"] == 5


def test_cache_skips_recomputation(frames_dir, tmp_path, monkeypatch):
    spec = _spec(frames_dir, tmp_path / "out", tmp_path / "cache")
    first = Pipeline(spec).run()
    assert first["sequences"]["clip"]["cached"] == []
    calls = []
    # the same spec again is a finished run: its sequence is skipped, not recomputed
    again = Pipeline(spec).run()
    assert again["sequences"]["clip"].get("resumed") is True
    # into another folder: every flow chunk comes from the cache
    spec = _spec(frames_dir, tmp_path / "out2", tmp_path / "cache")
    pipeline = Pipeline(spec)
    original = pipeline.stages["flow"].estimate
    monkeypatch.setattr(pipeline.stages["flow"], "estimate", lambda video: calls.append(1) or original(video))
    second = pipeline.run()
    assert second["sequences"]["clip"]["cached"] == ["flow"] and calls == []
    # a different flow parameter is a different key
    third = Pipeline(_spec(frames_dir, tmp_path / "out", tmp_path / "cache", flow={"preset": "fast"})).run()
    assert third["sequences"]["clip"]["cached"] == []
    # the cache can be switched off
    off = Pipeline(_spec(frames_dir, tmp_path / "out3", tmp_path / "cache"),
                   cache=Cache(tmp_path / "cache", enabled=False)).run()
    assert off["sequences"]["clip"]["cached"] == []


def test_a_stages_resolved_settings_are_part_of_its_cache_key(frames_dir, tmp_path):
    """``precision: auto`` means bfloat16 on one CPU and float32 on another: the key of a cached stage includes what
    its ``resolved`` dict says, so machines sharing a cache never mix the two; a stage without one keeps its key."""
    pipeline = Pipeline(_spec(frames_dir, tmp_path / "out", tmp_path / "cache"))
    plain = pipeline.key("flow", "input")
    assert not hasattr(pipeline.stages["flow"], "resolved")
    keys = set()
    for precision in ("bfloat16", "float32"):
        pipeline.stages["flow"].resolved = {"device": "cpu", "precision": precision}
        keys.add(pipeline.key("flow", "input"))
    assert len(keys) == 2 and plain not in keys


def test_nothing_half_written_on_a_corrupt_frame(tmp_path):
    root = tmp_path / "davis"
    write_frames(root / "JPEGImages" / "480p" / "a", textured_frames(3))
    paths = write_frames(root / "JPEGImages" / "480p" / "b", textured_frames(3))
    paths[2].write_bytes(paths[2].read_bytes()[:60])  # valid header, truncated body
    out = tmp_path / "out"
    from eponet.core.errors import SequenceFailures

    with pytest.raises(SequenceFailures, match=r"b/00002.png"):
        Pipeline(_spec(root, out, tmp_path / "cache")).run()
    assert (out / "a" / "flow").is_dir()  # the complete sequence is there
    assert not (out / "b").exists()
    # run.json is written per finished sequence: it lists the complete one only, and the failed one
    record = json.loads((out / "run.json").read_text())
    assert list(record["sequences"]) == ["a"] and list(record["failed"]) == ["b"]
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no partial folders left


@pytest.mark.parametrize("damage", ["body", "header"])
def test_a_corrupt_frame_mid_sequence_keeps_the_frames_before_it(tmp_path, damage):
    """A corrupt frame after the first three ends its sequence there: the frames before it are processed and
    written (the same files as a run on those frames alone), and the run fails with one line naming the file
    and the frames kept (exit code 2); the other sequence is intact, and a re-run redoes only the cut one."""
    from eponet.core.errors import SequenceFailures

    root = tmp_path / "davis"
    frames = textured_frames(8)
    write_frames(root / "JPEGImages" / "480p" / "a", frames)
    paths = write_frames(root / "JPEGImages" / "480p" / "b", frames)
    # "body": a valid header and a truncated body (found when decoding); "header": not an image at all (found
    # when the folder is checked, before anything runs)
    paths[5].write_bytes(paths[5].read_bytes()[:60] if damage == "body" else b"not an image")
    out = tmp_path / "out"
    with pytest.raises(SequenceFailures) as caught:
        Pipeline(_spec(root, out, tmp_path / "cache")).run()
    assert caught.value.exit_code == 2
    assert "b/00005.png: cannot read image" in str(caught.value)
    assert "its first 5 frames (00000 to 00004) were processed and their outputs kept" in str(caught.value)
    record = json.loads((out / "run.json").read_text())
    assert list(record["sequences"]) == ["a", "b"] and list(record["failed"]) == ["b"]
    assert record["sequences"]["b"]["frames"] == 5 and record["sequences"]["a"]["frames"] == 8
    kept = sorted(p.name for p in (out / "b" / "flow" / "forward").iterdir())
    assert kept == [f"{t:05d}.flo" for t in range(4)]
    write_frames(tmp_path / "first5" / "b", frames[:5])
    Pipeline(_spec(tmp_path / "first5" / "b", tmp_path / "ref", tmp_path / "cache2")).run()
    for name in kept:
        assert (out / "b" / "flow" / "forward" / name).read_bytes() == \
            (tmp_path / "ref" / "b" / "flow" / "forward" / name).read_bytes()
    with pytest.raises(SequenceFailures):
        Pipeline(_spec(root, out, tmp_path / "cache")).run()
    again = json.loads((out / "run.json").read_text())
    assert again["sequences"]["a"].get("resumed") and not again["sequences"]["b"].get("resumed")


def test_one_sequence_cut_short_fails_with_its_own_line(tmp_path):
    paths = write_frames(tmp_path / "clip", textured_frames(6))
    paths[4].write_bytes(b"not an image")
    from eponet.core.errors import SequenceFailures

    with pytest.raises(SequenceFailures) as caught:
        Pipeline(_spec(tmp_path / "clip", tmp_path / "out", tmp_path / "cache")).run()
    assert str(caught.value) == (f"{paths[4]}: cannot read image (not an image or corrupt); the sequence ends there: "
                                 "its first 4 frames (00000 to 00003) were processed and their outputs kept")
    assert len(list((tmp_path / "out" / "clip" / "flow" / "forward").iterdir())) == 3


def test_motion_images_carry_unsaturated_ed_for_the_network_to_encode(tmp_path):
    """The pipeline hands the motion net ED scaled per video but not clipped: a small object moving on its own
    (here a 6x6 patch, about 2% of the frame) keeps its ED well above the background's 95th percentile."""
    from eponet.core.inputs import discover_sequences, load_video
    from eponet.core.motion import normalise_ed

    frames = textured_frames(6, (48, 64), shift=(1.0, 0.5), seed=0)
    patch = np.random.default_rng(5).integers(0, 256, (6, 6, 3), dtype=np.uint8)
    for t, frame in enumerate(frames):
        frame[20 : 26, 10 + 4 * t : 16 + 4 * t] = patch  # moves 4 px per frame against the background's 1
    write_frames(tmp_path / "clip", frames)
    spec = parse_spec({"preset": "geometry", "input": {"path": str(tmp_path / "clip"), "scale": 1.0},
                       "stages": {"rigidity": {"plugin": "homography"}},
                       "output": {"dir": str(tmp_path / "out"), "save": []}, "cache": {"enabled": False}})
    video = load_video(discover_sequences(spec.input.path)[0], scale=1.0)
    result = Pipeline(spec).process(video)
    ed = result.motion_images[:, 2]
    np.testing.assert_allclose(ed, normalise_ed(result.ed, saturate=False), rtol=1e-6)
    # the patch in frame 2 stays well above 1, where the paper's encoding would clip it to the background's top
    assert ed[2, 21:25, 21:25].min() > 1.5 and np.median(ed) < 0.5


def test_large_frames_are_warned_about_with_the_estimated_memory(frames_dir, tmp_path):
    from eponet.core.inputs import SequenceSource
    from eponet.core.memory import memory_warning

    spec = parse_spec({"preset": "epo", "input": {"path": str(frames_dir)}, "output": {"dir": str(tmp_path / "out")}})
    big = SequenceSource(name="big", files=[], size=(3000, 4000), count=200)
    assert memory_warning(spec, big) == (
        "big: frames of 4000x3000 px (processed at 2000x1500) need about 28.0 GiB in the run loop (run.chunk 16, "
        "run.lag 30), above the 8 GiB warning bound; a lower input.scale, run.chunk or run.lag uses less")
    assert memory_warning(spec, SequenceSource(name="hd", files=[], size=(1080, 1920), count=200)) is None
    assert memory_warning(spec, SequenceSource(name="short", files=[], size=(3000, 4000), count=10)) is None
    # in one process the next sequence's flow and geometry run beside a sequence's networks: both count
    hd = SequenceSource(name="hd", files=[], size=(1080, 1920), count=200)  # under the bound alone
    assert memory_warning(spec, hd) is None
    assert memory_warning(spec, hd, hd).startswith("hd: frames of 1920x1080 px (processed at 960x540) need about "
                                                   "9.7 GiB in the run loop with the next sequence (hd) beside it")


def test_a_second_run_keeps_the_first_runs_record_and_the_same_spec_still_resumes(frames_dir, tmp_path):
    out = tmp_path / "out"
    first = Pipeline(_spec(frames_dir, out, tmp_path / "cache")).run()
    other = Pipeline(_spec(frames_dir, out, tmp_path / "cache", flow={"preset": "fast"})).run()
    assert "resumed" not in other["sequences"]["clip"]  # a different spec recomputes
    run = json.loads((out / "run.json").read_text())
    assert run["spec"]["stages"]["flow"]["preset"] == "fast"
    assert [r["spec"]["stages"]["flow"]["preset"] for r in run["runs"]] == ["medium"]
    assert run["runs"][0]["started"] == first["started"] and run["runs"][0]["sequences"]["clip"]["frames"] == 5
    again = Pipeline(_spec(frames_dir, out, tmp_path / "cache", flow={"preset": "fast"})).run()
    assert again["sequences"]["clip"]["resumed"] is True  # the same spec again skips what it finished
    run = json.loads((out / "run.json").read_text())
    assert [r["spec"]["stages"]["flow"]["preset"] for r in run["runs"]] == ["medium", "fast"]
    assert all("runs" not in r for r in run["runs"])  # one flat list, oldest first


def test_the_next_run_removes_what_a_killed_run_left_half_written(frames_dir, tmp_path):
    out = tmp_path / "out"
    partial = out / ".clip.k3x9.partial" / "flow" / "forward"
    partial.mkdir(parents=True)
    (partial / "00000.flo").write_bytes(b"half")
    (out / ".run.ab12.tmp.json").write_text("{")
    Pipeline(_spec(frames_dir, out, tmp_path / "cache")).run()
    assert sorted(p.name for p in out.iterdir()) == ["clip", "run.json"]


def test_an_unreadable_run_record_is_kept_aside(frames_dir, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "run.json").write_text("{not json")
    manifest = Pipeline(_spec(frames_dir, out, tmp_path / "cache")).run()
    assert manifest["runs"] == [] and "resumed" not in manifest["sequences"]["clip"]
    [aside] = out.glob("run-unreadable-*.json")
    assert aside.read_text() == "{not json"


def test_run_json_is_written_before_scoring_and_keeps_a_scoring_failure(frames_dir, tmp_path, monkeypatch):
    import dataclasses

    from eponet.core.errors import InputError as ScoringError
    from eponet.core.registry import Registry

    def fail(self, spec, sequences):
        assert json.loads((spec.output.dir / "run.json").read_text())["sequences"]["clip"]["frames"] == 5
        raise ScoringError("Annotations/240p: no such folder")

    monkeypatch.setattr(Registry, "evaluate", fail)
    spec = dataclasses.replace(_spec(frames_dir, tmp_path / "out", tmp_path / "cache"), evaluate={"dataset": "davis2016"})
    with pytest.raises(ScoringError):
        Pipeline(spec).run()
    record = json.loads((tmp_path / "out" / "run.json").read_text())
    assert record["sequences"]["clip"]["frames"] == 5 and "total_seconds" in record
    assert record["evaluation"] == {"error": "InputError: Annotations/240p: no such folder"}


def test_each_finished_sequence_logs_its_stage_seconds_and_progress(frames_dir, tmp_path, caplog):
    import logging

    with caplog.at_level(logging.INFO, logger="eponet.core.pipeline"):
        Pipeline(_spec(frames_dir, tmp_path / "out", tmp_path / "cache")).run()
    lines = [r.getMessage() for r in caplog.records]
    assert any(line.startswith("clip: flow ") and " s, " in line and "5 frames in " in line for line in lines)
    assert any(line.startswith("1/1 sequences done, ") and line.endswith(" s elapsed") for line in lines)


def test_a_missing_corpus_entry_is_named_and_the_others_run(frames_dir, tmp_path, caplog):
    from eponet.core.errors import SequenceFailures

    listing = tmp_path / "corpus.txt"
    listing.write_text("clip\nlost/clip2.mp4\n")
    out = tmp_path / "out"
    with caplog.at_level("ERROR"), pytest.raises(SequenceFailures) as failure:
        Pipeline(_spec(listing, out, tmp_path / "cache")).run()
    assert failure.value.exit_code == 2 and str(failure.value).startswith("1 of 2 sequences failed (clip2: ")
    assert "corpus.txt: line 2: " in str(failure.value) and "clip2: failed: " in caplog.text
    record = json.loads((out / "run.json").read_text())
    assert list(record["sequences"]) == ["clip"] and (out / "clip" / "flow").is_dir()
    assert record["failed"]["clip2"]["exit_code"] == 2 and "lost/clip2.mp4 does not exist" in record["failed"]["clip2"]["reason"]
    with pytest.raises(SequenceFailures):  # again: the finished sequence is kept, the missing one named again
        Pipeline(_spec(listing, out, tmp_path / "cache")).run()
    assert json.loads((out / "run.json").read_text())["sequences"]["clip"]["resumed"] is True


_EDITABLE_PLUGIN = '''
import numpy as np

from eponet.core.hookspecs import StageSpec, hookimpl
from eponet.core.types import FlowPair

from .motion import SHIFT


class ShiftFlow:
    def estimate(self, video):
        frames, height, width = video.frames.shape[:3]
        forward = np.full((frames - 1, height, width, 2), SHIFT, np.float32)
        return FlowPair(forward, -forward)


@hookimpl
def eponet_stages():
    return [StageSpec(kind="flow", name="shift", factory=ShiftFlow, doc="a constant flow")]
'''


def test_an_edited_third_party_plugin_does_not_reuse_stale_cache_entries(frames_dir, tmp_path, monkeypatch):
    """A plugin installed with ``pip install -e`` and edited keeps its version; its cache keys still change, since
    they carry a fingerprint of its package's files (before, they had none and the old flow came back)."""
    import importlib
    import sys

    from eponet.core.cache import code_fingerprint
    from eponet.core.registry import Registry

    source = tmp_path / "src" / "kit_editable_flow"
    source.mkdir(parents=True)
    (source / "__init__.py").write_text("")
    (source / "plugin.py").write_text(_EDITABLE_PLUGIN)
    (source / "motion.py").write_text("SHIFT = 1.5\n")
    monkeypatch.syspath_prepend(str(tmp_path / "src"))

    def run(out: str) -> tuple[dict, np.ndarray]:
        """One run in what stands for a new process: the plugin imported afresh, the fingerprints recomputed."""
        for name in [n for n in sys.modules if n.startswith("kit_editable_flow")]:
            monkeypatch.delitem(sys.modules, name)
        code_fingerprint.cache_clear()
        registry = Registry.load(entry_points=False)
        registry._register(importlib.import_module("kit_editable_flow.plugin"), "kit-editable-flow:shift",
                           package="kit-editable-flow", version="0.1.0")
        spec = parse_spec({"preset": "geometry", "input": {"path": str(frames_dir), "scale": 1.0},
                           "stages": {"flow": {"plugin": "shift"}, "trajectories": None, "rigidity": None},
                           "output": {"dir": str(tmp_path / out), "save": ["flow"]},
                           "cache": {"dir": str(tmp_path / "cache")}}, registry=registry)
        manifest = Pipeline(spec).run()
        return manifest["sequences"]["clip"], read_flo(tmp_path / out / "clip" / "flow" / "forward" / "00000.flo")

    first, flow = run("first")
    assert first["cached"] == [] and np.allclose(flow, 1.5)
    again, flow = run("again")
    assert again["cached"] == ["flow"] and np.allclose(flow, 1.5)  # unchanged code: the cache serves it
    (source / "motion.py").write_text("SHIFT = 2.5\n")  # edited in place; the version stays 0.1.0
    edited, flow = run("edited")
    assert edited["cached"] == [] and np.allclose(flow, 2.5)
    code_fingerprint.cache_clear()


@pytest.mark.parametrize("workers", [1, 2])
def test_a_sequence_that_fails_on_its_frames_does_not_stop_the_others(tmp_path, caplog, workers):
    import dataclasses

    from eponet.core.errors import SequenceFailures

    for name in ("a", "b", "c"):
        write_frames(tmp_path / "corpus" / name, textured_frames())
    broken = tmp_path / "corpus" / "b" / "00002.png"  # among the first three: the sequence cannot run at all
    broken.write_bytes(broken.read_bytes()[:60])  # its header reads, its pixels do not: fails while running
    listing = tmp_path / "corpus" / "list.txt"
    listing.write_text("a\nb\nc\n")
    out = tmp_path / "out"
    spec = _spec(listing, out, tmp_path / "cache")
    spec = dataclasses.replace(spec, run=dataclasses.replace(spec.run, workers=workers))
    with caplog.at_level("ERROR"), pytest.raises(SequenceFailures) as failure:
        Pipeline(spec).run()
    assert failure.value.exit_code == 2 and str(failure.value).startswith("1 of 3 sequences failed (")
    assert "b/00002.png" in str(failure.value) and "b: failed: " in caplog.text
    record = json.loads((out / "run.json").read_text())
    assert sorted(record["sequences"]) == ["a", "c"] and list(record["failed"]) == ["b"]
    assert sorted(p.name for p in out.iterdir()) == ["a", "c", "run.json"]  # nothing half-written of b
    assert len(list((out / "c" / "panels").iterdir())) == 5
    # one sequence alone fails with its own error, as before
    alone = dataclasses.replace(spec, input=dataclasses.replace(spec.input, path=tmp_path / "corpus" / "b"),
                                output=dataclasses.replace(spec.output, dir=tmp_path / "alone"))
    with pytest.raises(InputError, match="00002.png"):
        Pipeline(alone).run()
