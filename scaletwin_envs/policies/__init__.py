"""Bucket-fill policies that run the standard dig cycle at every size, and the tools that train them.

:class:`ScriptedDigPolicy` (with :data:`TUNED` parameters, the teacher of the learned policy) and
:class:`RandomPolicy` live here; :mod:`~scaletwin_envs.policies.domain` randomises scale and soil per episode
and :mod:`~scaletwin_envs.policies.cloning` clones a teacher into a Stable-Baselines3 policy. Trained
policies are stored in and loaded from the ``zoo`` package.
"""

from scaletwin_envs.policies.base import DigPolicy
from scaletwin_envs.policies.random_policy import RandomPolicy
from scaletwin_envs.policies.scripted import TUNED, ScriptedDigPolicy

__all__ = ["TUNED", "DigPolicy", "RandomPolicy", "ScriptedDigPolicy"]
