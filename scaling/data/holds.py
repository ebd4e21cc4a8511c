"""Static-hold episodes: a scripted dig, then the loaded bucket carried to random poses and held still.

The paper validates on a miniature at static equilibrium (a1 = α1 = 0), while dig cycles are mostly dynamic. So
that the δ1 models see near-static rows *from the simulator* (never from the analytical statics used for the
validation, which keeps training and validation independent), the standard data set adds episodes run with
:class:`StaticHoldPolicy`: the standard scripted dig (:class:`~scaletwin_envs.policies.ScriptedDigPolicy`) until
the loaded bucket is lifted clear of the pile, then a sequence of carry poses (boom angle, bucket pitch; rad),
each reached with a proportional controller on the observation and held with closed valves for ``hold_steps``
control steps, and finally the standard pull-back (which ends the episode). Poses and the penetration depth (hence
the load) are drawn from ``seed``, so :func:`make_hold_policy` is a deterministic factory with JSON arguments
that dataset sweeps can import by name (``"scaling.data.holds:make_hold_policy"``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from scaletwin_envs.envs.wheel_loader_dig import OBS_INDEX
from scaletwin_envs.physics.kinematics import LinkageUnreachable, solve_pose
from scaletwin_envs.policies import DigPolicy, ScriptedDigPolicy
from scaletwin_envs.policies.scripted import Stage
from scaletwin_envs.specs import make_loader

#: Ranges the carry poses are drawn from: boom angle above the dig pose (rad), bucket pitch (rad, + curled back).
BOOM_RANGE = (0.1, 0.8)
PITCH_RANGE = (0.3, 1.0)
#: Poses keep both cylinders this far (fraction of stroke) from their end stops, so that the cylinders, not the
#: stops, hold the load (at a stop the cylinder force no longer carries the pin forces).
STROKE_MARGIN = 0.12
PENETRATION_RANGE = (0.12, 0.5)


@dataclass
class StaticHoldPolicy(DigPolicy):
    """Dig, then reach and hold each of ``poses`` (callable, with Stable-Baselines3's ``predict``).

    Attributes:
        poses: (boom angle, bucket pitch) targets, rad.
        hold_steps: control steps each pose is held with closed valves (drive stopped).
        penetration: passed to the scripted dig (boom lengths past the pile toe; sets the load).
        gain: proportional gain, command per rad of error.
        max_command: command limit while moving (gentle starts and stops: valve jolts excite the linkage).
        tolerance: pose error (rad) below which a pose counts as reached.
        max_move_steps: give up reaching a pose after this many steps and hold where the bucket is.
    """

    poses: tuple[tuple[float, float], ...] = ((0.4, 0.6),)
    hold_steps: int = 25
    penetration: float = 0.45
    gain: float = 3.0
    max_command: float = 0.6
    tolerance: float = 0.01
    max_move_steps: int = 80
    dig: ScriptedDigPolicy = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.dig = ScriptedDigPolicy(penetration=self.penetration)
        self._pose, self._moving, self._count = 0, True, 0

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
                return np.array([*np.clip(self.gain * err, -self.max_command, self.max_command), 0.0], dtype=np.float32)
        if self._count >= self.hold_steps:
            self._pose, self._moving, self._count = self._pose + 1, True, 0
        return np.zeros(3, dtype=np.float32)


def pose_in_workspace(boom: float, pitch: float, margin: float = STROKE_MARGIN) -> bool:
    """True when both cylinders of the ER12 layout (shared by every preset and scale) are at least ``margin`` of
    their stroke away from either end stop at (boom angle, bucket pitch), rad."""
    spec = make_loader("er12")
    try:
        pose = solve_pose(spec.geometry, boom, pitch - boom)
    except LinkageUnreachable:
        return False
    for cyl, length in ((spec.lift, pose.lift_length), (spec.tilt, pose.tilt_length)):
        extension = (length - cyl.closed_length) / cyl.stroke
        if not margin <= extension <= 1.0 - margin:
            return False
    return True


def draw_hold(seed: int, n_poses: int = 3) -> dict[str, object]:
    """The seeded random arguments of a hold episode: ``poses`` (uniform in the module ranges, rejected unless
    :func:`pose_in_workspace`) and ``penetration``."""
    rng = np.random.default_rng(seed)
    poses: list[tuple[float, float]] = []
    while len(poses) < n_poses:
        boom, pitch = float(rng.uniform(*BOOM_RANGE)), float(rng.uniform(*PITCH_RANGE))
        if pose_in_workspace(boom, pitch):
            poses.append((boom, pitch))
    return {"poses": tuple(poses), "penetration": float(rng.uniform(*PENETRATION_RANGE))}


def make_hold_policy(seed: int = 0, n_poses: int = 3, hold_steps: int = 25) -> StaticHoldPolicy:
    """A :class:`StaticHoldPolicy` with poses and penetration drawn from ``seed`` (importable factory)."""
    drawn = draw_hold(seed, n_poses)
    return StaticHoldPolicy(poses=drawn["poses"], penetration=drawn["penetration"],  # type: ignore[arg-type]
                            hold_steps=hold_steps)
