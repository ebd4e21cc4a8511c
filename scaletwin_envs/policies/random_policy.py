"""Uniformly random commands: the floor of the KPI comparison (what a policy that knows nothing achieves)."""

from __future__ import annotations

import numpy as np

from scaletwin_envs.policies.base import DigPolicy


class RandomPolicy(DigPolicy):
    """``[lift, tilt, drive]`` drawn uniformly from [-1, 1] every step; ``predict`` mirrors Stable-Baselines3.

    Args:
        seed: seed of the command stream; :meth:`reseed` restarts it (the KPI harness reseeds per episode).
    """

    def __init__(self, seed: int | None = None) -> None:
        self.reseed(seed)

    def reseed(self, seed: int | None) -> None:
        """Restart the command stream from ``seed``."""
        self.rng = np.random.default_rng(seed)

    def act(self, obs: np.ndarray) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, size=3).astype(np.float32)

    def __repr__(self) -> str:
        return "RandomPolicy()"
