"""The registry: a plain JSON file naming the shipped checkpoints (path, kind, card sha256, summary).

Loading by name pins the card's sha256 here, and the card pins every other file's, so a registered
checkpoint cannot be altered without the change showing up as a hash mismatch.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from scaletwin_envs.recording.atomic import atomic_path
from zoo.checkpoint import CARD_NAME, FORMAT_VERSION, read_card, sha256_file
from zoo.errors import CheckpointError

ZOO_ROOT = Path(__file__).resolve().parent
REGISTRY_PATH = ZOO_ROOT / "registry.json"
_NAME = re.compile(r"^[a-z0-9][a-z0-9._-]*$")


def read_registry(path: str | Path = REGISTRY_PATH) -> dict[str, dict[str, Any]]:
    """Name → entry (``path``, ``kind``, ``card_sha256``, ``summary``)."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CheckpointError(f"{path}: malformed registry ({exc})") from exc
    entries = data.get("checkpoints") if isinstance(data, dict) else None
    if not isinstance(entries, dict):
        raise CheckpointError(f"{path}: malformed registry, expected {{'checkpoints': {{name: entry}}}}")
    return entries


def list_checkpoints(kind: str | None = None, registry: str | Path = REGISTRY_PATH) -> list[str]:
    """Registered checkpoint names (of one ``kind``, e.g. ``"policy"`` or ``"scaling-model"``), sorted."""
    return sorted(n for n, e in read_registry(registry).items() if kind is None or e.get("kind") == kind)


def resolve(name_or_path: str | Path, registry: str | Path = REGISTRY_PATH) -> tuple[Path, str | None]:
    """Directory of a registered name (with its pinned card sha256) or of a checkpoint path (no pin)."""
    entries = read_registry(registry)
    if isinstance(name_or_path, str) and name_or_path in entries:
        entry = entries[name_or_path]
        path = Path(entry["path"])
        return (path if path.is_absolute() else Path(registry).resolve().parent / path), entry["card_sha256"]
    path = Path(name_or_path)
    if (path / CARD_NAME).is_file():
        return path, None
    raise CheckpointError(f"{name_or_path!s}: neither a registered checkpoint ({', '.join(sorted(entries)) or 'none'})"
                          f" nor a checkpoint directory with a {CARD_NAME}")


def card(name_or_path: str | Path, registry: str | Path = REGISTRY_PATH) -> dict[str, Any]:
    """A checkpoint's card, checked against the registry's pinned hash (files are verified by ``load``)."""
    directory, pinned = resolve(name_or_path, registry)
    return read_card(directory, pinned)


def register(name: str, directory: str | Path, summary: str | None = None,
             registry: str | Path = REGISTRY_PATH) -> dict[str, Any]:
    """Add or replace a registry entry for a checkpoint directory (stored relative to the registry if inside)."""
    if not _NAME.match(name):
        raise ValueError(f"checkpoint names are lower-case letters, digits, '.', '_' and '-', got {name!r}")
    directory = Path(directory).resolve()
    info = read_card(directory)
    root = Path(registry).resolve().parent
    rel = directory.relative_to(root).as_posix() if directory.is_relative_to(root) else directory.as_posix()
    entry = {"path": rel, "kind": info["kind"], "card_sha256": sha256_file(directory / CARD_NAME),
             "summary": summary or info.get("description", "")}
    entries = read_registry(registry)
    entries[name] = entry
    text = json.dumps({"format_version": FORMAT_VERSION, "checkpoints": dict(sorted(entries.items()))}, indent=2)
    with atomic_path(registry) as tmp:
        tmp.write_text(text + "\n", encoding="utf-8")
    return entry
