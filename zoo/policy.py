"""The ``"policy"`` kind: Stable-Baselines3 actor–critic policies stored as safetensors + a JSON card.

:func:`save_policy` writes a checkpoint from a trained model and checks that the rebuilt policy acts
exactly like it; :func:`build_policy` (the kind's builder) rebuilds an ``ActorCriticPolicy`` from the card's
spaces and policy keyword arguments and loads the verified weights. Nothing is unpickled: the weights are
read with ``safetensors.torch.load_file`` and everything else is JSON.
"""

from __future__ import annotations

import shutil
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor

from zoo.checkpoint import CARD_NAME, finish_checkpoint, prepare_directory
from zoo.errors import CheckpointError
from zoo.loading import load, register_builder
from zoo.spaces import space_from_json, space_to_json

KIND = "policy"
WEIGHTS = "weights.safetensors"
POLICY_CLASSES: dict[str, type[ActorCriticPolicy]] = {
    "stable_baselines3.common.policies.ActorCriticPolicy": ActorCriticPolicy}
ACTIVATIONS: dict[str, type[torch.nn.Module]] = {"Tanh": torch.nn.Tanh, "ReLU": torch.nn.ReLU, "ELU": torch.nn.ELU,
                                                 "LeakyReLU": torch.nn.LeakyReLU}
POLICY_KEYS = ("algorithm", "env_id", "env_kwargs", "policy_class", "policy_kwargs", "observation_space",
               "action_space", "seed")
_KWARG_KEYS = ("net_arch", "activation_fn", "log_std_init", "ortho_init", "share_features_extractor")


class ZooPolicy:
    """A policy from the zoo: ``predict`` as in Stable-Baselines3, callable as obs → action, and usable by
    :func:`scaletwin_envs.rollout.run_episode` and the dataset sweeps as the standard dig cycle.

    Attributes:
        policy: the rebuilt ``ActorCriticPolicy``.  card: its card.  ref: the name or path it was loaded from.
    """

    def __init__(self, policy: ActorCriticPolicy, card: dict[str, Any], ref: str) -> None:
        self.policy, self.card, self.ref = policy, card, ref

    @property
    def name(self) -> str:
        return str(self.card["name"])

    def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        return self.policy.predict(obs, state, episode_start, deterministic)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.policy.predict(obs, deterministic=True)[0]

    def reset(self) -> None:
        """Stateless (a feed-forward policy); present so episode runners can call it."""

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        # Worker processes reload (and re-verify) the checkpoint instead of receiving pickled tensors.
        return load, (self.ref,)

    def __repr__(self) -> str:
        return f"ZooPolicy({self.name!r})"


def _policy_kwargs(card: dict[str, Any]) -> dict[str, Any]:
    kwargs = dict(card["policy_kwargs"])
    unknown = set(kwargs) - set(_KWARG_KEYS)
    if unknown:
        raise CheckpointError(f"malformed card: unsupported policy_kwargs {sorted(unknown)}")
    if "activation_fn" in kwargs:
        if kwargs["activation_fn"] not in ACTIVATIONS:
            raise CheckpointError(f"malformed card: activation_fn must be one of {sorted(ACTIVATIONS)}")
        kwargs["activation_fn"] = ACTIVATIONS[kwargs["activation_fn"]]
    return kwargs


def build_policy(directory: Path, card: dict[str, Any], ref: str) -> ZooPolicy:
    """Builder of the ``"policy"`` kind (called by :func:`zoo.load` after the hashes were verified)."""
    missing = [k for k in POLICY_KEYS if k not in card]
    if missing or WEIGHTS not in card["files"]:
        raise CheckpointError(f"{directory}: malformed policy card, missing {missing or [WEIGHTS]}")
    cls = POLICY_CLASSES.get(card["policy_class"])
    if cls is None:
        raise CheckpointError(f"{directory}: unsupported policy_class {card['policy_class']!r}")
    obs_space = space_from_json(card["observation_space"], "observation_space")
    act_space = space_from_json(card["action_space"], "action_space")
    try:
        policy = cls(obs_space, act_space, lambda _: 0.0, **_policy_kwargs(card))
        policy.load_state_dict(load_file(directory / WEIGHTS), strict=True)
    except (RuntimeError, TypeError, ValueError) as exc:
        raise CheckpointError(f"{directory}: weights do not fit the card's policy ({exc})") from exc
    policy.set_training_mode(False)
    return ZooPolicy(policy, card, ref)


register_builder(KIND, build_policy)


def load_policy(name: str = "bucketfill-ppo") -> ZooPolicy:
    """Factory for dataset sweeps (``policy="zoo:load_policy"``): a verified policy checkpoint by name or path."""
    obj = load(name)
    if not isinstance(obj, ZooPolicy):
        raise CheckpointError(f"{name}: is a {type(obj).__name__}, not a policy")
    return obj


def describe(policy: ActorCriticPolicy) -> dict[str, Any]:
    """Card fields that rebuild ``policy``: class, keyword arguments and spaces."""
    if type(policy) is not ActorCriticPolicy or policy.features_extractor_class is not FlattenExtractor:
        raise TypeError("save_policy stores Stable-Baselines3 ActorCriticPolicy with the default (flatten) "
                        f"features extractor, got {type(policy).__name__}")
    if policy.use_sde:
        raise TypeError("gSDE policies are not supported by the zoo")
    params = policy._get_constructor_parameters()
    names = {v: k for k, v in ACTIVATIONS.items()}
    if params["activation_fn"] not in names:
        raise TypeError(f"activation {params['activation_fn'].__name__} not in {sorted(ACTIVATIONS)}")
    return {
        "policy_class": "stable_baselines3.common.policies.ActorCriticPolicy",
        "policy_kwargs": {"net_arch": params["net_arch"], "activation_fn": names[params["activation_fn"]],
                          "log_std_init": float(params["log_std_init"]), "ortho_init": bool(params["ortho_init"]),
                          "share_features_extractor": bool(policy.share_features_extractor)},
        "observation_space": space_to_json(policy.observation_space),
        "action_space": space_to_json(policy.action_space),
    }


def save_policy(model: Any, directory: str | Path, card_fields: Mapping[str, Any],
                attachments: Mapping[str, str | Path] | None = None, overwrite: bool = False) -> Path:
    """Write a policy checkpoint: ``weights.safetensors``, attachments (e.g. ``training.rrd``) and ``card.json``.

    Args:
        model: a Stable-Baselines3 algorithm (its ``.policy`` is stored) or an ``ActorCriticPolicy``.
        card_fields: the rest of the card: at least ``env_id``, ``env_kwargs``, ``seed``; usually ``name``,
            ``description``, ``training``, ``metrics``, observation/action ``names``.
        attachments: file name → source path, copied in and hashed like the weights.

    The rebuilt policy is checked to act exactly like ``model`` before returning the directory.
    """
    policy = getattr(model, "policy", model)
    directory = Path(directory)
    attachments = dict(attachments or {})
    prepare_directory(directory, [WEIGHTS, CARD_NAME, *attachments], overwrite)
    state = {k: v.detach().cpu().contiguous() for k, v in policy.state_dict().items()}
    save_file(state, str(directory / WEIGHTS), metadata={"format": "pt"})
    (directory / WEIGHTS).chmod(0o644)  # safetensors writes 0600; checkpoints are shared read-only data
    for name, src in attachments.items():
        shutil.copyfile(src, directory / name)
    fields = {"algorithm": type(model).__name__ if model is not policy else "unknown", **dict(card_fields),
              **describe(policy)}
    if fields.get("observation_names") is not None:
        fields["observation_space"]["names"] = list(fields["observation_names"])
    finish_checkpoint(directory, KIND, fields, (WEIGHTS, *attachments))
    _check_round_trip(policy, directory)
    return directory


def _check_round_trip(policy: ActorCriticPolicy, directory: Path) -> None:
    rebuilt = load(directory)
    obs = np.random.default_rng(0).uniform(-2.0, 2.0, size=(64, *policy.observation_space.shape))
    obs = obs.astype(policy.observation_space.dtype)
    ours = policy.predict(obs, deterministic=True)[0]
    theirs = rebuilt.predict(obs, deterministic=True)[0]
    if not np.array_equal(ours, theirs):
        raise CheckpointError(f"{directory}: the rebuilt policy does not reproduce the model's actions")
