"""Tampered, missing or malformed checkpoint files are refused with a clear CheckpointError."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

import zoo
from zoo.scaling_kind import CARD_KEYS, check_rows
from zoo.serving.inputs import split_header


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


# -- every file of every shipped checkpoint ---------------------------------------------------------------------------
def _shipped_files() -> list[tuple[str, str]]:
    cases = []
    for name in zoo.list():
        directory, _ = zoo.resolve(name)
        cases += [(name, p.name) for p in sorted(directory.iterdir())]
    return cases


SHIPPED_FILES = _shipped_files()


def _copy_registered(name: str, tmp_path: Path) -> tuple[Path, Path]:
    """A copy of one shipped checkpoint and a private registry pinning its card, as the shipped registry does."""
    src, _ = zoo.resolve(name)
    dst = tmp_path / name
    shutil.copytree(src, dst)
    registry = tmp_path / "registry.json"
    zoo.register(name, dst, registry=registry)
    return dst, registry


def test_every_shipped_kind_and_file_is_covered():
    kinds = {zoo.card(name)["kind"] for name in zoo.list()}
    assert kinds == set(zoo.builders()) >= {"policy", "scaling-model"}
    files = {f for _, f in SHIPPED_FILES}
    assert {"card.json", "weights.safetensors", "config.json", "check.csv", "training.rrd"} <= files
    for name in zoo.list():  # every file present is listed in the card (and the card pins nothing absent)
        card = zoo.card(name)
        assert {f for n, f in SHIPPED_FILES if n == name} == {*card["files"], "card.json"}, name


@pytest.mark.parametrize("name", sorted({n for n, _ in SHIPPED_FILES}))
def test_untampered_copy_loads(name: str, tmp_path: Path):
    """The control for the flips below: the copy itself loads, by path and through a registry pin."""
    directory, registry = _copy_registered(name, tmp_path)
    for ref, reg in ((directory, zoo.REGISTRY_PATH), (name, registry)):
        loaded = zoo.load(ref, registry=reg)
        assert isinstance(loaded, zoo.ZooPolicy | zoo.ScalingModel)


@pytest.mark.parametrize(("name", "file"), SHIPPED_FILES)
def test_one_flipped_byte_in_any_file_is_refused(name: str, file: str, tmp_path: Path):
    """One bit of one byte, in the middle of the file, of each file of each shipped checkpoint.

    Every file but the card is pinned by the card; the card itself is pinned by the registry (loaded by path, a
    card is only parsed and checked for structure: a flipped byte inside one of its strings would go unnoticed).
    """
    directory, registry = _copy_registered(name, tmp_path)
    path = directory / file
    _flip_byte(path, offset=path.stat().st_size // 2)
    with pytest.raises(zoo.CheckpointError, match=r"card sha256 .* registry" if file == "card.json"
                       else rf"{re.escape(file)}: sha256 .* tampered"):
        zoo.load(name, registry=registry)
    if file != "card.json":
        with pytest.raises(zoo.CheckpointError, match=rf"{re.escape(file)}: sha256 .* tampered"):
            zoo.load(directory)


@pytest.mark.parametrize("name", ["bucketfill-ppo", "ffnn-eq10"])
@pytest.mark.parametrize("extra", ["notes.txt", "check.csv", "config.json"])
def test_file_not_listed_in_the_card_refused(name: str, extra: str, tmp_path: Path):
    """A file the card does not list is covered by no hash: refused (e.g. a check set the card never pinned)."""
    directory, _ = _copy_registered(name, tmp_path)
    card = zoo.card(directory)
    if extra in card["files"]:  # drop it from the card: the file is there, the card no longer lists it
        del card["files"][extra]
        (directory / "card.json").write_text(json.dumps(card))
    else:
        (directory / extra).write_text("a,b\n1,2\n")
    with pytest.raises(zoo.CheckpointError, match=rf"\['{re.escape(extra)}'\] not listed in the card"):
        zoo.load(directory)


def test_saving_again_without_a_check_set_leaves_no_unlisted_one(tmp_path: Path):
    """save_scaling_model(check_rows=None, overwrite=True) over a checkpoint with a check set removes the old
    ``check.csv`` (which the new card would not list) instead of writing a checkpoint that cannot be loaded."""
    served = zoo.load("ffnn-eq10")
    fields = {k: served.card[k] for k in CARD_KEYS}
    rows = check_rows(zoo.resolve("ffnn-eq10")[0]).rename(columns=lambda c: split_header(c)[0])
    directory = zoo.save_scaling_model(served.model, tmp_path / "m", fields, rows)
    assert "check.csv" in zoo.card(directory)["files"]
    zoo.save_scaling_model(served.model, directory, fields, overwrite=True)
    assert not (directory / "check.csv").exists() and "check.csv" not in zoo.card(directory)["files"]
    assert isinstance(zoo.load(directory), zoo.ScalingModel)
