"""A scripted short loading cycle for ``WheelLoaderLoadTruck-v1``, built on any bucket-fill (dig) policy.

The dig is delegated to a dig policy acting on the dig view of the observation (entries 0–18, the dig env's
:data:`~scaletwin_envs.envs.wheel_loader_dig.OBS_NAMES`): the scripted :class:`ScriptedDigPolicy` (with the
:data:`TUNED` parameters) or a learned one (anything with ``act`` or Stable-Baselines3's ``predict``, e.g.
``zoo.load("bucketfill-ppo")``); the default, :class:`FaceDigPolicy`, is the scripted dig with a lift-crowd cut on
the face left by earlier passes. The rest is a state machine on the dimensionless observation, so the same
thresholds serve every size: lift the loaded bucket clear of the pile while backing off slowly (on the last pass,
tip back onto the pile what the truck no longer needs), reverse with the
bucket racked (the boom rising while the bucket is below carry height) until the leg switches, haul forward raising
the boom, stop with the edge over the body once it clears the truck's side, tip until the bucket is empty (or the
truck holds its target: partial last dump), back out, lower, and hand back to the dig policy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np

from scaletwin_envs.envs.load_truck import OBS_INDEX
from scaletwin_envs.envs.wheel_loader_dig import OBS_INDEX as DIG_OBS_INDEX
from scaletwin_envs.envs.wheel_loader_dig import OBS_NAMES as DIG_OBS_NAMES
from scaletwin_envs.physics.bucket import capacity_fraction
from scaletwin_envs.policies.base import DigPolicy
from scaletwin_envs.policies.scripted import TUNED, ScriptedDigPolicy, Stage

N_DIG = len(DIG_OBS_NAMES)
#: Dig-view entries that count from the start of a dig-env episode (re-based at each handover to a learned dig).
_RESTARTED = [DIG_OBS_INDEX[k] for k in ("time", "spilled", "advance")]


class CycleStage(IntEnum):
    """Stages of the cycle, in their order within a pass."""

    DIG = 0
    REVERSE = 1
    HAUL = 2
    DUMP = 3
    BACK_OUT = 4
    LIFT_OUT = 5  # between DIG and REVERSE (numbered last so the earlier values keep their meaning)
    SHED = 6  # between LIFT_OUT and REVERSE on the last pass: tip back onto the pile what the truck does not need
    RETURN = 7  # between BACK_OUT and DIG for a dig policy without an approach of its own (a learned one)


# The dump linkage turns the bucket 4-6x faster per unit of tilt stroke than the presets' (velocity ratio
# dL/dθ ≈ 0.025-0.035 L/rad against 0.15), and ~3x faster again near its rack-back stop (0.012 L/rad), where a dig
# leaves it: a full tilt command turns it by up to ~0.6 rad in one control step there. At 1.2/rad with a D term on
# the one-step pitch change the loop swung a loaded mini bucket between -0.1 and 1.0 rad every 4-5 steps and threw a
# quarter of its load (2026-11-27); at 0.4/rad without D (per-step loop gain ≤ 0.25) the bucket settles on target.
PITCH_KP = 0.4  # tilt command per rad of pitch error
PITCH_KD = 0.0  # tilt command per rad of pitch change in one step (a D term on a one-step-old rate destabilised it)
SHED_MIN_TILT = 0.05  # smallest forward tilt command while shedding: the last hundredths of surplus still go
# rad: pitch error at which raising stops, so the hold keeps up with the racking of the boom (0.5: with the slower
# hold, 0.25 held the boom still for most of the haul, 2026-11-27)
LIFT_GATE = 0.5


#: (fill, pitch) pairs of the bucket's capacity curve over the pitches where it changes (rad: empty at about -0.9,
#: the full heap from 0.35): the pitch at which the bucket holds a given fill, by interpolation.
_PITCHES = np.linspace(-0.9, 0.35, 126)
_HELD = np.array([capacity_fraction(float(p)) for p in _PITCHES])


def pitch_holding(fill: float) -> float:
    """Bucket pitch (rad) at which the bucket holds ``fill`` (fraction of heaped capacity) and spills the rest
    (:func:`~scaletwin_envs.physics.bucket.capacity_fraction` inverted)."""
    return float(np.interp(fill, _HELD, _PITCHES))


def _hold_pitch(pitch: float, rate: float, target: float, kp: float = PITCH_KP, kd: float = PITCH_KD) -> float:
    """Tilt command holding the bucket pitch at ``target`` (rad): PD on the pitch (rad) and its change over the last
    step (``rate``, rad per step; steps are a fixed fraction of the Froude time at every scale); ``kp`` per rad,
    ``kd`` per rad per step."""
    return float(np.clip(kp * (target - pitch) - kd * rate, -1.0, 1.0))


def _gate(pitch: float, target: float) -> float:
    """1 with the pitch on target, falling to 0 at :data:`LIFT_GATE` rad off: scales the lift command."""
    return float(np.clip(1.0 - abs(pitch - target) / LIFT_GATE, 0.0, 1.0))


@dataclass
class FaceDigPolicy(ScriptedDigPolicy):
    """The scripted dig, cutting a slice off a dug face: while penetrating, the boom rises as soon as the cutting
    edge is deeper than ``cut_depth`` below the surface above it, so the cut stays that deep.

    After the first pass the pile ends in a face about as tall as the pile (0.5 L of 0.65 on the mini in gravel);
    driven straight into it at ground level the bucket stalls within a few hundredths of L with 0.1-0.2 of a bucket
    (2026-11-27), where a lift-crowd cut up the face fills it. On the undug pile's slope the cut is shallower than
    ``cut_depth`` for most of the penetration, so the first pass is the plain scripted dig.

    Attributes (besides :class:`ScriptedDigPolicy`'s):
        cut_depth: edge depth below the pile surface above it kept while penetrating, boom lengths.
        cut_gain: lift command per boom length of depth beyond ``cut_depth``.
        face_steps: control steps of a dig for which a slow penetration with the cut deeper than ``cut_depth``
            does not count as a stall (40 ≈ 8 Froude times, several times what the boom needs to lift a cut).
        face_reach: distance to the face (extrapolated to the ground) within which the approach may turn into
            penetration, boom lengths.
        lower_above: edge height above which the approach lowers the boom at full speed, boom lengths.
    """

    cut_depth: float = 0.25
    cut_gain: float = 5.0
    face_steps: int = 40
    face_reach: float = 0.1
    lower_above: float = 0.05

    def reset(self) -> None:
        """Start a new dig."""
        super().reset()
        self._face = 0

    def _advance(self, o: dict[str, float]) -> None:
        # a pass hands over on the way back from the truck, the boom still raised and the bucket often tipped onto
        # the ground (edge_depth > 0 off the pile): penetrating from there ran the edge into the face at 0.2 L
        # height and curled after a 0.6 L push at 0.1-0.3 of a bucket (er12 and mini in gravel, 2026-11-28);
        # the approach lowers the boom and levels the bucket until the edge is at the face
        if self.stage is Stage.APPROACH and o["edge_x_to_pile"] < -self.face_reach:
            return
        # slowed by the face while the boom brings the cut up to cut_depth is not a stall (the scripted dig curls
        # after 3 slow steps), for at most face_steps steps (a boom that cannot lift the cut then curls)
        if self.stage is Stage.PENETRATE and o["edge_depth"] > self.cut_depth and self._face < self.face_steps:
            self._face += 1
            self._stall = 0
        super()._advance(o)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """The scripted dig's action, the lift replaced while penetrating (see class docstring)."""
        action = super().act(obs)
        if self.stage is Stage.APPROACH and obs[DIG_OBS_INDEX["edge_height"]] > self.lower_above:
            # back from the truck the boom is still up: the scripted approach's slow lowering (-0.3) left the edge
            # 0.16 L up when it met the pile at λ 0.5, and the cut skimmed the slope (0.13 of a bucket, 2026-11-25)
            action[0] = -1.0
        if self.stage is Stage.PENETRATE:
            depth = float(obs[DIG_OBS_INDEX["edge_depth"]])
            action[0] = float(np.clip(self.cut_gain * (depth - self.cut_depth), 0.0, 1.0))
        return action


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
        lift_out_drive: drive command while the boom lifts the loaded bucket out of the pile (the scripted dig's
            TUNED ``lift_drive``: backing off slowly keeps the bucket from dragging through the face).
        pile_clearance: edge height above the pile surface before reversing at full speed, boom lengths (the
            scripted dig's ``clearance``).
        empty_fill: fill below which the bucket counts as emptied (carry-back stays in it).
        pitch_kp, pitch_kd: gains of the pitch hold (:data:`PITCH_KP`, :data:`PITCH_KD`).
        lift_rate: largest change of the lift command from one control step to the next outside the dig (a
            control step is a fixed fraction of the Froude time, so the boom ramps alike at every size).
        shed_margin: fill (fraction of heaped capacity) kept above what the truck still needs when the last
            pass tips the surplus back onto the pile.
        shed_tilt: largest tilt command while shedding (the dump linkage turns up to ~0.6 rad per step at full
            command near rack-back: slowly, the fill follows the pitch without overshooting).
        shed_gain: forward tilt command per bucket fill of surplus while shedding (between
            :data:`SHED_MIN_TILT` and ``shed_tilt``).
        shed_clearance: edge height above the pile surface the boom rises to before the bucket tips, L.
        dig_gap: distance from the cutting edge to the pile face at which a dig policy without an approach of its
            own (anything but a :class:`ScriptedDigPolicy`) takes over, L: the dig env's ``pile_distance``, so a
            learned dig starts each pass where it was trained to start (bucket level on the ground, facing the pile).
        return_drive: drive command on the way back to ``dig_gap``.
        full_steps: control steps a dig policy without stages of its own may keep a full bucket (fill ≥
            ``full_fill``) in the pile before the cycle lifts it out: a learned dig ends its dig-env episode by
            clearing the pile, but on a face standing in cohesive soil it was seen to crowd a full bucket on into
            the pile for 1.5 L (wa475, clay loam, 2026-11-25); 15 steps ≈ 3 Froude times.
        full_fill: fill (fraction of heaped capacity) counted as full for ``full_steps``.
        dig_retreat: distance in front of the turn (``to_apex``, L) at which a dig policy without stages of its
            own that backs away is taken over: a learned dig that curled a nearly empty bucket pulled back past
            the turn, which switched the env to the truck leg with 0.07 of a bucket (mini, gravel, seed 1,
            2026-11-25); a bucket above 0.3 is carried, a lighter one taken back to the pile for another dig.

    The last pass takes what the truck still needs: the truck's payload per bucket fill is learnt from the dumps
    so far (``truck_fill`` gained over bucket fill emptied), so the policy needs no truck size; after the dig, a
    bucket holding more than ``(1 - truck_fill)`` worth is raised clear of the pile and tipped forward over it
    until it holds just that before reversing (the surplus runs back onto the pile; :func:`pitch_holding` gives
    the pitch that holds a fill).
    """

    dig: Any = field(default_factory=lambda: FaceDigPolicy(**TUNED))
    carry_pitch: float = 0.45
    carry_height: float = 0.25
    clearance: float = 0.06
    dump_reach: float = 0.3
    haul_drive: float = 0.8
    lift_out_drive: float = -0.3
    pitch_kp: float = PITCH_KP
    pitch_kd: float = PITCH_KD
    pile_clearance: float = 0.08
    empty_fill: float = 0.08
    lift_rate: float = 0.2
    shed_margin: float = 0.03
    shed_tilt: float = 0.3
    shed_gain: float = 1.0
    shed_clearance: float = 0.2
    dig_gap: float = 0.5
    return_drive: float = 0.5
    full_steps: int = 15
    full_fill: float = 1.0
    dig_retreat: float = 0.1

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.stage = CycleStage.DIG
        self._dump_steps = 0
        self._pitch: float | None = None
        self._lift = 0.0  # last lift command
        self._dumped_fill = self._dumped_truck = 0.0  # bucket fill emptied and truck_fill gained by the dumps
        self._before: tuple[float, float] = (0.0, 0.0)  # fill and truck_fill as the current dump started
        self._full = 0  # control steps the bucket has been full in the current dig
        self._dig_origin: np.ndarray | None = None  # time, spilled, advance at the handover to a learned dig
        if hasattr(self.dig, "reset"):
            self.dig.reset()

    def needed_fill(self, truck_fill: float) -> float:
        """Bucket fill (fraction of heaped capacity) that brings the truck to its target from ``truck_fill``; inf
        before the first dump (the truck's size in buckets is not known yet)."""
        if self._dumped_truck <= 0.0 or self._dumped_fill <= 0.0:
            return math.inf
        return max(1.0 - truck_fill, 0.0) * self._dumped_fill / self._dumped_truck

    def _dig_action(self, obs: np.ndarray) -> np.ndarray:
        view = obs[:N_DIG]
        if not isinstance(self.dig, ScriptedDigPolicy):
            # the dig view as the dig env shows it from the start of an episode: time, spill and advance count
            # from this handover, not from the pass's switch to the pile leg (a learned dig handed over 20 Froude
            # times into its pass read it as the end of its episode and pulled back at once: mini, 2026-11-25)
            if self._dig_origin is None:
                self._dig_origin = view[_RESTARTED].copy()
            view = view.copy()
            view[_RESTARTED] -= self._dig_origin
        if hasattr(self.dig, "act"):
            return np.asarray(self.dig.act(view), dtype=np.float32)
        return np.asarray(self.dig.predict(view, deterministic=True)[0], dtype=np.float32)

    def _dig_done(self, o: dict[str, float]) -> bool:
        if isinstance(self.dig, ScriptedDigPolicy):
            return self.dig.stage in (Stage.LIFT, Stage.PULL_BACK)  # the cycle lifts and carries from here
        self._full = self._full + 1 if o["fill"] >= self.full_fill else 0
        if self._full >= self.full_steps:
            return True  # full and still in the pile: the cycle lifts it out (see full_steps)
        return o["fill"] > 0.3 and o["edge_depth"] < -0.05 and o["bucket_pitch"] > 0.3  # the dig env's "clear"

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Action ``[lift, tilt, drive]`` in [-1, 1] for the load-truck observation ``obs`` (:data:`OBS_INDEX`)."""
        o = {k: float(obs[i]) for k, i in OBS_INDEX.items()}
        self._advance(o)
        pitch = o["bucket_pitch"]
        rate = 0.0 if self._pitch is None else pitch - self._pitch
        self._pitch = pitch
        if self.stage is CycleStage.DIG:
            action = self._dig_action(obs)
        else:
            self._dig_origin = None
            action = self._carry_action(o, pitch, rate)
            # the boom starts and stops gradually: a lift command stepping between 0 and 1 (bang-bang height
            # keeping, the pitch gate) rocked the loaded bucket on its tilt cylinder by ±0.3 rad per step on the
            # mini, shook 0.15 of a bucket out on the way back and throttled the raise at the truck (2026-11-28)
            step = self.lift_rate
            action[0] = float(np.clip(action[0], self._lift - step, self._lift + step))
        self._lift = float(action[0])
        return action

    def _carry_action(self, o: dict[str, float], pitch: float, rate: float) -> np.ndarray:
        """The action of every stage but the dig (see the module docstring); ``rate``: pitch change in the last
        step, rad."""
        hold = _hold_pitch(pitch, rate, self.carry_pitch, self.pitch_kp, self.pitch_kd)
        gate = _gate(pitch, self.carry_pitch)
        if self.stage is CycleStage.LIFT_OUT:
            # boom up out of the pile at full speed, backing off slowly: a bucket dragged back through the pile
            # or along the ground bounces and throws its heap (mini, 2026-11-27)
            return np.array([1.0, hold, self.lift_out_drive], dtype=np.float32)
        if self.stage is CycleStage.SHED:
            # boom up to shed_clearance over the pile (tipped near it, the edge ran into it), then tip forward
            # faster the more surplus is left (the fill follows the pitch within a step: no overshoot to wait on)
            lift = 1.0 if o["edge_depth"] > -self.shed_clearance else 0.0
            surplus = o["fill"] - self.needed_fill(o["truck_fill"])
            tilt = -float(np.clip(self.shed_gain * surplus, SHED_MIN_TILT, self.shed_tilt))
            if o["edge_depth"] > -self.pile_clearance:
                tilt = hold
            return np.array([lift, tilt, 0.0], dtype=np.float32)
        if self.stage is CycleStage.REVERSE:
            # below carry height the boom rises whatever the pitch (the bucket must not touch the ground);
            # above it, it waits for the hold
            lift = 1.0 if o["edge_height"] < self.carry_height else 0.0
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
        if self.stage is CycleStage.RETURN:
            # boom down until the edge is on the ground, bucket level, forward to where a dig env episode starts
            lift = -1.0 if o["edge_height"] > 0.02 else 0.0
            return np.array([lift, _hold_pitch(pitch, rate, 0.0), self.return_drive], dtype=np.float32)
        # BACK_OUT: clear the body before lowering, then lower and level on the way to the apex
        over = o["edge_x_to_truck"] > -0.1
        lift = 0.0 if over else -1.0
        tilt = 0.5 if over else _hold_pitch(pitch, rate, 0.0)
        return np.array([lift, tilt, -1.0], dtype=np.float32)

    def _advance(self, o: dict[str, float]) -> None:
        if (self.stage is CycleStage.DIG and o["leg"] == 0.0 and o["to_apex"] < self.dig_retreat
                and not isinstance(self.dig, ScriptedDigPolicy)):
            # a learned dig backing away towards the turn (its dig-env episodes end with a pull back): carry on
            # with what it holds, or, nearly empty, return to the pile and dig again
            self.stage, self._full = (CycleStage.REVERSE if o["fill"] > 0.3 else CycleStage.RETURN), 0
        elif self.stage is CycleStage.DIG and o["leg"] == 0.0 and self._dig_done(o):
            self.stage, self._full = CycleStage.LIFT_OUT, 0
        elif self.stage is CycleStage.LIFT_OUT and (o["edge_depth"] < -self.pile_clearance or o["leg"] == 1.0):
            surplus = o["fill"] > self.needed_fill(o["truck_fill"]) + self.shed_margin
            self.stage = CycleStage.SHED if surplus and o["leg"] == 0.0 else CycleStage.REVERSE
        elif self.stage is CycleStage.SHED:
            shed = o["fill"] <= self.needed_fill(o["truck_fill"]) + self.shed_margin
            if shed or o["bucket_pitch"] < pitch_holding(0.0):  # (an empty bucket: nothing more to shed)
                self.stage = CycleStage.REVERSE
        elif self.stage is CycleStage.REVERSE and o["leg"] == 1.0:
            self.stage = CycleStage.HAUL
        elif self.stage is CycleStage.HAUL and o["edge_x_to_truck"] > self.dump_reach and o["clearance"] > 0.0:
            self.stage, self._dump_steps = CycleStage.DUMP, 0
            self._before = (o["fill"], o["truck_fill"])
        elif self.stage is CycleStage.DUMP:
            self._dump_steps += 1
            if o["fill"] < self.empty_fill or o["truck_fill"] >= 1.0 or o["bucket_pitch"] < -1.0:
                self.stage = CycleStage.BACK_OUT
                self._dumped_fill += self._before[0] - o["fill"]
                self._dumped_truck += o["truck_fill"] - self._before[1]
        elif self.stage is CycleStage.BACK_OUT and o["leg"] == 0.0:
            self.stage = CycleStage.DIG if isinstance(self.dig, ScriptedDigPolicy) else CycleStage.RETURN
            if hasattr(self.dig, "reset"):
                self.dig.reset()
        elif self.stage is CycleStage.RETURN and o["edge_x_to_pile"] >= -self.dig_gap:
            self.stage = CycleStage.DIG
