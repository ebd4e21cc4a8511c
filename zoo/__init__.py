"""zoo: named, verified checkpoints (policies; scaling models plug in through :func:`register_builder`).

The registry (``zoo/registry.json``) names checkpoint directories under ``zoo/checkpoints/``; each holds
safetensors weights and a JSON ``card.json`` with the sha256 of every file. Nothing is ever unpickled::

    import zoo

    zoo.list()                          # ['bucketfill-ppo', ...]
    zoo.card("bucketfill-ppo")          # the card (its hash checked against the registry)
    policy = zoo.load("bucketfill-ppo") # hashes verified, then rebuilt; policy.predict(obs, deterministic=True)

A tampered, missing or malformed file raises :class:`CheckpointError`.

Adding a kind (e.g. ``"scaling-model"``): write its files into a directory and call
:func:`finish_checkpoint` (card with every file's sha256), then ``register_builder(kind, builder)`` with
``builder(directory, card, ref) -> object``, called by :func:`load` only after every hash has been verified.
"""

from zoo.checkpoint import CARD_NAME, finish_checkpoint, sha256_file, versions
from zoo.errors import CheckpointError
from zoo.loading import builders, load, register_builder
from zoo.policy import ZooPolicy, load_policy, save_policy
from zoo.registry import REGISTRY_PATH, ZOO_ROOT, card, list_checkpoints, register, resolve

list = list_checkpoints  # the public name: zoo.list()

__all__ = [
    "CARD_NAME",
    "REGISTRY_PATH",
    "ZOO_ROOT",
    "CheckpointError",
    "ZooPolicy",
    "builders",
    "card",
    "finish_checkpoint",
    "list",
    "list_checkpoints",
    "load",
    "load_policy",
    "register",
    "register_builder",
    "resolve",
    "save_policy",
    "sha256_file",
    "versions",
]
