"""The ``eponet`` command line: run, validate, plugins, cache, report, evaluate, make-rbsf, train."""

from __future__ import annotations

import argparse
import contextlib
import logging
import re
import signal
import sys
import threading
import traceback
from pathlib import Path
from typing import Callable

from .core.errors import EponetError, InputError, SpecError, UsageError

__all__ = ["main", "run_main", "guarded", "parse_size", "parse_duration"]

log = logging.getLogger("eponet")


def _configure_logging(verbose: bool, quiet: bool) -> None:
    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    logging.basicConfig(level=level, format="eponet: %(levelname)s: %(message)s", stream=sys.stderr, force=True)
    # third-party libraries stay quiet unless -v
    for noisy in ("PIL", "matplotlib"):
        logging.getLogger(noisy).setLevel(logging.WARNING)


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``timeout``, a batch scheduler), raised in the main thread as Ctrl-C raises
    ``KeyboardInterrupt``: the run stops the same way (its workers ended, nothing half-written), exit status 143."""


def _raise_terminated(signum, frame) -> None:
    raise Terminated()


@contextlib.contextmanager
def _terminate_like_interrupt():
    """SIGTERM raises :class:`Terminated` while the block runs (where a handler can be set: the main thread)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:  # (None: a handler set outside Python, which cannot be restored from here; the default then)
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


def guarded(function: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    """Run a command; an eponet error becomes one line on stderr and its exit code (traceback with -v); Ctrl-C
    and SIGTERM become one line and 130 / 143."""
    verbose = getattr(args, "verbose", False)
    try:
        with _terminate_like_interrupt():
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
    except Terminated:
        print("error: terminated (SIGTERM)", file=sys.stderr)
        return 143
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
    from .core.progress import redirect_logging, set_quiet
    from .core.spec import load_spec

    set_quiet(args.quiet)
    spec = load_spec(args.spec, args.overrides)
    cache_dir = Path(args.cache_dir) if args.cache_dir else spec.cache_dir
    cache = Cache(cache_dir, enabled=spec.cache_enabled and not args.no_cache)
    invocation = {"overrides": list(args.overrides), "no_cache": args.no_cache, "cache_dir": args.cache_dir}
    with redirect_logging():  # log lines above the progress bars, not through them
        manifest = Pipeline(spec, cache=cache).run(invocation=invocation)
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
        if evaluation.get("max_frames") is not None:
            rows = [e for e in evaluation.get("sequences", {}).values() if isinstance(e, dict)]
            parts.append(f"{sum(e.get('frames_scored', 0) for e in rows)} of "
                         f"{sum(e.get('frames_in_ground_truth', 0) for e in rows)} ground-truth frames scored "
                         f"(input.max_frames {evaluation['max_frames']})")
        lines.append("evaluation: " + ", ".join(parts))
    lines.append(f"outputs in {out_dir} (run.json beside them)")
    if not quiet:
        print("\n".join(lines))


def _cmd_validate(args: argparse.Namespace) -> int:
    from .core.inputs import discover_sequences
    from .core.memory import warn_about_memory
    from .core.pipeline import sequences_overlap
    from .core.spec import load_spec

    spec = load_spec(args.spec, args.overrides)
    sources = discover_sequences(spec.input.path, sequences=spec.input.sequences, resolution=spec.input.resolution,
                                 max_frames=spec.input.max_frames)
    for source in sources:  # an unreadable frame after the first three: a run would stop there
        if source.stopped:
            raise InputError(f"{source.stopped} (a run processes the {source.count} frames before it, then fails)")
    warn_about_memory(spec, sources, overlap=sequences_overlap(spec, len(sources)))
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


_SIZE_UNITS = {"": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
_DURATION_UNITS = {"s": 1, "m": 60, "h": 3600, "d": 86400, "w": 7 * 86400}


def parse_size(option: str, text: str) -> int:
    """``500M``, ``2G``, ``1.5T`` or a number of bytes (binary units: ``2G`` is 2 GiB)."""
    match = re.fullmatch(r"(\d+(?:\.\d+)?)\s*([KMGT]?)(?:i?B)?", text.strip(), re.IGNORECASE)
    if not match:
        raise UsageError(f"{option}: expected a size such as 500M or 2G, got {text!r}")
    return int(float(match[1]) * _SIZE_UNITS[match[2].upper()])


def parse_duration(option: str, text: str) -> float:
    """``30m``, ``12h``, ``7d``, ``2w`` or a number of seconds."""
    match = re.fullmatch(r"(\d+(?:\.\d+)?)\s*([smhdw]?)", text.strip())
    if not match:
        raise UsageError(f"{option}: expected a duration such as 12h or 7d, got {text!r}")
    return float(match[1]) * _DURATION_UNITS[match[2] or "s"]


def _format_size(size: float) -> str:
    if size < 1024:
        return f"{size:.0f} B"
    for unit in ("KiB", "MiB", "GiB", "TiB"):
        size /= 1024
        if size < 1024 or unit == "TiB":
            return f"{size:.1f} {unit}"


def _format_time(timestamp: float) -> str:
    from datetime import datetime, timezone

    return datetime.fromtimestamp(timestamp, timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def _by_stage(entries) -> str:
    counts: dict[str, list[int]] = {}
    for entry in entries:
        counts.setdefault(entry.stage, [0, 0])
        counts[entry.stage][0] += 1
        counts[entry.stage][1] += entry.size
    return ", ".join(f"{stage} {n} ({_format_size(size)})" for stage, (n, size) in sorted(counts.items()))


def _open_cache(args: argparse.Namespace):
    from .core.cache import Cache
    from .core.spec import default_cache_dir

    return Cache(Path(args.cache_dir) if args.cache_dir else default_cache_dir())


def _cmd_cache_info(args: argparse.Namespace) -> int:
    cache = _open_cache(args)
    entries = cache.entries()
    if not entries:
        print(f"cache: {cache.root} (empty)")
        return 0
    print(f"cache: {cache.root}")
    print(f"size: {_format_size(sum(e.size for e in entries))} in {len(entries)} entries")
    print(f"entries per stage: {_by_stage(entries)}")
    print(f"oldest: {_format_time(entries[0].mtime)}; newest: {_format_time(entries[-1].mtime)} (last written or read)")
    return 0


def _cmd_cache_prune(args: argparse.Namespace) -> int:
    older_than = parse_duration("--older-than", args.older_than) if args.older_than is not None else None
    max_size = parse_size("--max-size", args.max_size) if args.max_size is not None else None
    cache = _open_cache(args)
    removed = cache.prune(older_than=older_than, max_size=max_size)
    left = cache.entries()
    freed = f"freed {_format_size(sum(e.size for e in removed))}: {len(removed)} entries"
    if removed:
        freed += f" ({_by_stage(removed)})"
    if not args.quiet:
        print(f"{freed}; {_format_size(sum(e.size for e in left))} in {len(left)} entries left in {cache.root}")
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from .core.html_report import write_report

    path = write_report(Path(args.out_dir))
    if not args.quiet:
        print(f"wrote {path}")
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
    cache = sub.add_parser("cache", help="report on or prune the cache of intermediate results")
    actions = cache.add_subparsers(dest="action", required=True, metavar="ACTION")
    info = actions.add_parser("info", help="cache folder, total size, entries per stage kind, oldest and newest")
    prune = actions.add_parser("prune", help="remove the least recently used entries")
    prune.add_argument("--older-than", metavar="AGE", help="remove entries not used for AGE (e.g. 12h, 7d)")
    prune.add_argument("--max-size", metavar="SIZE", help="then remove the oldest until at most SIZE (e.g. 500M, 2G)")
    for parser_, handler in ((info, _cmd_cache_info), (prune, _cmd_cache_prune)):
        parser_.add_argument("--cache-dir", help="cache location (default: $EPONET_CACHE or ~/.cache/eponet)")
        _add_common(parser_)
        parser_.set_defaults(handler=handler)
    report = sub.add_parser("report", help="write OUT_DIR/index.html: a run's videos, panels, timings, scores and record")
    report.add_argument("out_dir", metavar="OUT_DIR", help="a run's output folder (output.dir, with its run.json)")
    _add_common(report)
    report.set_defaults(handler=_cmd_report)
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
