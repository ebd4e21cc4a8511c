"""Bucket-fill policies that run the standard dig cycle at every size."""

from scaletwin_envs.policies.scripted import ScriptedDigPolicy

__all__ = ["ScriptedDigPolicy"]
