"""Uniformly random commands: the floor of the KPI comparison (what a policy that knows nothing achieves)."""

from __future__ import annotations

import numpy as np


class RandomPolicy:
    """``[lift, tilt, drive]`` drawn uniformly from [-1, 1] every step; ``predict`` mirrors Stable-Baselines3.

    Args:
        seed: seed of the command stream; :meth:`reseed` restarts it (the KPI harness reseeds per episode).
    """

    def __init__(self, seed: int | None = None) -> None:
        self.reseed(seed)

    def reseed(self, seed: int | None) -> None:
        """Restart the command stream from ``seed``."""
        self.rng = np.random.default_rng(seed)

    def reset(self) -> None:
        """Nothing to forget between episodes (the stream simply continues)."""

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, size=3).astype(np.float32)

    def predict(self, obs: np.ndarray, state: object = None, episode_start: object = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        return self(obs), None

    def __repr__(self) -> str:
        return "RandomPolicy()"
