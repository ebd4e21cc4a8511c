"""The standard dig cycle of the paper (approach in a straight line, lower, penetrate, curl, lift, pull back),
scripted on the dimensionless observation so the same thresholds work at every size.

Timing needs no scaling by hand: every threshold is in boom lengths, Froude speeds or fractions of stroke.

The defaults are the original cycle (kept so existing datasets reproduce); :data:`TUNED` is a parameter set
that fills fuller with less energy at every size (it is the teacher of the learned bucket-fill policy).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np

from scaletwin_envs.envs.wheel_loader_dig import OBS_INDEX
from scaletwin_envs.policies.base import DigPolicy


class Stage(IntEnum):
    APPROACH = 0
    PENETRATE = 1
    CURL = 2
    LIFT = 3
    PULL_BACK = 4


@dataclass
class ScriptedDigPolicy(DigPolicy):
    """A state machine over :data:`OBS_NAMES`; ``predict`` mirrors Stable-Baselines3's signature.

    Attributes:
        penetration: how far past the pile toe to push before curling, boom lengths.
        approach_drive, penetrate_drive: drive commands.
        curl_lift, curl_drive: lift and drive while curling (crowding keeps the edge loaded).
        rack_pitch: bucket pitch (rad) at which the bucket counts as racked back.
        clearance: edge height above the pile surface before pulling back, boom lengths.
        penetrate_pitch: bucket pitch (rad) held while penetrating; above 0 the bucket holds more than the
            struck volume, so filling continues during penetration instead of stopping at ~0.75.
        curl_fill: fill factor at which penetration ends and the curl starts.
        full_fill: fill factor at which a curl stops early once the bucket is racked past 0.35 rad (it then
            holds the full heap), instead of curling on against the pile.
        lift_tilt, lift_drive: tilt (until the bucket is racked 1 rad) and drive commands while lifting clear.
    """

    penetration: float = 0.45
    approach_drive: float = 0.8
    penetrate_drive: float = 1.0
    curl_lift: float = 0.35
    curl_drive: float = 0.5
    rack_pitch: float = 0.55
    clearance: float = 0.08
    penetrate_pitch: float = 0.0
    curl_fill: float = 0.7
    full_fill: float = math.inf
    lift_tilt: float = 0.0
    lift_drive: float = 0.1

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.stage = Stage.APPROACH
        self._stall = 0

    def act(self, obs: np.ndarray) -> np.ndarray:
        o = {k: float(obs[i]) for k, i in OBS_INDEX.items()}
        self._advance(o)
        level = float(np.clip(-3.0 * o["bucket_pitch"], -1.0, 1.0))  # keep the bucket floor level
        if self.stage is Stage.APPROACH:
            down = -0.3 if o["edge_height"] > 0.01 else 0.0
            return np.array([down, level, self.approach_drive], dtype=np.float32)
        if self.stage is Stage.PENETRATE:
            hold = float(np.clip(-3.0 * (o["bucket_pitch"] - self.penetrate_pitch), -1.0, 1.0))
            return np.array([0.0, hold, self.penetrate_drive], dtype=np.float32)
        if self.stage is Stage.CURL:
            return np.array([self.curl_lift, 1.0, self.curl_drive], dtype=np.float32)
        if self.stage is Stage.LIFT:
            tilt = self.lift_tilt if o["bucket_pitch"] < 1.0 else 0.0
            return np.array([1.0, tilt, self.lift_drive], dtype=np.float32)
        return np.array([0.0, 0.0, -1.0], dtype=np.float32)

    def _advance(self, o: dict[str, float]) -> None:
        if self.stage is Stage.APPROACH and o["edge_depth"] > 0.0:
            self.stage = Stage.PENETRATE
        elif self.stage is Stage.PENETRATE:
            self._stall = self._stall + 1 if o["travel_speed"] < 0.01 else 0
            if o["edge_x_to_pile"] > self.penetration or self._stall >= 3 or o["fill"] > self.curl_fill:
                self.stage = Stage.CURL
        elif self.stage is Stage.CURL and self._curled(o):
            self.stage = Stage.LIFT
        elif self.stage is Stage.LIFT and o["edge_depth"] < -self.clearance:
            self.stage = Stage.PULL_BACK

    def _curled(self, o: dict[str, float]) -> bool:
        racked = o["bucket_pitch"] > self.rack_pitch or o["tilt_extension"] > 0.97
        return racked or (o["fill"] > self.full_fill and o["bucket_pitch"] > 0.35)


#: Parameters of the teacher of ``bucketfill-ppo``: penetrate further with the bucket tilted back, fill to 0.9
#: before curling, crowd harder while curling, stop curling once the full heap is held, and lift clear while
#: curling and backing off. On gravel it fills ~0.95-1.1 (defaults: 0.75-0.86) with less specific energy and
#: shorter cycles at every scale; see benchmarks/results/policy_kpis.md.
TUNED: dict[str, Any] = {"penetration": 0.6, "penetrate_pitch": 0.2, "curl_fill": 0.9, "curl_drive": 0.8,
                         "full_fill": 1.05, "lift_tilt": 0.5, "lift_drive": -0.3}
