"""Replay a recording's stored commands in the twin rebuilt from its provenance.

For a simulated recording the replay reproduces every signal exactly (same machine, soil, seed, timing and
env arguments; the physics is deterministic). For a recording of an altered model or a real machine it gives
the twin's response to the same commands, i.e. what the twin predicts for that episode.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium as gym
import numpy as np

import scaletwin_envs
from scaletwin_envs.recording.recording import Provenance, Recording


class CommandPlayback:
    """A policy that returns stored ``[lift, tilt, drive]`` commands in order, ignoring the observation.

    Raises:
        IndexError: called more often than there are commands.
    """

    def __init__(self, commands: np.ndarray) -> None:
        self.commands = np.asarray(commands, dtype=np.float32).reshape(-1, 3)
        self.index = 0

    def reset(self) -> None:
        self.index = 0

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        if self.index >= len(self.commands):
            raise IndexError(f"playback has only {len(self.commands)} commands")
        self.index += 1
        return self.commands[self.index - 1]


def make_twin(provenance: Provenance, **overrides: Any) -> gym.Env:
    """The env described by ``provenance`` (machine spec, soil, env arguments), via ``gym.make``.

    Args:
        provenance: from a recording; needs ``machine`` and a registered ``env_id`` (default WheelLoaderDig-v1).
        overrides: constructor arguments replacing the recorded ones (e.g. ``render_mode``).

    Raises:
        ValueError: no machine spec in the provenance, or an env id that is not registered.
    """
    spec = provenance.machine_spec()
    if spec is None:
        raise ValueError("the recording's provenance has no machine spec; pass the twin as env=")
    env_id = provenance.env_id or scaletwin_envs.ENV_ID
    if env_id not in gym.registry:
        family = env_id.rsplit("-v", 1)[0]
        newer = sorted(k for k in gym.registry if k.rsplit("-v", 1)[0] == family)
        hint = (f"; its dynamics were replaced by {', '.join(newer)} (see that env's version history): a replay "
                "there is no replay of this recording's physics, pass env= to compare anyway") if newer else (
                f" (known: {sorted(gym.registry)})")
        raise ValueError(f"env id {env_id!r} of the recording is not registered{hint}")
    kwargs: dict[str, Any] = {**provenance.env_kwargs, "scale": spec}
    soil = provenance.soil_spec()
    if soil is not None:
        kwargs["soil"] = soil
    kwargs.update(overrides)
    return gym.make(env_id, **kwargs)


def replay(recording: Recording, env: gym.Env | None = None, seed: int | None = None) -> Recording:
    """Step the stored commands in the twin and record what it does.

    Args:
        recording: the recording to replay (simulated, or imported with a machine spec).
        env: the env to replay in (default: :func:`make_twin` of the provenance).
        seed: reset seed (default: the recorded seed).

    Returns:
        The twin's recording: as many rows as the original unless the twin's episode ends sooner. Its
        provenance has ``source="replay"`` and ``extra["replay_of"]`` (the original's policy and model hash,
        and whether the twin's model hash matches).

    Raises:
        ValueError: no seed recorded and none given.
    """
    prov = recording.provenance
    seed = prov.seed if seed is None else seed
    if seed is None:
        raise ValueError("the recording has no seed; pass seed= to choose the twin's initial state")
    twin = env if env is not None else make_twin(prov)
    playback = CommandPlayback(recording.commands)
    from scaletwin_envs.recording.recorder import record_episode  # the simulator side, loaded when replaying

    out = record_episode(twin, playback, seed, max_steps=len(recording),
                         policy_name=f"replay of {len(recording)} stored commands")
    replay_of = {"policy": prov.policy, "source": prov.source, "model_sha256": prov.model_sha256,
                 "model_matches": prov.model_sha256 is not None
                 and prov.model_sha256 == out.provenance.model_sha256}
    out.provenance = dataclasses.replace(out.provenance, source="replay",
                                         extra={**out.provenance.extra, "replay_of": replay_of})
    return out
