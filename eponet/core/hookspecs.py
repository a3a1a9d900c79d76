"""pluggy hook specifications: how a plugin module tells eponet which stages it provides."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import pluggy

from .params import Param

__all__ = ["PROJECT", "hookspec", "hookimpl", "StageSpec", "eponet_stages"]

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
