"""zoo: named, verified checkpoints: δ1 scaling models (served by :class:`ScalingModel`) and policies.

The registry (``zoo/registry.json``) names checkpoint directories under ``zoo/checkpoints/``; each holds
safetensors weights and a JSON ``card.json`` with the sha256 of every file. Nothing is ever unpickled::

    import zoo

    zoo.list()                          # ['bucketfill-ppo', ...]
    zoo.card("bucketfill-ppo")          # the card (its hash checked against the registry)
    policy = zoo.load("bucketfill-ppo") # hashes verified, then rebuilt; policy.predict(obs, deterministic=True)
    model = zoo.load("ffnn-eq10")       # a ScalingModel: model.scale_force(source, target) -> F21 + interval

A tampered, missing or malformed file raises :class:`CheckpointError`.

Kinds: ``"policy"`` (:mod:`zoo.policy`) and ``"scaling-model"`` (:mod:`zoo.scaling_kind`, served through
:mod:`zoo.serving`; rebuilt from the pipeline by :mod:`zoo.build`). Adding a kind: write its files into a
directory and call :func:`finish_checkpoint` (card with every file's sha256), then
``register_builder(kind, builder)`` with ``builder(directory, card, ref) -> object``, called by :func:`load` only
after every hash has been verified.
"""

from zoo.checkpoint import CARD_NAME, finish_checkpoint, sha256_file, versions
from zoo.errors import CheckpointError
from zoo.loading import builders, load, register_builder
from zoo.policy import ZooPolicy, load_policy, save_policy
from zoo.registry import REGISTRY_PATH, ZOO_ROOT, card, list_checkpoints, register, resolve
from zoo.scaling_kind import save_scaling_model
from zoo.serving import (
    EndStopWarning,
    ExtrapolationWarning,
    InputError,
    Prediction,
    ScaledForce,
    ScalingModel,
    SourceWarning,
    Stream,
)

list = list_checkpoints  # the public name: zoo.list()

__all__ = [
    "CARD_NAME",
    "REGISTRY_PATH",
    "ZOO_ROOT",
    "CheckpointError",
    "EndStopWarning",
    "ExtrapolationWarning",
    "InputError",
    "Prediction",
    "ScaledForce",
    "ScalingModel",
    "SourceWarning",
    "Stream",
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
    "save_scaling_model",
    "sha256_file",
    "versions",
]
