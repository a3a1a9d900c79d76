"""The stage registry: built-in and third-party plugins, registered with pluggy, and the presets."""

from __future__ import annotations

import difflib
import importlib
import logging
from dataclasses import dataclass, field, replace
from importlib import metadata
from pathlib import Path

import pluggy
import yaml

from . import hookspecs
from .errors import DuplicatePlugin, EponetError, PluginLoadError, PluginNotFound
from .hookspecs import PROJECT, StageSpec
from .graph import KINDS

__all__ = ["ENTRY_POINT_GROUP", "REGISTRY_FILE", "Registry", "get_registry", "nearest"]

log = logging.getLogger(__name__)

ENTRY_POINT_GROUP = "eponet.plugins"
REGISTRY_FILE = Path(__file__).resolve().parent.parent / "registry.yaml"


def nearest(name: str, candidates: list[str]) -> str | None:
    """The candidate closest to ``name`` (for "did you mean ...?" hints), or ``None``."""
    lowered = {c.lower(): c for c in candidates}
    match = difflib.get_close_matches(name.lower(), list(lowered), n=1, cutoff=0.5)
    return lowered[match[0]] if match else None


@dataclass
class Registry:
    """All known stages by ``(kind, name)``, the presets, and the plugin packages that failed to load."""

    stages: dict[tuple[str, str], StageSpec] = field(default_factory=dict)
    presets: dict[str, dict] = field(default_factory=dict)
    default_preset: str = "epo"
    #: package name -> one-line reason, for third-party plugins that failed to import.
    failed: dict[str, str] = field(default_factory=dict)
    manager: pluggy.PluginManager | None = None

    # -- building -------------------------------------------------------------------------------
    @classmethod
    def load(cls, registry_file: str | Path = REGISTRY_FILE, *, entry_points: bool = True) -> "Registry":
        """Read ``registry.yaml`` (built-ins and presets), import the built-ins and, if ``entry_points``, the
        third-party plugins of the ``eponet.plugins`` entry-point group."""
        registry = cls()
        manager = pluggy.PluginManager(PROJECT)
        manager.add_hookspecs(hookspecs)
        registry.manager = manager
        try:
            declared = yaml.safe_load(Path(registry_file).read_text())
        except (OSError, yaml.YAMLError) as exc:
            raise EponetError(f"{registry_file}: cannot read the plugin registry ({exc})") from None
        builtin: dict[str, list[tuple[str, str]]] = {}
        for entry in declared.get("plugins", []):
            builtin.setdefault(entry["module"], []).append((entry["kind"], entry["name"]))
        for module_name, expected in builtin.items():
            module = importlib.import_module(module_name)
            registry._register(module, module_name, package="eponet", version=_version("eponet"))
            provided = {(s.kind, s.name) for s in registry.stages.values() if s.package == "eponet"}
            missing = [f"{k}/{n}" for k, n in expected if (k, n) not in provided]
            if missing:
                raise EponetError(f"{registry_file}: module {module_name} does not provide {', '.join(missing)}")
        for module_name in declared.get("hooks", []):  # built-in hook implementations that are not stages
            module = importlib.import_module(module_name)
            if not manager.is_registered(module):
                manager.register(module, name=module_name)
        registry.presets = declared.get("presets", {})
        registry.default_preset = declared.get("default_preset", registry.default_preset)
        if entry_points:
            registry._load_entry_points()
        return registry

    def _load_entry_points(self) -> None:
        for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
            package = ep.dist.name if ep.dist is not None else ep.value.split(":")[0]
            version = ep.dist.version if ep.dist is not None else None
            try:
                module = ep.load()
                self._register(module, f"{package}:{ep.name}", package=package, version=version)
            except DuplicatePlugin:
                raise
            except Exception as exc:  # a broken third-party plugin must not take the others down
                reason = f"{exc.__class__.__name__}: {exc}".splitlines()[0]
                self.failed[package] = reason
                log.warning("plugin package %s failed to load (%s); its stages are unavailable", package, reason)

    def _register(self, module, plugin_name: str, *, package: str, version: str | None) -> None:
        assert self.manager is not None
        if self.manager.is_registered(module):
            return
        self.manager.register(module, name=plugin_name)
        impls = [i for i in self.manager.hook.eponet_stages.get_hookimpls() if i.plugin is module]
        for impl in impls:
            for spec in impl.function() or []:
                self.add(replace(spec, package=package, version=spec.version or version))

    def add(self, spec: StageSpec) -> None:
        """Add one stage; a second stage with the same (kind, name) is a :class:`DuplicatePlugin` error."""
        if spec.kind not in KINDS:
            raise EponetError(f"plugin {spec.name!r} from {spec.package} declares unknown kind {spec.kind!r}; kinds: {', '.join(KINDS)}")
        key = (spec.kind, spec.name)
        if key in self.stages:
            other = self.stages[key]
            raise DuplicatePlugin(
                f"duplicate {spec.kind} plugin {spec.name!r}: provided by both {other.package} and {spec.package}"
            )
        self.stages[key] = spec

    # -- lookup ---------------------------------------------------------------------------------
    def evaluate(self, spec, sequences: list[str]) -> dict | None:
        """The evaluation after a run, from the first ``eponet_evaluate`` implementation that gives one."""
        assert self.manager is not None
        return self.manager.hook.eponet_evaluate(spec=spec, sequences=sequences)

    def evaluate_problems(self, options: dict, input_path, resolution: str, sequences) -> list[str]:
        """What the spec's ``evaluate:`` section will miss (``eponet_evaluate_problems``), as one-line problems."""
        if self.manager is None:
            return []
        return list(self.manager.hook.eponet_evaluate_problems(options=options, input_path=input_path,
                                                               resolution=resolution, sequences=sequences) or [])

    def builtin_weights(self) -> set[str]:
        """Names of the weights that plugins ship (``eponet_weights``)."""
        assert self.manager is not None
        return {name for names in self.manager.hook.eponet_weights() for name in names or []}

    def names(self, kind: str) -> list[str]:
        return sorted(name for k, name in self.stages if k == kind)

    def get(self, kind: str, name: str, *, path: str | None = None) -> StageSpec:
        """The stage ``name`` of ``kind``; unknown names raise :class:`PluginNotFound` listing what exists."""
        if kind not in KINDS:
            hint = nearest(kind, list(KINDS))
            raise PluginNotFound(f"{path or kind}: unknown stage kind {kind!r}{_hint(hint)}; kinds: {', '.join(KINDS)}")
        spec = self.stages.get((kind, name))
        if spec is not None:
            return spec
        available = self.names(kind)
        where = f"{path}: " if path else ""
        listing = f"available: {', '.join(available)}" if available else f"no {kind} plugin is installed"
        failed = f"; plugin packages that failed to load: {', '.join(f'{p} ({r})' for p, r in self.failed.items())}" if self.failed else ""
        elsewhere = [k for k in KINDS if (k, name) in self.stages]
        if elsewhere:  # e.g. refiner: {plugin: dis}
            kinds = " and ".join(_a(k) for k in elsewhere)
            raise PluginNotFound(f"{where}{name!r} is {kinds} plugin, not {_a(kind)} plugin; {kind} plugins: "
                                 f"{', '.join(available) or 'none'}{failed}")
        raise PluginNotFound(f"{where}unknown {kind} plugin {name!r}{_hint(nearest(name, available))}; {listing}{failed}")

    def preset(self, name: str, *, path: str = "preset") -> dict:
        if name not in self.presets:
            hint = nearest(name, list(self.presets))
            raise PluginNotFound(f"{path}: unknown preset {name!r}{_hint(hint)}; presets: {', '.join(self.presets)}")
        return self.presets[name]

    def resolve_preset(self, name: str, *, path: str = "preset") -> dict[str, dict]:
        """The stage table of a preset, following ``extends`` chains: kind -> {plugin: ..., params...}."""
        chain, seen = [], set()
        while name is not None:
            if name in seen:
                raise EponetError(f"registry.yaml: preset {name!r} extends itself")
            seen.add(name)
            preset = self.preset(name, path=path)
            chain.append(preset)
            name = preset.get("extends")
        stages: dict[str, dict] = {}
        for preset in reversed(chain):
            for kind, config in (preset.get("stages") or {}).items():
                stages[kind] = dict(config) if config is not None else None
        return {k: v for k, v in stages.items() if v is not None}


def _a(word: str) -> str:
    return f"{'an' if word[0] in 'aeiou' else 'a'} {word}"


def _hint(name: str | None) -> str:
    return f" (did you mean {name!r}?)" if name else ""


def _version(package: str) -> str | None:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


_REGISTRY: Registry | None = None


def get_registry() -> Registry:
    """The process-wide registry, loaded once at start-up."""
    global _REGISTRY
    if _REGISTRY is None:
        _REGISTRY = Registry.load()
    return _REGISTRY
