"""scaletwin_envs: MuJoCo wheel loaders of any size, digging a soil pile (Gymnasium).

``import scaletwin_envs`` registers ``WheelLoaderDig-v1`` and ``WheelLoaderDigRandom-v1`` (a new machine size
and soil every episode, for training one policy at every scale)::

    import gymnasium as gym
    import scaletwin_envs  # noqa: F401

    env = gym.make("WheelLoaderDig-v1", scale="mini", soil="gravel")
    env = gym.make("WheelLoaderDigRandom-v1", scale_range=(0.1, 2.0), soils=("sand", "gravel"))
"""

from __future__ import annotations

import os
import sys

from scaletwin_envs.gl import offscreen_gl

if ("MUJOCO_GL" not in os.environ and sys.platform.startswith("linux") and not os.environ.get("DISPLAY")
        and not os.environ.get("WAYLAND_DISPLAY") and (_backend := offscreen_gl())):
    os.environ["MUJOCO_GL"] = _backend  # headless rendering; must be set before MuJoCo creates a GL context

import gymnasium as gym

from scaletwin_envs.specs import SOILS, LoaderSpec, SoilSpec, make_loader, make_soil, preset_names

__version__ = "0.1.0"
ENV_ID = "WheelLoaderDig-v1"
RANDOM_ENV_ID = "WheelLoaderDigRandom-v1"
#: Control steps of an episode at the default ``max_episode_time`` (60 Froude times) and ``frame_skip``: the same at
#: every scale, since the control step and the Froude time both grow as √λ (the env truncates itself there too).
MAX_EPISODE_STEPS = 290

if ENV_ID not in gym.registry:
    gym.register(id=ENV_ID, entry_point="scaletwin_envs.envs.wheel_loader_dig:WheelLoaderDigEnv",
                 max_episode_steps=MAX_EPISODE_STEPS)
if RANDOM_ENV_ID not in gym.registry:
    gym.register(id=RANDOM_ENV_ID, entry_point="scaletwin_envs.policies.domain:make_randomized_dig_env",
                 max_episode_steps=MAX_EPISODE_STEPS)
if "WheelLoaderLoadTruck-v1" not in gym.registry:  # the loading cycle; 2899 steps = its 600 Froude-time horizon
    gym.register(id="WheelLoaderLoadTruck-v1", entry_point="scaletwin_envs.envs.load_truck:WheelLoaderLoadTruckEnv",
                 max_episode_steps=2899)

__all__ = ["ENV_ID", "MAX_EPISODE_STEPS", "RANDOM_ENV_ID", "SOILS", "LoaderSpec", "SoilSpec", "make_loader",
           "make_soil", "preset_names"]
