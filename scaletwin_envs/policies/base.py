"""The shape every dig policy shares: ``act(obs) -> action``, callable, and Stable-Baselines3's ``predict``."""

from __future__ import annotations

import numpy as np


class DigPolicy:
    """Subclasses implement :meth:`act` (and :meth:`reset` if they keep state between steps)."""

    def act(self, obs: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def reset(self) -> None:
        """Forget the episode (stateless policies need nothing)."""

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.act(obs)

    def predict(self, obs: np.ndarray, state: object = None, episode_start: object = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        """Stable-Baselines3's signature, so these policies go wherever a trained one does."""
        return self.act(obs), None
