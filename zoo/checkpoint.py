"""Checkpoint directories on disk: the JSON card, the sha256 of every file, and verification.

A checkpoint is a directory holding ``card.json`` and the files the card lists under ``files`` (name →
sha256), and nothing else: a file the card does not list is covered by no hash, so loading refuses it rather than
let a reader (e.g. of ``check.csv``) take unverified content for part of the checkpoint. Nothing but JSON and
safetensors is ever read; names must be plain file names inside the directory.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import platform
import re
from collections.abc import Iterable, Mapping
from importlib import metadata
from pathlib import Path
from typing import Any

from scaletwin_envs.recording.atomic import atomic_path
from zoo.errors import CheckpointError

CARD_NAME = "card.json"
FORMAT_VERSION = 1
#: Keys every card has, whatever its kind.
COMMON_KEYS = ("format_version", "name", "kind", "files", "versions")
VERSION_PACKAGES = ("scaletwin", "torch", "stable-baselines3", "gymnasium", "mujoco", "numpy", "safetensors")
_FILE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
_SHA256 = re.compile(r"^[0-9a-f]{64}$")


def sha256_file(path: str | Path) -> str:
    """Hex sha256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def read_card(directory: str | Path, expected_sha256: str | None = None) -> dict[str, Any]:
    """Parse and check a checkpoint's card (its own hash first, if the registry pins one)."""
    path = Path(directory) / CARD_NAME
    if not path.is_file():
        raise CheckpointError(f"{path}: missing card ({CARD_NAME}); not a checkpoint directory")
    if expected_sha256 is not None and (actual := sha256_file(path)) != expected_sha256:
        raise CheckpointError(f"{path}: card sha256 {actual} does not match the registry's {expected_sha256}; "
                              "the card was modified or replaced")
    try:
        card = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CheckpointError(f"{path}: malformed card, not valid JSON ({exc})") from exc
    check_card(card, path)
    return card


def check_card(card: Any, where: str | Path = CARD_NAME) -> None:
    """Structural checks shared by every kind (kind-specific checks live with the kind's builder)."""
    if not isinstance(card, dict):
        raise CheckpointError(f"{where}: malformed card, expected a JSON object")
    missing = [k for k in COMMON_KEYS if k not in card]
    if missing:
        raise CheckpointError(f"{where}: malformed card, missing keys {missing}")
    if card["format_version"] != FORMAT_VERSION:
        raise CheckpointError(f"{where}: card format_version {card['format_version']!r} is not supported "
                              f"(this zoo reads version {FORMAT_VERSION})")
    files = card["files"]
    if not isinstance(files, dict) or not files:
        raise CheckpointError(f"{where}: malformed card, 'files' must map file names to sha256 digests")
    for name, digest in files.items():
        if not (isinstance(name, str) and _FILE_NAME.match(name)) or name == CARD_NAME:
            raise CheckpointError(f"{where}: malformed card, bad file name {name!r} (plain names only)")
        if not (isinstance(digest, str) and _SHA256.match(digest)):
            raise CheckpointError(f"{where}: malformed card, bad sha256 for {name!r}")


def verify_files(directory: str | Path, card: dict[str, Any]) -> None:
    """Every listed file exists and has the card's sha256, and the directory holds nothing else besides the card;
    raises :class:`CheckpointError` otherwise."""
    directory = Path(directory)
    for name, expected in card["files"].items():
        path = directory / name
        if not path.is_file():
            raise CheckpointError(f"{path}: missing file listed in the card")
        if (actual := sha256_file(path)) != expected:
            raise CheckpointError(f"{path}: sha256 {actual} does not match the card's {expected}; the file is "
                                  "corrupted or was tampered with, refusing to load it")
    unlisted = sorted(p.name for p in directory.iterdir() if p.name != CARD_NAME and p.name not in card["files"])
    if unlisted:
        raise CheckpointError(f"{directory}: {unlisted} not listed in the card, so no sha256 covers them; refusing "
                              "to load the checkpoint (remove them, or save the checkpoint again to list them)")


def write_card(directory: str | Path, card: dict[str, Any]) -> Path:
    """Write ``card.json`` (after the structural checks), sorted and indented."""
    check_card(card)
    path = Path(directory) / CARD_NAME
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(card, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return path


def prepare_directory(directory: str | Path, names: Iterable[str], overwrite: bool) -> Path:
    """Create ``directory``; refuse (``FileExistsError``) if it already holds one of ``names`` unless ``overwrite``."""
    directory = Path(directory)
    present = [n for n in names if (directory / n).exists()]
    if present and not overwrite:
        raise FileExistsError(f"{directory} already holds {present}; pass overwrite=True to replace them")
    directory.mkdir(parents=True, exist_ok=True)
    return directory


def versions(packages: Iterable[str] = VERSION_PACKAGES) -> dict[str, str]:
    """Versions of Python and of the packages a checkpoint depends on."""
    out = {"python": platform.python_version()}
    for pkg in packages:
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "not installed"
    return out


def finish_checkpoint(directory: str | Path, kind: str, fields: Mapping[str, Any], files: Iterable[str]) -> Path:
    """Write the card of a checkpoint whose ``files`` are already in ``directory`` (any kind).

    The card is ``fields`` plus ``format_version``, ``kind``, ``versions``, ``created`` and the sha256 of every
    file; ``name`` defaults to the directory's name. Returns the card's path.
    """
    directory = Path(directory)
    card = {"name": directory.name, **dict(fields), "format_version": FORMAT_VERSION, "kind": kind,
            "versions": versions(), "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            "files": {n: sha256_file(directory / n) for n in files}}
    return write_card(directory, card)
