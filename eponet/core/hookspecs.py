"""pluggy hook specifications: how a plugin module tells eponet which stages it provides."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import pluggy

from .params import Param

__all__ = ["PROJECT", "hookspec", "hookimpl", "StageSpec", "eponet_stages", "eponet_evaluate", "eponet_evaluate_problems", "eponet_weights"]

PROJECT = "eponet"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


@dataclass(frozen=True)
class StageSpec:
    """What one plugin provides: a stage ``kind`` (see ``eponet.core.protocols.KINDS``), a unique ``name``
    within that kind, a ``factory`` called with the validated parameters as keywords, the typed parameter
    schema, a one-line ``doc`` and a ``version`` (defaults to the providing package's version)."""

    kind: str
    name: str
    factory: Callable[..., Any]
    params: tuple[Param, ...] = ()
    doc: str = ""
    version: str | None = None
    #: Optional semantic check of the validated parameters (e.g. that a weights file exists), called while the
    #: spec is validated, before anything runs; returns problems as ``"<param>: <what is wrong>"`` strings.
    check: Callable[[dict], list[str]] | None = None
    #: Optional check of the validated parameters against the composition, called once every stage of the spec
    #: is validated (and only if ``check`` found nothing): ``check_stages(params, stages)`` with ``stages`` the
    #: spec's other stages, ``{kind: (plugin name, validated parameters)}``; returns problems as ``check`` does
    #: (e.g. a fusion's weights trained on another appearance stage's features).
    check_stages: Callable[[dict, dict[str, tuple[str, dict]]], list[str]] | None = None
    #: Filled in by the registry: the distribution (package) that provided the plugin.
    package: str = field(default="eponet", compare=False)


@hookspec
def eponet_stages() -> list[StageSpec]:
    """Return the stages this plugin module provides (a list of :class:`StageSpec`).

    A third-party package exposes a module implementing this hook through the entry-point group
    ``eponet.plugins``::

        [project.entry-points."eponet.plugins"]
        myflow = "myflow.plugin"
    """


@hookspec(firstresult=True)
def eponet_evaluate(spec, sequences: list[str]) -> dict | None:
    """Score the masks a run wrote under ``spec.output.dir`` for ``sequences`` as the spec's ``evaluate:``
    section says; return the evaluation (JSON-serialisable) or ``None`` to leave it to another plugin. The
    built-in implementation (``eponet.plugins.evaluate``) uses :mod:`eponet.evaluation`; core never imports it."""


@hookspec(firstresult=True)
def eponet_evaluate_problems(options: dict, input_path, resolution: str, sequences: list[str] | None) -> list[str] | None:
    """Check, while a spec is validated, that the ground truth its ``evaluate:`` section (``options``, paths
    resolved) will need exists for the input (``input.path``, ``input.resolution``, ``input.sequences``); return
    one-line problems (an empty list when all is there) or ``None`` to leave it to another plugin."""


@hookspec
def eponet_weights() -> list[str]:
    """Names of the built-in weights this plugin ships (a spec's ``weights`` parameter may name them instead of a
    file); the built-in implementation is ``eponet.plugins.weights`` (the sha256 catalog of ``eponet.weights``)."""
