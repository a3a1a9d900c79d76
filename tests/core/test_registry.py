import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from eponet.core.errors import DuplicatePlugin, PluginNotFound
from eponet.core.hookspecs import StageSpec
from eponet.core.graph import GRAPH, KINDS, check_stage, stage_kind
from eponet.core.registry import Registry, get_registry

REPO = Path(__file__).resolve().parents[2]


def test_builtins_are_registered_with_their_package():
    registry = get_registry()
    assert {"dis", "farneback", "flo"} <= set(registry.names("flow"))
    assert {"threshold", "densecrf"} <= set(registry.names("refiner"))
    assert registry.stages[("flow", "dis")].package == "eponet"
    assert registry.manager.is_registered(sys.modules["eponet.plugins.flow.dis"])


def test_every_builtin_satisfies_its_kind_protocol():
    registry = get_registry()
    for (kind, name), spec in registry.stages.items():
        if spec.package != "eponet":
            continue
        method = stage_kind(kind).method
        factory = getattr(spec.factory, "func", spec.factory)  # a class, or a functools.partial of one
        assert callable(getattr(factory, method, None)), f"{kind}/{name} lacks {method}()"
        params = {p.name: p.default for p in spec.params}
        if name == "flo":
            params["path"] = "."
        if spec.check is not None and spec.check(params):
            continue  # needs a file (e.g. weights) that the defaults do not name
        stage = spec.factory(**params)
        assert isinstance(stage, stage_kind(kind).protocol), f"{kind}/{name}"
        assert check_stage(kind, name, stage) is None
        # schema defaults equal the constructor's keyword defaults
        import inspect

        defaults = {k: v.default for k, v in inspect.signature(spec.factory).parameters.items()
                    if v.default is not inspect.Parameter.empty}
        for param in spec.params:
            if param.name in defaults:
                assert defaults[param.name] == param.default, f"{kind}/{name}.{param.name}"


def test_presets_cover_the_default_compositions():
    registry = get_registry()
    assert set(registry.presets) >= {"geometry", "epo", "epo+"}
    assert list(registry.resolve_preset("geometry")) == ["flow", "trajectories", "rigidity"]
    assert set(registry.resolve_preset("epo")) == {"flow", "trajectories", "rigidity", "motion_net", "refiner"}
    assert set(registry.resolve_preset("epo+")) == set(registry.resolve_preset("epo")) | {"appearance", "fusion"}


def test_unknown_name_lists_available_and_suggests():
    with pytest.raises(PluginNotFound) as info:
        get_registry().get("flow", "farnback", path="stages.flow.plugin")
    message = str(info.value)
    assert "stages.flow.plugin: unknown flow plugin 'farnback' (did you mean 'farneback'?)" in message
    assert "available: dis, farneback, flo" in message


def test_a_plugin_of_another_kind_is_named_as_such():
    """``refiner: {plugin: dis}`` said only "unknown refiner plugin"; the registry knows every kind's names."""
    with pytest.raises(PluginNotFound) as info:
        get_registry().get("refiner", "dis", path="stages.refiner.plugin")
    assert str(info.value) == ("stages.refiner.plugin: 'dis' is a flow plugin, not a refiner plugin; refiner plugins: "
                               "densecrf, threshold")
    with pytest.raises(PluginNotFound, match=r"'none' is an appearance plugin, not a motion_net plugin; motion_net "
                                             r"plugins: epo_unet$"):
        get_registry().get("motion_net", "none")


def test_unknown_kind():
    with pytest.raises(PluginNotFound, match=r"unknown stage kind 'refine' \(did you mean 'refiner'\?\)"):
        get_registry().get("refine", "densecrf")


def test_duplicate_name_is_an_error():
    registry = Registry()
    spec = StageSpec(kind="flow", name="dis", factory=object, package="one")
    registry.add(spec)
    with pytest.raises(DuplicatePlugin, match="duplicate flow plugin 'dis': provided by both one and two"):
        registry.add(StageSpec(kind="flow", name="dis", factory=object, package="two"))


def _site_with(tmp_path: Path, name: str, module_source: str | None, entry: str) -> Path:
    """A folder usable on PYTHONPATH holding a fake installed distribution with an eponet.plugins entry point."""
    site = tmp_path / "site"
    dist = site / f"{name.replace('-', '_')}-1.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text(f"[eponet.plugins]\n{entry}\n")
    if module_source is not None:
        module = entry.split("=")[1].strip()
        (site / f"{module}.py").write_text(textwrap.dedent(module_source))
    return site


def _run(code: str, site: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)


def test_broken_third_party_plugin_is_named_and_others_keep_working(tmp_path):
    site = _site_with(tmp_path, "eponet-broken", "raise ImportError('needs libfoo')\n", "broken = broken_plugin")
    code = ("from eponet.core.registry import get_registry\n"
            "r = get_registry(); print(sorted(r.failed.items())); print(r.names('flow'))")
    result = _run(code, site)
    assert result.returncode == 0, result.stderr
    assert "[('eponet-broken', 'ImportError: needs libfoo')]" in result.stdout
    assert "['dis', 'farneback', 'flo']" in result.stdout


def test_third_party_duplicate_is_an_error(tmp_path):
    source = """
        from eponet.core.hookspecs import StageSpec, hookimpl
        @hookimpl
        def eponet_stages():
            return [StageSpec(kind="flow", name="dis", factory=object)]
    """
    site = _site_with(tmp_path, "eponet-dup", source, "dup = dup_plugin")
    result = _run("from eponet.core.registry import get_registry; get_registry()", site)
    assert result.returncode != 0
    assert "duplicate flow plugin 'dis': provided by both eponet and eponet-dup" in result.stderr


@pytest.mark.slow
def test_example_plugin_package_installs_and_runs(tmp_path, frames_dir):
    """Install examples/plugins/eponet-flow-example (into a private folder) and run a spec that uses it."""
    target = tmp_path / "site"
    install = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", "--target", str(target),
         str(REPO / "examples" / "plugins" / "eponet-flow-example")],
        capture_output=True, text=True, timeout=300,
    )
    assert install.returncode == 0, install.stderr
    spec = tmp_path / "spec.yaml"
    out = tmp_path / "out"
    spec.write_text(textwrap.dedent(f"""
        preset: geometry
        input: {{path: {frames_dir}, scale: 1.0}}
        stages:
          flow: {{plugin: dis_fine, patch_size: 8}}
          trajectories: null
          rigidity: null
        output: {{dir: {out}, save: [flow]}}
        cache: {{enabled: false}}
    """))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(target), os.environ.get("PYTHONPATH", "")])}
    listing = subprocess.run([sys.executable, "-m", "eponet", "plugins", "flow"], capture_output=True, text=True, env=env)
    assert "dis_fine  [eponet-flow-example 0.1.0]" in listing.stdout
    result = subprocess.run([sys.executable, "-m", "eponet.run", str(spec), "-q"], capture_output=True, text=True,
                            env=env, timeout=300)
    assert result.returncode == 0, result.stderr
    from eponet.core.io import read_flo

    flow = read_flo(out / "clip" / "flow" / "forward" / "00001.flo")
    # the frames' content translates by (1.0, 0.5) px per frame
    inner = flow[8:-8, 8:-8]
    assert abs(float(inner[..., 0].mean()) - 1.0) < 0.1 and abs(float(inner[..., 1].mean()) - 0.5) < 0.1
    import json

    manifest = json.loads((out / "run.json").read_text())
    assert manifest["plugins"]["flow"] == {"plugin": "dis_fine", "package": "eponet-flow-example", "version": "0.1.0",
                                           "params": {"patch_size": 8, "refinement_iterations": 10}}


def test_kinds_are_the_seven_of_the_method():
    assert KINDS == ("flow", "trajectories", "rigidity", "motion_net", "appearance", "fusion", "refiner")
