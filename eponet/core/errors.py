"""Typed errors: every one carries what it is about and reads as one line."""

from __future__ import annotations

__all__ = [
    "EponetError",
    "SpecError",
    "InputError",
    "PluginNotFound",
    "DuplicatePlugin",
    "PluginLoadError",
    "StageError",
    "MissingWeights",
    "OutputError",
    "UsageError",
    "SequenceFailures",
]


class EponetError(Exception):
    """Base class. ``exit_code`` is what the CLI returns: 2 for bad spec/input, 1 for run failures."""

    exit_code = 1


class SpecError(EponetError):
    """One or more problems in a pipeline spec, each with its YAML path."""

    exit_code = 2

    def __init__(self, problems: list[str] | str, file: str | None = None):
        self.problems = [problems] if isinstance(problems, str) else list(problems)
        self.file = file
        where = f"{file}: " if file else ""
        if len(self.problems) == 1:
            msg = where + self.problems[0]
        else:
            msg = where + f"{len(self.problems)} problems: " + "; ".join(self.problems)
        super().__init__(msg)


class InputError(EponetError):
    """Unreadable, missing or inconsistent input (frames, videos, flow files, masks)."""

    exit_code = 2


class PluginNotFound(SpecError):
    """An unknown plugin name; the message lists what exists and suggests the nearest name."""


class DuplicatePlugin(EponetError):
    """Two plugins registered the same (kind, name)."""

    exit_code = 2


class PluginLoadError(EponetError):
    """A third-party plugin package failed to import."""

    exit_code = 2


class StageError(EponetError):
    """A stage failed while running (names the stage, plugin and sequence/frame)."""

    exit_code = 1


class MissingWeights(EponetError):
    """Weights file missing, unreadable or failing its checksum; ``key`` is the stage parameter it is about
    (``weights`` or ``sha256``)."""

    exit_code = 2

    def __init__(self, message: str, *, key: str = "weights"):
        super().__init__(message)
        self.key = key

    @property
    def problem(self) -> str:
        """The spec-validation line: ``<key>: <message>`` (the caller prefixes the stage's YAML path)."""
        return f"{self.key}: {self}"


class OutputError(EponetError):
    """The output folder cannot be written; ``errno`` is the failed write's (e.g. ``ENOSPC``), when known."""

    exit_code = 2

    def __init__(self, message: str, *, errno: int | None = None):
        super().__init__(message)
        self.errno = errno


class UsageError(EponetError):
    """A bad command-line value (names the option, what it expects and what it got)."""

    exit_code = 2


class SequenceFailures(EponetError):
    """Some sequences of a run failed while the others finished; ``failures`` maps each name to its one-line
    reason. Exit code 2 when every failure is a bad input (a missing corpus entry, an unreadable file), else 1."""

    def __init__(self, failures: dict[str, tuple[str, int]], total: int):
        self.failures = dict(failures)
        self.exit_code = 2 if all(code == 2 for _, code in self.failures.values()) else 1
        if total == 1:  # the run's only sequence: its reason alone
            super().__init__(next(iter(self.failures.values()))[0])
            return
        reasons = "; ".join(reason if reason.startswith(name) else f"{name}: {reason}"
                            for name, (reason, _) in self.failures.items())
        super().__init__(f"{len(self.failures)} of {total} sequences failed ({reasons}); the others finished, and "
                         f"running the spec again redoes only what is missing")
