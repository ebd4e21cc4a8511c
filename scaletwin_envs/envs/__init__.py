"""Gymnasium environments."""

from scaletwin_envs.envs.loader_base import LoaderEnv
from scaletwin_envs.envs.wheel_loader_dig import WheelLoaderDigEnv

__all__ = ["LoaderEnv", "WheelLoaderDigEnv"]
