"""scaletwin_envs: MuJoCo wheel loaders of any size, digging a soil pile (Gymnasium).

``import scaletwin_envs`` registers ``WheelLoaderDig-v0``::

    import gymnasium as gym
    import scaletwin_envs  # noqa: F401

    env = gym.make("WheelLoaderDig-v0", scale="mini", soil="gravel")
"""

from __future__ import annotations

import os
import sys

if "MUJOCO_GL" not in os.environ and sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
    os.environ["MUJOCO_GL"] = "egl"  # headless rendering; must be set before MuJoCo creates a GL context

import gymnasium as gym

from scaletwin_envs.specs import SOILS, LoaderSpec, SoilSpec, make_loader, make_soil, preset_names

__version__ = "0.1.0"
ENV_ID = "WheelLoaderDig-v0"

if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="scaletwin_envs.envs.wheel_loader_dig:WheelLoaderDigEnv",
                 max_episode_steps=None)

__all__ = ["ENV_ID", "SOILS", "LoaderSpec", "SoilSpec", "make_loader", "make_soil", "preset_names"]
