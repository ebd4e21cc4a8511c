"""Static-hold episodes: a scripted dig, then the loaded bucket carried to random poses and held still.

The paper validates on a miniature at static equilibrium (a1 = α1 = 0), while dig cycles are mostly dynamic. So
that the δ1 models see near-static rows *from the simulator* (never from the analytical statics used for the
validation, which keeps training and validation independent), the standard data set adds episodes run with
:class:`StaticHoldPolicy`: the standard scripted dig (:class:`~scaletwin_envs.policies.ScriptedDigPolicy`) until
the loaded bucket is lifted clear of the pile, then a sequence of carry poses (boom angle, bucket pitch; rad),
each reached with a proportional controller on the observation and held with closed valves for ``hold_steps``
control steps, and finally the standard pull-back (which ends the episode). Poses and the penetration depth (hence
the load) are drawn from ``seed``, so :func:`make_hold_policy` is a deterministic factory with JSON arguments
that dataset sweeps can import by name (``"scaling.holds:make_hold_policy"``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scaletwin_envs.envs.wheel_loader_dig import OBS_INDEX
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.policies.scripted import Stage

#: Ranges the carry poses are drawn from: boom angle above the dig pose (rad), bucket pitch (rad, + curled back).
BOOM_RANGE = (0.15, 0.75)
PITCH_RANGE = (0.35, 0.95)
PENETRATION_RANGE = (0.12, 0.5)


@dataclass
class StaticHoldPolicy:
    """Dig, then reach and hold each of ``poses``; ``predict`` mirrors Stable-Baselines3's signature.

    Attributes:
        poses: (boom angle, bucket pitch) targets, rad.
        hold_steps: control steps each pose is held with closed valves (drive stopped).
        penetration: passed to the scripted dig (boom lengths past the pile toe; sets the load).
        gain: proportional gain, command per rad of error.
        tolerance: pose error (rad) below which a pose counts as reached.
        max_move_steps: give up reaching a pose after this many steps and hold where the bucket is.
    """

    poses: tuple[tuple[float, float], ...] = ((0.4, 0.6),)
    hold_steps: int = 25
    penetration: float = 0.45
    gain: float = 6.0
    tolerance: float = 0.01
    max_move_steps: int = 60
    dig: ScriptedDigPolicy = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.dig = ScriptedDigPolicy(penetration=self.penetration)
        self._pose, self._moving, self._count = 0, True, 0

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.act(obs)

    def predict(self, obs: np.ndarray, state: object = None, episode_start: object = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        return self.act(obs), None

    def act(self, obs: np.ndarray) -> np.ndarray:
        action = self.dig.act(obs)
        if self.dig.stage is not Stage.PULL_BACK or self._pose >= len(self.poses):
            return action  # digging, or every pose done: the scripted pull-back ends the episode
        boom, pitch = float(obs[OBS_INDEX["boom_angle"]]), float(obs[OBS_INDEX["bucket_pitch"]])
        target_boom, target_pitch = self.poses[self._pose]
        err = np.array([target_boom - boom, target_pitch - pitch])
        self._count += 1
        if self._moving:
            if np.all(np.abs(err) < self.tolerance) or self._count > self.max_move_steps:
                self._moving, self._count = False, 0
            else:
                return np.array([*np.clip(self.gain * err, -1.0, 1.0), 0.0], dtype=np.float32)
        if self._count >= self.hold_steps:
            self._pose, self._moving, self._count = self._pose + 1, True, 0
        return np.zeros(3, dtype=np.float32)


def draw_hold(seed: int, n_poses: int = 3) -> dict[str, object]:
    """The seeded random arguments of a hold episode: ``poses`` and ``penetration`` (see module ranges)."""
    rng = np.random.default_rng(seed)
    poses = [(float(rng.uniform(*BOOM_RANGE)), float(rng.uniform(*PITCH_RANGE))) for _ in range(n_poses)]
    return {"poses": tuple(poses), "penetration": float(rng.uniform(*PENETRATION_RANGE))}


def make_hold_policy(seed: int = 0, n_poses: int = 3, hold_steps: int = 25) -> StaticHoldPolicy:
    """A :class:`StaticHoldPolicy` with poses and penetration drawn from ``seed`` (importable factory)."""
    drawn = draw_hold(seed, n_poses)
    return StaticHoldPolicy(poses=drawn["poses"], penetration=drawn["penetration"],  # type: ignore[arg-type]
                            hold_steps=hold_steps)
