"""The built-in weights catalog, offered to core through ``eponet_weights`` (core never imports eponet.weights)."""

from __future__ import annotations

from eponet.core.hookspecs import hookimpl

__all__ = ["eponet_weights"]


@hookimpl
def eponet_weights():
    from eponet.weights import builtin_weights

    return list(builtin_weights())
