"""Typed parameter schemas for plugins: defaults, ranges, one-line docs, and validation messages."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["Param", "validate_params"]

_TYPES = ("int", "float", "bool", "str", "choice", "path", "weights", "list")


@dataclass(frozen=True)
class Param:
    """One plugin parameter.

    ``type`` is one of ``int, float, bool, str, choice, path, weights, list`` (``weights``: a built-in weights
    name or a path). ``minimum``/``maximum`` bound
    numbers (inclusive unless ``exclusive_min``); ``choices`` lists the values of a ``choice``;
    ``nullable`` allows ``null``.
    """

    name: str
    type: str
    default: Any
    doc: str
    minimum: float | None = None
    maximum: float | None = None
    choices: tuple = ()
    nullable: bool = False
    exclusive_min: bool = False
    #: A required parameter has no default: a spec must give it.
    required: bool = False
    many: bool = False

    def __post_init__(self) -> None:
        if self.type not in _TYPES:
            raise ValueError(f"parameter {self.name}: unknown type {self.type!r}; use one of {', '.join(_TYPES)}")
        if self.many and self.type not in ("str", "path", "weights"):
            raise ValueError(f"parameter {self.name}: many is for str, path and weights parameters, not {self.type}")
        if not self.required and (self.default is not None or not self.nullable):
            problem = self.check(self.default)
            if problem:
                raise ValueError(f"parameter {self.name}: default {self.default!r} is invalid: {problem}")

    def describe(self) -> str:
        """Human description of what values are accepted, e.g. ``an integer in [1, 100]``."""
        if self.type == "choice":
            text = "one of " + ", ".join(repr(c) for c in self.choices)
        elif self.type in ("int", "float"):
            noun = "an integer" if self.type == "int" else "a number"
            lo, hi = self.minimum, self.maximum
            if lo is not None and hi is None and lo == (0 if self.exclusive_min else 1) and self.type == "int":
                text = "a positive integer"
            elif lo is not None and hi is not None:
                text = f"{noun} in {'(' if self.exclusive_min else '['}{lo:g}, {hi:g}]"
            elif lo is not None:
                text = f"{noun} {'>' if self.exclusive_min else '>='} {lo:g}"
            elif hi is not None:
                text = f"{noun} <= {hi:g}"
            else:
                text = noun
        else:
            text = {"bool": "true or false", "str": "a string", "path": "a path", "list": "a list",
                    "weights": "a built-in weights name or a file"}[self.type]
        if self.many:
            text += " or a list of them"
        return text + (" or null" if self.nullable else "")

    def check(self, value: Any) -> str | None:
        """Return ``None`` if ``value`` is acceptable, else ``"expected ..., got ..."``."""
        if value is None:
            return None if self.nullable else f"expected {self.describe()}, got null"
        if self.many and isinstance(value, list):
            if value and all(self._check_one(v) is None for v in value):
                return None
            return f"expected {self.describe()}, got {_show(value)}"
        return self._check_one(value)

    def _check_one(self, value: Any) -> str | None:
        bad = f"expected {self.describe()}, got {_show(value)}"
        if self.type == "int":
            if isinstance(value, bool) or not isinstance(value, int):
                return bad
        elif self.type == "float":
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                return bad
        elif self.type == "bool":
            if not isinstance(value, bool):
                return bad
        elif self.type in ("str", "path", "weights"):
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                # e.g. an all-digit sha256 left unquoted: YAML made it a number (all zeros: 0)
                return (f"expected {self.describe()}, got the number {value!r} (YAML reads unquoted digits as a "
                        "number; quote the value)")
            if not isinstance(value, str) or (self.type != "str" and not value):
                return bad
        elif self.type == "choice":
            if value not in self.choices:
                return bad
        elif self.type == "list":
            if not isinstance(value, list):
                return bad
        if self.type in ("int", "float"):
            if self.minimum is not None and (value < self.minimum or (self.exclusive_min and value == self.minimum)):
                return bad
            if self.maximum is not None and value > self.maximum:
                return bad
        return None


def _show(value: Any) -> str:
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, bool):
        return "true" if value else "false"
    return repr(value)


def validate_params(params: dict, schema: tuple[Param, ...], path: str) -> tuple[dict, list[str]]:
    """Check ``params`` against ``schema``; return (values with defaults filled in, problems with YAML paths)."""
    by_name = {p.name: p for p in schema}
    problems: list[str] = []
    resolved = {p.name: p.default for p in schema}
    for key, value in params.items():
        if key not in by_name:
            from .registry import nearest  # local: registry imports this module

            hint = nearest(key, list(by_name))
            known = ", ".join(sorted(by_name)) or "none"
            problems.append(f"{path}.{key}: unknown parameter{f' (did you mean {hint!r}?)' if hint else ''}; known: {known}")
            continue
        problem = by_name[key].check(value)
        if problem:
            problems.append(f"{path}.{key}: {problem}")
        else:
            resolved[key] = float(value) if by_name[key].type == "float" and value is not None else value
    for param in schema:
        if param.required and param.name not in params:
            problems.append(f"{path}.{param.name}: missing required parameter ({param.doc}; {param.describe()})")
    return resolved, problems
