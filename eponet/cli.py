"""The ``eponet`` command line: run, validate, plugins, evaluate, make-rbsf, train."""

from __future__ import annotations

import argparse
import logging
import sys
import traceback
from pathlib import Path
from typing import Callable

from .core.errors import EponetError, SpecError

__all__ = ["main", "run_main", "guarded"]

log = logging.getLogger("eponet")


def _configure_logging(verbose: bool, quiet: bool) -> None:
    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    logging.basicConfig(level=level, format="eponet: %(levelname)s: %(message)s", stream=sys.stderr, force=True)
    # third-party libraries stay quiet unless -v
    for noisy in ("PIL", "matplotlib"):
        logging.getLogger(noisy).setLevel(logging.WARNING)


def guarded(function: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    """Run a command; an eponet error becomes one line on stderr and its exit code (traceback with -v)."""
    verbose = getattr(args, "verbose", False)
    try:
        return function(args)
    except SpecError as exc:
        if verbose:
            traceback.print_exc()
        where = f"{exc.file}: " if exc.file else ""
        if len(exc.problems) == 1:
            print(f"error: {where}{exc.problems[0]}", file=sys.stderr)
        else:
            print(f"error: {where}{len(exc.problems)} problems:", file=sys.stderr)
            for problem in exc.problems:
                print(f"  {problem}", file=sys.stderr)
        return exc.exit_code
    except EponetError as exc:
        if verbose:
            traceback.print_exc()
        print(f"error: {exc}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # an unexpected failure: still one line unless -v
        if verbose:
            traceback.print_exc()
        print(f"error: internal failure: {exc.__class__.__name__}: {exc} (run with -v for the traceback)", file=sys.stderr)
        return 1


def _add_common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging and tracebacks")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars, warnings only")


def _add_spec_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("spec", help="pipeline spec (YAML)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                        help="override a spec value (YAML syntax), e.g. --set stages.refiner.iterations=10")


def _cmd_run(args: argparse.Namespace) -> int:
    from .core.cache import Cache
    from .core.pipeline import Pipeline
    from .core.progress import set_quiet
    from .core.spec import load_spec

    set_quiet(args.quiet)
    spec = load_spec(args.spec, args.overrides)
    cache_dir = Path(args.cache_dir) if args.cache_dir else spec.cache_dir
    cache = Cache(cache_dir, enabled=spec.cache_enabled and not args.no_cache)
    manifest = Pipeline(spec, cache=cache).run()
    _print_summary(manifest, spec.output.dir, quiet=args.quiet)
    return 0


def _print_summary(manifest: dict, out_dir: Path, quiet: bool) -> None:
    lines = []
    for name, info in manifest["sequences"].items():
        timings = ", ".join(f"{k} {v:.2f}s" for k, v in info["timings_s"].items())
        cached = f" (cached: {', '.join(info['cached'])})" if info["cached"] else ""
        lines.append(f"{name}: {info['frames']} frames; {timings}{cached}")
    evaluation = manifest.get("evaluation")
    if evaluation:
        overall = evaluation.get("overall", {})
        parts = []
        for metric in ("J", "F", "T"):
            value = overall.get(metric, {}).get("mean") if isinstance(overall.get(metric), dict) else None
            if value is not None:
                parts.append(f"{metric} mean {value:.3f}")
        lines.append("evaluation: " + ", ".join(parts))
    lines.append(f"outputs in {out_dir} (run.json beside them)")
    if not quiet:
        print("\n".join(lines))


def _cmd_validate(args: argparse.Namespace) -> int:
    from .core.inputs import discover_sequences
    from .core.pipeline import warn_about_memory
    from .core.spec import load_spec

    spec = load_spec(args.spec, args.overrides)
    sources = discover_sequences(spec.input.path, sequences=spec.input.sequences, resolution=spec.input.resolution,
                                 max_frames=spec.input.max_frames)
    warn_about_memory(spec, sources)
    stages = ", ".join(f"{k}={c.plugin}" for k, c in spec.stages.items())
    print(f"{args.spec}: valid (preset {spec.preset}; {stages}; {len(sources)} sequence(s): "
          f"{', '.join(s.name for s in sources[:8])}{' ...' if len(sources) > 8 else ''})")
    return 0


def _cmd_plugins(args: argparse.Namespace) -> int:
    from .core.graph import KINDS, stage_kind
    from .core.registry import get_registry

    registry = get_registry()
    kinds = [args.kind] if args.kind else list(KINDS)
    for kind in kinds:
        if kind not in KINDS:
            raise SpecError(f"unknown stage kind {kind!r}; kinds: {', '.join(KINDS)}")
        node = stage_kind(kind)
        print(f"{kind}: {node.doc}")
        print(f"  protocol {node.protocol.__name__}.{node.method}(); consumes {', '.join(node.consumes)}; produces "
              f"{node.produces}; context {node.context}; {'cached' if node.cached else 'not cached'}")
        names = registry.names(kind)
        if not names:
            print("  (none installed)")
        for name in names:
            spec = registry.stages[(kind, name)]
            print(f"  {name}  [{spec.package} {spec.version or ''}]  {spec.doc}".rstrip())
            for param in spec.params:
                default = "required" if param.required else f"default {param.default!r}"
                print(f"      {param.name}: {param.describe()}, {default}; {param.doc}")
    print("presets:")
    for name, preset in registry.presets.items():
        stages = registry.resolve_preset(name)
        marker = " (default)" if name == registry.default_preset else ""
        print(f"  {name}{marker}: " + ", ".join(f"{k}={v['plugin']}" for k, v in stages.items()))
    for package, reason in registry.failed.items():
        print(f"failed to load: {package}: {reason}")
    return 0


def _forward(module: str) -> Callable[[list[str]], int]:
    def call(argv: list[str]) -> int:
        import importlib

        return importlib.import_module(module).main(argv)

    return call


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="eponet", description="Salient motion segmentation (EpO-Net).")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    run = sub.add_parser("run", help="run a pipeline spec")
    _add_spec_args(run)
    run.add_argument("--no-cache", action="store_true", help="neither read nor write cached intermediate results")
    run.add_argument("--cache-dir", help="cache location (default: the spec's cache.dir, $EPONET_CACHE or ~/.cache/eponet)")
    _add_common(run)
    run.set_defaults(handler=_cmd_run)
    validate = sub.add_parser("validate", help="check a spec (and its inputs) without running it")
    _add_spec_args(validate)
    _add_common(validate)
    validate.set_defaults(handler=_cmd_validate)
    plugins = sub.add_parser("plugins", help="list stage kinds, plugins, their parameters and the presets")
    plugins.add_argument("kind", nargs="?", help="only this stage kind")
    _add_common(plugins)
    plugins.set_defaults(handler=_cmd_plugins)
    for name, text in (("evaluate", "score masks with the DAVIS J / F / T protocol (see eponet evaluate -h)"),
                       ("make-rbsf", "generate RBSF-style synthetic videos with exact ground truth"),
                       ("train", "train a network from a training spec (see eponet train -h)")):
        sub.add_parser(name, help=text, add_help=False)
    return parser


#: Sub-commands implemented by their own modules' ``main(argv)``.
_FORWARDED = {
    "evaluate": "eponet.evaluate",
    "make-rbsf": "eponet.synth.cli",
    "train": "eponet.train",
}


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in _FORWARDED:
        return _forward(_FORWARDED[argv[0]])(argv[1:])
    parser = build_parser()
    if not argv:
        parser.print_help()
        return 2
    args = parser.parse_args(argv)
    _configure_logging(args.verbose, args.quiet)
    return guarded(args.handler, args)


def run_main(argv: list[str] | None = None) -> int:
    """``python -m eponet.run spec.yaml [--set ...]``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    return main(["run", *argv])
