"""Fixtures: copies of the shipped checkpoint to tamper with, and a private registry."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

import zoo

SHIPPED = "bucketfill-ppo"


@pytest.fixture
def checkpoint_copy(tmp_path: Path) -> Path:
    """A copy of the shipped policy checkpoint directory."""
    src, _ = zoo.resolve(SHIPPED)
    dst = tmp_path / SHIPPED
    shutil.copytree(src, dst)
    return dst


@pytest.fixture
def private_registry(tmp_path: Path, checkpoint_copy: Path) -> Path:
    """A registry file naming the copy (so its card hash is pinned, as for shipped checkpoints)."""
    registry = tmp_path / "registry.json"
    zoo.register("copy", checkpoint_copy, registry=registry)
    return registry
