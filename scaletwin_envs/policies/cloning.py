"""Behaviour cloning with DAgger: warm-start a Stable-Baselines3 actor–critic from a teacher policy.

Rollouts are labelled by a *shadow* teacher that watches the same observations as the acting policy (the
scripted teacher is a state machine driven by observations only, so it can label any trajectory). Round 0
lets the teacher act; later rounds let the student act and aggregate the teacher's labels on the states the
student visits (DAgger), which fixes the drift of a plain cloned policy. The critic is fitted to the
discounted returns of the same rollouts so that reinforcement-learning fine-tuning starts from a value
function that matches the cloned actor (a random critic would wreck the actor in the first updates).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3.common.policies import ActorCriticPolicy

Teacher = Callable[[np.ndarray], np.ndarray]


@dataclass
class Transitions:
    """Observations with the teacher's action labels and the discounted return from each state on."""

    obs: np.ndarray
    labels: np.ndarray
    returns: np.ndarray
    fills: np.ndarray  # final fill factor of each episode

    def __len__(self) -> int:
        return len(self.obs)

    def concat(self, other: Transitions) -> Transitions:
        return Transitions(*(np.concatenate([a, b]) for a, b in zip(self.astuple(), other.astuple(), strict=True)))

    def astuple(self) -> tuple[np.ndarray, ...]:
        return self.obs, self.labels, self.returns, self.fills


def discounted(rewards: list[float], gamma: float) -> np.ndarray:
    """Discounted return from every step of an episode."""
    out, acc = np.zeros(len(rewards)), 0.0
    for i in range(len(rewards) - 1, -1, -1):
        acc = rewards[i] + gamma * acc
        out[i] = acc
    return out


def labelled_episode(env: gym.Env, teacher_factory: Callable[[], Teacher], student: ActorCriticPolicy | None,
                     gamma: float) -> Transitions:
    """One episode acted by ``student`` (deterministic) or, if None, by the teacher; labelled by the teacher."""
    teacher = teacher_factory()
    obs, _ = env.reset()
    observations, labels, rewards = [], [], []
    done, info = False, {}
    while not done:
        label = np.asarray(teacher(obs), dtype=np.float32)
        action = label if student is None else student.predict(obs, deterministic=True)[0]
        observations.append(obs)
        labels.append(label)
        obs, reward, terminated, truncated, info = env.step(action)
        rewards.append(float(reward))
        done = terminated or truncated
    return Transitions(np.asarray(observations), np.asarray(labels), discounted(rewards, gamma),
                       np.array([info.get("fill_factor", 0.0)]))


def collect(env: gym.Env, teacher_factory: Callable[[], Teacher], episodes: int,
            student: ActorCriticPolicy | None = None, gamma: float = 0.99) -> Transitions:
    """``episodes`` labelled episodes (see :func:`labelled_episode`)."""
    parts = [labelled_episode(env, teacher_factory, student, gamma) for _ in range(episodes)]
    data = parts[0]
    for p in parts[1:]:
        data = data.concat(p)
    return data


def actor_mean(policy: ActorCriticPolicy, obs: torch.Tensor) -> torch.Tensor:
    """The deterministic action (mean of the Gaussian) before clipping."""
    features = policy.extract_features(obs, policy.pi_features_extractor)
    return policy.action_net(policy.mlp_extractor.forward_actor(features))


def _minibatches(n: int, batch_size: int, gen: torch.Generator) -> list[torch.Tensor]:
    return list(torch.randperm(n, generator=gen).split(batch_size))


def fit(policy: ActorCriticPolicy, data: Transitions, target: str, epochs: int, batch_size: int = 256,
        lr: float = 1e-3, seed: int = 0) -> list[float]:
    """Supervised fit of the actor's mean to the labels (``target="actor"``, MSE) or of the critic to the
    returns (``"critic"``); only that head's parameters move. Returns the mean loss of every epoch."""
    obs = torch.as_tensor(data.obs, dtype=torch.float32)
    if target == "actor":
        y = torch.as_tensor(data.labels, dtype=torch.float32)
        params = [*policy.mlp_extractor.policy_net.parameters(), *policy.action_net.parameters()]
        predict: Callable[[torch.Tensor], torch.Tensor] = lambda x: actor_mean(policy, x)  # noqa: E731
    elif target == "critic":
        y = torch.as_tensor(data.returns, dtype=torch.float32).unsqueeze(1)
        params = [*policy.mlp_extractor.value_net.parameters(), *policy.value_net.parameters()]
        predict = policy.predict_values
    else:
        raise ValueError(f"target must be 'actor' or 'critic', got {target!r}")
    opt = torch.optim.Adam(params, lr=lr)
    gen = torch.Generator().manual_seed(seed)
    losses = []
    policy.set_training_mode(True)
    for _ in range(epochs):
        total = 0.0
        for idx in _minibatches(len(obs), batch_size, gen):
            loss = torch.nn.functional.mse_loss(predict(obs[idx]), y[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(idx)
        losses.append(total / len(obs))
    policy.set_training_mode(False)
    return losses
