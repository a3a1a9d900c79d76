import textwrap
from pathlib import Path

import pytest

from eponet.core.errors import SpecError
from eponet.core.spec import apply_overrides, load_spec, parse_spec


def _flow_only(frames_dir, out, **extra):
    doc = {
        "preset": "geometry",
        "input": {"path": str(frames_dir), "scale": 1.0},
        "stages": {"trajectories": None, "rigidity": None},
        "output": {"dir": str(out), "save": ["flow"]},
    }
    doc.update(extra)
    return doc


FLOW = {"preset": "medium", "finest_scale": 0, "patch_stride": None, "refinement_iterations": None,
        "backward_finest_scale": None}


def test_valid_spec_resolves_defaults(frames_dir, tmp_path):
    spec = parse_spec(_flow_only(frames_dir, tmp_path / "out"))
    assert list(spec.stages) == ["flow"]
    assert spec.stages["flow"].plugin == "dis" and spec.stages["flow"].params == FLOW
    assert spec.input.scale == 1.0 and spec.input.resolution == "480p" and spec.seed == 0
    assert spec.document["stages"] == {"flow": {"plugin": "dis", **FLOW}}


def test_every_problem_is_reported_at_once(frames_dir, tmp_path):
    doc = {
        "preset": "geometry",
        "input": {"path": str(tmp_path / "nowhere"), "scale": 0},
        "stages": {"refiner": {"plugin": "densecrf", "iterations": "five"}, "flow": {"plugin": "diss"}, "colour": {}},
        "output": {"dir": str(tmp_path / "o"), "save": ["maks"]},
        "extra": 1,
        "seed": -3,
    }
    with pytest.raises(SpecError) as info:
        parse_spec(doc)
    problems = info.value.problems
    expected = [
        "extra: unknown top-level key",
        "input.scale: expected a number in (0, 1], got 0",
        f"input.path: {tmp_path / 'nowhere'} does not exist",
        "seed: expected a non-negative integer, got -3",
        "output.save: unknown output 'maks' (did you mean 'masks'?)",
        "stages.colour: unknown stage kind",
        "stages.flow.plugin: unknown flow plugin 'diss' (did you mean 'dis'?); available: dis, farneback, flo",
        'stages.refiner.iterations: expected a positive integer, got "five"',
        "stages.refiner: needs a motion_net or fusion stage",
    ]
    for text in expected:
        assert any(p.startswith(text) for p in problems), (text, problems)


def test_preset_override_merges_parameters(frames_dir, tmp_path):
    doc = _flow_only(frames_dir, tmp_path / "o")
    doc["stages"]["flow"] = {"preset": "fast"}
    assert parse_spec(doc).stages["flow"].params == {**FLOW, "preset": "fast"}
    doc["stages"]["flow"] = {"finest_scale": None}  # back to OpenCV's own finest level for the preset
    assert parse_spec(doc).stages["flow"].params == {**FLOW, "finest_scale": None}
    doc["stages"]["flow"] = {"plugin": "farneback", "levels": 3}
    params = parse_spec(doc).stages["flow"].params
    assert params["levels"] == 3 and params["winsize"] == 15 and "preset" not in params


def test_unknown_preset_suggests(frames_dir, tmp_path):
    with pytest.raises(SpecError, match=r"preset: unknown preset 'geometri' \(did you mean 'geometry'\?\)"):
        parse_spec(_flow_only(frames_dir, tmp_path / "o", preset="geometri"))


def test_an_unknown_preset_is_the_only_problem_reported(frames_dir, tmp_path):
    """Without the preset's stages nothing can be said of what the composition lacks (a flow stage, the producers
    of the saved outputs, masks to score): one line, not a cascade."""
    doc = _flow_only(frames_dir, tmp_path / "o", preset="epo+fin")
    doc["stages"] = {}
    doc["output"]["save"] = ["masks", "saliency", "ed"]
    doc["evaluate"] = {"dataset": "generic", "masks": str(frames_dir)}
    with pytest.raises(SpecError) as caught:
        parse_spec(doc)
    assert caught.value.problems == [
        "preset: unknown preset 'epo+fin' (did you mean 'epo+fine'?); presets: geometry, epo, epo-st, epo+, epo+fine"]


def test_missing_plugin_of_a_preset_is_reported(frames_dir, tmp_path):
    doc = _flow_only(frames_dir, tmp_path / "o")
    doc["stages"] = {"trajectories": None, "rigidity": None, "motion_net": {"plugin": "nonexistent_net"}}
    with pytest.raises(SpecError, match=r"stages.motion_net.plugin: unknown motion_net plugin 'nonexistent_net'"):
        parse_spec(doc)


def test_outputs_need_their_stage(frames_dir, tmp_path):
    with pytest.raises(SpecError, match=r"output.save: 'masks' needs a refiner stage"):
        parse_spec(_flow_only(frames_dir, tmp_path / "o", output={"dir": str(tmp_path / "o"), "save": ["masks"]}))


def test_unwritable_output(frames_dir, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(SpecError, match=r"output.dir: .*file exists and is not a folder"):
        parse_spec(_flow_only(frames_dir, blocker / "out"))


def test_yaml_syntax_error_has_line_and_column(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("preset: epo\ninput: {path: x\n  scale: 0.5\n")
    with pytest.raises(SpecError) as info:
        load_spec(path)
    assert str(info.value).startswith(f"{path}: line ")
    assert "column" in str(info.value) and "YAML syntax error" in str(info.value)


def test_spec_must_be_a_mapping(tmp_path):
    path = tmp_path / "list.yaml"
    path.write_text("- a\n- b\n")
    with pytest.raises(SpecError, match="expected a mapping"):
        load_spec(path)


def test_set_overrides_and_relative_paths(frames_dir, tmp_path, monkeypatch):
    spec_dir = tmp_path / "specs"
    spec_dir.mkdir()
    (spec_dir / "s.yaml").write_text(textwrap.dedent(f"""
        preset: geometry
        input: {{path: {frames_dir}}}
        stages: {{trajectories: null, rigidity: null}}
        output: {{dir: runs/x, save: [flow]}}
    """))
    spec = load_spec(spec_dir / "s.yaml", ["stages.flow.preset=ultrafast", "input.scale=0.25", "seed=7"])
    assert spec.stages["flow"].params["preset"] == "ultrafast"
    assert spec.input.scale == 0.25 and spec.seed == 7
    assert spec.output.dir == spec_dir / "runs" / "x"  # relative to the spec file
    monkeypatch.chdir(tmp_path)
    spec = load_spec(spec_dir / "s.yaml", ["output.dir=elsewhere"])
    assert spec.output.dir == tmp_path / "elsewhere"  # --set values are relative to the current folder
    with pytest.raises(SpecError, match=r"stages.flow.preset: expected one of"):
        load_spec(spec_dir / "s.yaml", ["stages.flow.preset=slow"])


def test_malformed_override():
    with pytest.raises(SpecError, match=r"--set nonsense: expected key.path=value"):
        apply_overrides({}, ["nonsense"])


def _davis_input(root, resolutions=("480p",), sequences=("bear", "dog")):
    """A DAVIS-layout input root: frames at 240p, annotations at ``resolutions``."""
    from tests.conftest import textured_frames, write_frames

    for seq in sequences:
        write_frames(root / "JPEGImages" / "240p" / seq, textured_frames(4), suffix=".jpg")
        for resolution in resolutions:
            write_frames(root / "Annotations" / resolution / seq, textured_frames(4))
    return root


def _evaluated(root, out, **input_extra):
    return {"preset": "epo", "input": {"path": str(root), "resolution": "240p", **input_extra},
            "output": {"dir": str(out)}, "evaluate": {"dataset": "davis2016"}}


def test_evaluation_without_its_annotations_fails_at_validation(tmp_path):
    root = _davis_input(tmp_path / "DAVIS")
    with pytest.raises(SpecError) as info:
        parse_spec(_evaluated(root, tmp_path / "out"))
    (problem,) = info.value.problems
    assert "Annotations/240p: no such folder" in problem and "resolutions here: 480p" in problem
    assert "\n" not in problem


def test_evaluation_sequence_typo_suggests_the_nearest_name(tmp_path):
    root = _davis_input(tmp_path / "DAVIS", resolutions=("240p",))
    with pytest.raises(SpecError, match="did you mean 'bear'"):
        parse_spec(_evaluated(root, tmp_path / "out", sequences=["baer"]))


def test_evaluation_with_max_frames_is_valid(tmp_path):
    root = _davis_input(tmp_path / "DAVIS", resolutions=("240p",))
    spec = parse_spec(_evaluated(root, tmp_path / "out", max_frames=3))
    assert spec.input.max_frames == 3 and spec.evaluate["dataset"] == "davis2016"


def test_evaluation_at_another_resolution_than_the_masks_fails_at_validation(tmp_path):
    root = _davis_input(tmp_path / "DAVIS")
    document = _evaluated(root, tmp_path / "out")
    document["evaluate"]["resolution"] = "480p"
    with pytest.raises(SpecError, match=r"evaluate.resolution: masks are written at the input frames' size \(240p\)"):
        parse_spec(document)


def test_input_path_may_be_a_glob_that_must_match(frames_dir, tmp_path):
    spec = parse_spec(_flow_only(frames_dir.parent / "cl*", tmp_path / "out"))
    assert spec.input.path == frames_dir.parent / "cl*" and spec.run.executor == "local" and spec.run.address is None
    with pytest.raises(SpecError, match=r"input.path: no file or folder matches .*/nothing\*"):
        parse_spec(_flow_only(tmp_path / "nothing*", tmp_path / "out"))
    with pytest.raises(SpecError, match=r"run.executor: expected one of 'local', 'ray', got \"dask\""):
        parse_spec(_flow_only(frames_dir, tmp_path / "out", run={"executor": "dask"}))
