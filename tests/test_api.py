"""The Python API: ``eponet.run`` and ``eponet.segment`` (README, "Python API")."""

import importlib
import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

import eponet
from eponet.core.errors import InputError, SpecError
from tests.conftest import REPO, textured_frames, write_frames
from tests.geometry.scenes import parallax_scene

FLOW_ONLY = {"preset": "geometry", "stages": {"trajectories": None, "rigidity": None}}


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("EPONET_CACHE", str(tmp_path / "cache"))


def test_import_is_light_and_exposes_the_api():
    assert {"run", "segment", "Segmentation"} <= set(eponet.__all__)
    assert all(callable(getattr(eponet, name)) for name in eponet.__all__ if name != "__version__")
    loaded = subprocess.run([sys.executable, "-c", "import sys, eponet; print('torch' in sys.modules, "
                             "'eponet.core.pipeline' in sys.modules)"], capture_output=True, text=True, cwd=REPO)
    assert loaded.stdout.split() == ["False", "False"]
    importlib.import_module("eponet.run")  # the ``python -m eponet.run`` program: eponet.run stays the function
    assert eponet.run is importlib.import_module("eponet.api").run


def test_run_with_a_dict_returns_the_manifest_of_run_json(frames_dir, tmp_path):
    out = tmp_path / "out"
    manifest = eponet.run({**FLOW_ONLY, "input": {"path": str(frames_dir)}, "output": {"dir": str(out), "save": ["flow"]}})
    assert manifest == json.loads((out / "run.json").read_text())
    assert manifest["sequences"]["clip"]["frames"] == 5 and manifest["plugins"]["flow"]["plugin"] == "dis"
    assert manifest["invocation"] == {"api": "eponet.run", "overrides": {}}


def test_run_with_a_path_and_overrides(frames_dir, tmp_path):
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump({**FLOW_ONLY, "input": {"path": "clip"},
                                    "output": {"dir": "out", "save": ["flow"]}}))
    manifest = eponet.run(spec, set={"stages.flow.preset": "fast"}, **{"input.max_frames": 3})
    assert manifest == json.loads((tmp_path / "out" / "run.json").read_text())  # relative to the spec file
    assert manifest["sequences"]["clip"]["frames"] == 3
    assert manifest["plugins"]["flow"]["params"]["preset"] == "fast"
    assert manifest["invocation"]["overrides"] == {"stages.flow.preset": "fast", "input.max_frames": 3}


def test_run_with_a_parsed_spec_and_an_override(frames_dir, tmp_path):
    from eponet.core.spec import parse_spec

    spec = parse_spec({**FLOW_ONLY, "input": {"path": str(frames_dir)},
                       "output": {"dir": str(tmp_path / "out"), "save": ["flow"]}})
    manifest = eponet.run(spec, **{"input.max_frames": 4})
    assert manifest["sequences"]["clip"]["frames"] == 4 == manifest["spec"]["input"]["max_frames"]


def test_run_errors_are_typed_not_system_exit(frames_dir, tmp_path):
    spec = {"input": {"path": str(frames_dir)}, "output": {"dir": str(tmp_path / "out")}}
    with pytest.raises(SpecError, match=r'^stages.refiner.iterations: expected a positive integer, got "five"$'):
        eponet.run(spec, **{"stages.refiner.iterations": "five"})
    with pytest.raises(SpecError, match="cannot read spec"):
        eponet.run(tmp_path / "nope.yaml")
    with pytest.raises(SpecError, match="expected a spec file path, a dict or a Spec, got int"):
        eponet.run(3)


def _jaccard(masks, truth):
    inter = (masks.astype(bool) & truth).sum((1, 2))
    return inter / np.maximum((masks.astype(bool) | truth).sum((1, 2)), 1)


def test_segment_an_array_finds_the_moving_object():
    """The parallax scene (a camera passing near rigid rocks, an object moving behind them): EpO's saliency with
    a threshold refiner (the CRF is slower) gives J 0.70-0.75 per frame against the exact ground truth."""
    scene = parallax_scene(num_frames=6)
    result = eponet.segment(scene.frames, "epo", refiner={"plugin": "threshold"}, device="cpu")
    assert result.masks.shape == result.saliency.shape == result.ed.shape == scene.masks.shape
    assert result.masks.dtype == np.uint8 and set(np.unique(result.masks)) <= {0, 1}
    assert result.saliency.dtype == np.float32 and 0 <= result.saliency.min() and result.saliency.max() <= 1
    assert _jaccard(result.masks, scene.masks).min() > 0.6
    assert result.manifest["plugins"]["refiner"]["plugin"] == "threshold"
    assert result.manifest["plugins"]["motion_net"]["params"]["device"] == "cpu"
    assert result.manifest["sequences"]["video"]["processing_size"] == [90, 120]


def test_segment_a_list_and_a_folder_give_the_arrays_results(tmp_path):
    frames = textured_frames(5, (48, 64))
    options = dict(preset="geometry", scale=1.0, max_frames=4)
    whole = eponet.segment(frames, **options)
    assert whole.ed.shape == (4, 48, 64) and whole.saliency is None
    listed = eponet.segment(list(frames), **options)
    folder = eponet.segment(write_frames(tmp_path / "clip", frames)[0].parent, **options)
    np.testing.assert_array_equal(listed.ed, whole.ed)
    np.testing.assert_array_equal(folder.ed, whole.ed)  # PNG frames are lossless
    assert folder.manifest["sequences"]["clip"]["frames"] == 4


@pytest.mark.parametrize("video, error, message", [
    (np.zeros((4, 32, 32, 3)), InputError, r"video: frame 0 is a float64 array of shape \(32, 32, 3\); expected uint8"),
    (np.zeros((2, 32, 32, 3), np.uint8), InputError, r"video: 2 frame\(s\), the pipeline needs at least 3"),
    ([np.zeros((32, 32, 3), np.uint8)] * 2 + [np.zeros((16, 32, 3), np.uint8)], InputError,
     "video: frame 2 is 32x16 but the first frame is 32x32"),
    (42, InputError, "expected a path, a list of frames or a"),
    ("no/such/clip.mp4", SpecError, "input.path: .*no/such/clip.mp4 does not exist"),
])
def test_segment_bad_input_is_a_typed_one_line_error(video, error, message):
    with pytest.raises(error, match=message) as caught:
        eponet.segment(video, "geometry")
    assert "\n" not in str(caught.value)


def test_segment_bad_stage_names_the_spec_path():
    with pytest.raises(SpecError, match=r"stages.refinr: unknown stage kind \(did you mean 'refiner'\?\)"):
        eponet.segment(textured_frames(3), "geometry", refinr={"plugin": "threshold"})


def test_readme_example(tmp_path, monkeypatch, capsys):
    """The README's "Python API" example runs as written from the repository root (its output folder moved)."""
    readme = (REPO / "README.md").read_text()
    section = readme[readme.index("## Python API"):]
    code = section[section.index("```python\n") + 10 : section.index("```\n", section.index("```python"))]
    monkeypatch.chdir(REPO)
    exec(code.replace('"runs/api-demo"', repr(str(tmp_path / "out"))), {})
    lines = capsys.readouterr().out.splitlines()
    frames, j = lines[0].split()
    assert frames == "5" and float(j) > 0.5
    assert lines[1].startswith("(5, 240, 427) float32 ")
    assert json.loads((tmp_path / "out" / "run.json").read_text())["sequences"]["demo"]["frames"] == 5
