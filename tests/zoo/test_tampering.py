"""Tampered, missing or malformed checkpoint files are refused with a clear CheckpointError."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import zoo


def _flip_byte(path: Path, offset: int = -20) -> None:
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x01
    path.write_bytes(bytes(data))


def test_copy_loads_by_path(checkpoint_copy: Path):
    assert isinstance(zoo.load(checkpoint_copy), zoo.ZooPolicy)


def test_tampered_weights_refused(checkpoint_copy: Path):
    _flip_byte(checkpoint_copy / "weights.safetensors")
    with pytest.raises(zoo.CheckpointError, match=r"weights\.safetensors: sha256 .* tampered"):
        zoo.load(checkpoint_copy)


def test_tampered_attachment_refused(checkpoint_copy: Path):
    _flip_byte(checkpoint_copy / "training.rrd")
    with pytest.raises(zoo.CheckpointError, match=r"training\.rrd"):
        zoo.load(checkpoint_copy)


def test_missing_file_refused(checkpoint_copy: Path):
    (checkpoint_copy / "weights.safetensors").unlink()
    with pytest.raises(zoo.CheckpointError, match="missing file"):
        zoo.load(checkpoint_copy)


def test_tampered_card_refused_by_registry_pin(checkpoint_copy: Path, private_registry: Path):
    assert isinstance(zoo.load("copy", registry=private_registry), zoo.ZooPolicy)
    card_path = checkpoint_copy / "card.json"
    card = json.loads(card_path.read_text())
    card["metrics"]["tampered"] = True
    card_path.write_text(json.dumps(card))
    with pytest.raises(zoo.CheckpointError, match=r"card sha256 .* registry"):
        zoo.load("copy", registry=private_registry)
    with pytest.raises(zoo.CheckpointError, match="card sha256"):
        zoo.card("copy", registry=private_registry)


def test_card_edited_to_other_weights_hash_refused(checkpoint_copy: Path):
    card_path = checkpoint_copy / "card.json"
    card = json.loads(card_path.read_text())
    card["files"]["weights.safetensors"] = "0" * 64
    card_path.write_text(json.dumps(card))
    with pytest.raises(zoo.CheckpointError, match="does not match the card"):
        zoo.load(checkpoint_copy)


def test_card_architecture_mismatch_refused(checkpoint_copy: Path):
    card_path = checkpoint_copy / "card.json"
    card = json.loads(card_path.read_text())
    card["policy_kwargs"]["net_arch"]["pi"] = [7]
    card_path.write_text(json.dumps(card))
    with pytest.raises(zoo.CheckpointError, match="weights do not fit"):
        zoo.load(checkpoint_copy)


@pytest.mark.parametrize("text", ["{not json", "[]", json.dumps({"kind": "policy"})])
def test_malformed_card_refused(checkpoint_copy: Path, text: str):
    (checkpoint_copy / "card.json").write_text(text)
    with pytest.raises(zoo.CheckpointError, match="malformed card"):
        zoo.load(checkpoint_copy)


@pytest.mark.parametrize("bad", ["../weights.safetensors", "/etc/passwd", "sub/dir.bin"])
def test_file_names_outside_the_directory_refused(checkpoint_copy: Path, bad: str):
    card_path = checkpoint_copy / "card.json"
    card = json.loads(card_path.read_text())
    card["files"][bad] = "0" * 64
    card_path.write_text(json.dumps(card))
    with pytest.raises(zoo.CheckpointError, match="bad file name"):
        zoo.load(checkpoint_copy)


def test_unsupported_activation_refused(checkpoint_copy: Path):
    card_path = checkpoint_copy / "card.json"
    card = json.loads(card_path.read_text())
    card["policy_kwargs"]["activation_fn"] = "os.system"
    card_path.write_text(json.dumps(card))
    with pytest.raises(zoo.CheckpointError, match="activation_fn"):
        zoo.load(checkpoint_copy)
