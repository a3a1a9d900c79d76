"""Pretrained weights as data: a catalogue of built-in files (name, file, sha256), verified before loading."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import yaml

from eponet.core.errors import MissingWeights, SpecError
from eponet.core.registry import nearest

__all__ = ["WEIGHTS_DIR", "BuiltinWeights", "builtin_weights", "sha256_of", "weights_path", "resolve_weights",
           "weights_list", "load_each"]

WEIGHTS_DIR = Path(__file__).resolve().parent


@dataclass(frozen=True)
class BuiltinWeights:
    name: str
    file: Path
    sha256: str
    kind: str
    description: str = ""


def builtin_weights() -> dict[str, BuiltinWeights]:
    """The catalogue in ``eponet/weights/catalog.yaml``."""
    entries = yaml.safe_load((WEIGHTS_DIR / "catalog.yaml").read_text()) or {}
    return {
        name: BuiltinWeights(name, WEIGHTS_DIR / e["file"], e["sha256"], e["kind"], e.get("description", ""))
        for name, e in (entries.get("weights") or {}).items()
    }


def sha256_of(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def weights_path(name_or_path: str, *, kind: str | None = None) -> Path:
    """The file behind a built-in name or a path, not read (:func:`resolve_weights` also verifies it). Raises
    :class:`MissingWeights` for a built-in name of another ``kind`` and for a name that is neither built in nor
    a file."""
    catalogue = builtin_weights()
    if name_or_path in catalogue:
        entry = catalogue[name_or_path]
        if kind is not None and entry.kind != kind:
            raise MissingWeights(f"weights {name_or_path!r} are for a {entry.kind} stage, not {kind}")
        return entry.file
    path = Path(name_or_path).expanduser()
    if not path.suffix and not path.exists():
        names = [n for n, e in catalogue.items() if kind is None or e.kind == kind]
        hint = nearest(path.name, names)
        raise MissingWeights(f"weights {name_or_path!r}: neither a built-in name"
                             f"{f' (did you mean {hint!r}?)' if hint else ''} (built-in: {', '.join(names) or 'none'}) "
                             "nor a file")
    return path


def resolve_weights(name_or_path: str, *, sha256: str | None = None, kind: str | None = None) -> tuple[Path, str]:
    """The verified file behind a built-in name or a path, and its sha256.

    A built-in name is checked against the catalogue's checksum, and ``sha256``, when given, must be that
    checksum (a spec that pins the digest a run recorded keeps meaning that file); a path is checked against
    ``sha256`` when given.
    Raises :class:`MissingWeights` (one line, naming the file) when the file is missing, unreadable or fails
    its checksum.
    """
    entry = builtin_weights().get(name_or_path)
    if entry is not None and sha256 is not None and sha256.lower() != entry.sha256:
        raise MissingWeights(f"built-in weights {name_or_path!r}: expected sha256 {entry.sha256} (the catalogue's), "
                             f"given {sha256}", key="sha256")
    path = weights_path(name_or_path, kind=kind)
    expected = entry.sha256 if entry is not None else sha256
    if not path.is_file():
        raise MissingWeights(f"{path}: weights file not found")
    try:
        actual = sha256_of(path)
    except OSError as exc:
        raise MissingWeights(f"{path}: cannot read weights ({exc.strerror or exc})") from None
    if expected and actual != expected.lower():
        raise MissingWeights(f"{path}: checksum mismatch (sha256 {actual[:12]}..., expected {expected[:12]}...); "
                             "the file is corrupt or not the expected weights")
    return path, actual


def weights_list(weights: str | list[str], sha256: str | list[str] | None) -> list[tuple[str, str | None]]:
    """Pairs (weights, expected sha256 or None) of a stage's ``weights`` and ``sha256`` parameters, each one name or
    a list (an ensemble); a :class:`~eponet.core.errors.SpecError` when the checksums do not pair with the files."""
    names = weights if isinstance(weights, list) else [weights]
    if sha256 is None or (isinstance(sha256, str) and len(names) == 1):
        digests = [sha256] * len(names)
    elif isinstance(sha256, list) and len(sha256) == len(names):
        digests = sha256
    else:
        count = 1 if isinstance(sha256, str) else len(sha256)
        raise SpecError(f"sha256: {count} checksum(s) for {len(names)} weights files; give one per file, in the "
                        "same order, or none")
    return list(zip(names, digests))


def load_each(load, weights: str | list[str], sha256: str | list[str] | None) -> tuple[list, str | list[str]]:
    """A stage's networks from its ``weights`` and ``sha256`` parameters (:func:`weights_list`), each by
    ``load(name, expected sha256) -> (network, sha256)``; returns the networks and the sha256 the stage records:
    a list for a list of weights, else the one digest."""
    loaded = [load(name, digest) for name, digest in weights_list(weights, sha256)]
    digests = [digest for _, digest in loaded]
    return [network for network, _ in loaded], digests if isinstance(weights, list) else digests[0]
