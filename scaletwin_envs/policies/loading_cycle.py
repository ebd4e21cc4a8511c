"""A scripted short loading cycle for ``WheelLoaderLoadTruck-v0``, built on any bucket-fill (dig) policy.

The dig is delegated to a dig policy acting on the dig view of the observation (entries 0–18, the dig env's
:data:`~scaletwin_envs.envs.wheel_loader_dig.OBS_NAMES`): the scripted :class:`ScriptedDigPolicy` (default, with
the :data:`TUNED` parameters) or a learned one (anything with ``act`` or Stable-Baselines3's ``predict``, e.g.
``zoo.load("bucketfill-ppo")``). The rest is a state machine on the dimensionless observation, so the same
thresholds serve every size: reverse with the bucket racked until the leg switches, haul forward raising the boom,
stop with the edge over the body once it clears the truck's side, tip until the bucket is empty (or the truck holds
its target: partial last dump), back out, lower, and hand back to the dig policy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np

from scaletwin_envs.envs.load_truck import OBS_INDEX
from scaletwin_envs.envs.wheel_loader_dig import OBS_NAMES as DIG_OBS_NAMES
from scaletwin_envs.policies.base import DigPolicy
from scaletwin_envs.policies.scripted import TUNED, ScriptedDigPolicy, Stage

N_DIG = len(DIG_OBS_NAMES)


class CycleStage(IntEnum):
    DIG = 0
    REVERSE = 1
    HAUL = 2
    DUMP = 3
    BACK_OUT = 4


# The dump linkage turns the bucket 4-6x faster per unit of tilt stroke than the presets' (velocity ratio
# dL/dθ ≈ 0.025-0.035 L/rad against 0.15): a full tilt command turns it by ~0.25 rad in one control step, so the
# pitch loop's gains are low (per-step loop gain ≈ 0.3 at PITCH_KP, measured on er12, 2026-11-27).
PITCH_KP = 1.2  # tilt command per rad of pitch error
PITCH_KD = 0.6  # tilt command per rad of pitch change in one step: damps the swing of a loaded bucket
LIFT_GATE = 0.25  # rad: pitch error at which raising stops, so the hold keeps up with the racking of the boom


def _hold_pitch(pitch: float, rate: float, target: float) -> float:
    """Tilt command holding the bucket pitch at ``target`` (rad): PD on the pitch (rad) and its change over the last
    step (``rate``, rad per step; steps are a fixed fraction of the Froude time at every scale)."""
    return float(np.clip(PITCH_KP * (target - pitch) - PITCH_KD * rate, -1.0, 1.0))


def _gate(pitch: float, target: float) -> float:
    """1 with the pitch on target, falling to 0 at :data:`LIFT_GATE` rad off: scales the lift command."""
    return float(np.clip(1.0 - abs(pitch - target) / LIFT_GATE, 0.0, 1.0))


@dataclass
class LoadingCyclePolicy(DigPolicy):
    """Scripted loading cycle (see module docstring); ``act(obs) -> action``.

    Attributes:
        dig: the bucket-fill policy used for the dig (default: scripted, TUNED).
        carry_pitch: bucket pitch held while carrying, rad (racked past 0.35 rad the heap is held,
            capacity_fraction = 1.1; 0.45 leaves 0.1 rad for the swing and keeps clear of the rack-back stop).
        carry_height: edge height while reversing, boom lengths (clear of the pile, low for stability).
        clearance: margin above the truck's side before moving over it, boom lengths.
        dump_reach: how far past the inside of the near wall the edge goes before tipping, boom lengths.
        haul_drive: drive command on the truck leg.
        empty_fill: fill below which the bucket counts as emptied (carry-back stays in it).
    """

    dig: Any = field(default_factory=lambda: ScriptedDigPolicy(**TUNED))
    carry_pitch: float = 0.45
    carry_height: float = 0.25
    clearance: float = 0.06
    dump_reach: float = 0.3
    haul_drive: float = 0.8
    empty_fill: float = 0.08

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.stage = CycleStage.DIG
        self._dump_steps = 0
        self._pitch: float | None = None
        if hasattr(self.dig, "reset"):
            self.dig.reset()

    def _dig_action(self, obs: np.ndarray) -> np.ndarray:
        view = obs[:N_DIG]
        if hasattr(self.dig, "act"):
            return np.asarray(self.dig.act(view), dtype=np.float32)
        return np.asarray(self.dig.predict(view, deterministic=True)[0], dtype=np.float32)

    def _dig_done(self, o: dict[str, float]) -> bool:
        if isinstance(self.dig, ScriptedDigPolicy):
            return self.dig.stage in (Stage.LIFT, Stage.PULL_BACK)  # the cycle lifts and carries from here
        return o["fill"] > 0.3 and o["edge_depth"] < -0.05 and o["bucket_pitch"] > 0.3  # the dig env's "clear"

    def act(self, obs: np.ndarray) -> np.ndarray:
        o = {k: float(obs[i]) for k, i in OBS_INDEX.items()}
        self._advance(o)
        pitch = o["bucket_pitch"]
        rate = 0.0 if self._pitch is None else pitch - self._pitch
        self._pitch = pitch
        if self.stage is CycleStage.DIG:
            return self._dig_action(obs)
        hold = _hold_pitch(pitch, rate, self.carry_pitch)
        gate = _gate(pitch, self.carry_pitch)
        if self.stage is CycleStage.REVERSE:
            lift = 0.6 * gate if o["edge_height"] < self.carry_height else 0.0
            return np.array([lift, hold, -1.0], dtype=np.float32)
        if self.stage is CycleStage.HAUL:
            clear = o["clearance"] > self.clearance
            lift = gate if o["clearance"] < self.clearance + 0.05 else 0.0
            # far from the truck: haul; close to it: creep once clear of its side, else wait for the boom
            drive = self.haul_drive if o["edge_x_to_truck"] < -0.5 else 0.3 if clear else 0.0
            return np.array([lift, hold, drive], dtype=np.float32)
        if self.stage is CycleStage.DUMP:
            tilt = 0.0 if o["truck_fill"] >= 1.0 else -1.0  # partial last dump: stop once the target is in
            return np.array([0.0, tilt, 0.0], dtype=np.float32)
        # BACK_OUT: clear the body before lowering, then lower and level on the way to the apex
        over = o["edge_x_to_truck"] > -0.1
        lift = 0.0 if over else -1.0
        tilt = 0.5 if over else _hold_pitch(pitch, rate, 0.0)
        return np.array([lift, tilt, -1.0], dtype=np.float32)

    def _advance(self, o: dict[str, float]) -> None:
        if self.stage is CycleStage.DIG and o["leg"] == 0.0 and self._dig_done(o):
            self.stage = CycleStage.REVERSE
        elif self.stage is CycleStage.REVERSE and o["leg"] == 1.0:
            self.stage = CycleStage.HAUL
        elif self.stage is CycleStage.HAUL and o["edge_x_to_truck"] > self.dump_reach and o["clearance"] > 0.0:
            self.stage, self._dump_steps = CycleStage.DUMP, 0
        elif self.stage is CycleStage.DUMP:
            self._dump_steps += 1
            if o["fill"] < self.empty_fill or o["truck_fill"] >= 1.0 or o["bucket_pitch"] < -1.0:
                self.stage = CycleStage.BACK_OUT
        elif self.stage is CycleStage.BACK_OUT and o["leg"] == 0.0:
            self.stage = CycleStage.DIG
            if hasattr(self.dig, "reset"):
                self.dig.reset()
