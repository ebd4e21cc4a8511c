"""``load``: verify a checkpoint, then hand it to the builder registered for its kind.

Each kind of checkpoint (``"policy"``, and ``"scaling-model"`` from the scaling side) registers a builder
``(directory, card, ref) -> object`` with :func:`register_builder`; the loader itself knows no kind. Builders
run only after the card and every file have passed their sha256 checks. ``ref`` is how to load the same
checkpoint again (its registered name, or its directory), e.g. for worker processes.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from zoo.checkpoint import read_card, verify_files
from zoo.errors import CheckpointError
from zoo.registry import REGISTRY_PATH, resolve

Builder = Callable[[Path, dict[str, Any], str], Any]
_BUILDERS: dict[str, Builder] = {}


def register_builder(kind: str, builder: Builder) -> None:
    """Make ``load`` build checkpoints whose card has ``"kind": kind`` with ``builder(directory, card, ref)``."""
    _BUILDERS[kind] = builder


def builders() -> list[str]:
    """Kinds that :func:`load` can build."""
    return sorted(_BUILDERS)


def load(name_or_path: str | Path, registry: str | Path = REGISTRY_PATH) -> Any:
    """Load a registered checkpoint by name, or a checkpoint directory by path, after verifying its hashes.

    Raises:
        CheckpointError: unknown name, missing or malformed card, a missing file, a sha256 mismatch, a kind
            without a builder, or weights that do not fit the card.
    """
    directory, pinned = resolve(name_or_path, registry)
    card = read_card(directory, pinned)
    verify_files(directory, card)
    builder = _BUILDERS.get(card["kind"])
    if builder is None:
        raise CheckpointError(f"{directory}: no builder for checkpoint kind {card['kind']!r} "
                              f"(known: {', '.join(builders())})")
    registered = pinned is not None and Path(registry).resolve() == REGISTRY_PATH
    return builder(directory, card, str(name_or_path) if registered else str(directory))
