"""WheelLoaderLoadTruck-v1: the whole short loading cycle (dig, reverse, haul, raise, dump into a truck, return).

The machine and the pile are those of ``WheelLoaderDig-v1`` (same scales, laws, distortions and soils; soil
resistance, bucket fill and the combined bucket + load body reused from it), with the dump-capable tilt linkage of
:mod:`scaletwin_envs.envs.dump_linkage` (the presets' linkages cannot tip the bucket forward above ground height).

The bucket has dump and rack-back stops on the boom (``bucket_hinge`` limits,
:func:`~scaletwin_envs.envs.dump_linkage.bucket_stops`), as real loaders do: they keep link B away from its toggle,
so the bucket's pitch stays within about ±2.4 rad (never wraps past ±π) whatever the actions.

Planar V-cycle. The machine moves on one straight line (x). The pile lies ahead on the *pile leg*, the truck's
body ahead on the *truck leg*; reversing past the apex of the V (``turn_back`` boom lengths behind the start)
switches leg, which stands for the steering an operator does while reversing. Distances of both legs are measured
from the cutting edge at the start pose. Soil resistance acts on the pile leg only, contact with the truck's walls
and floor on the truck leg only.

Mass. Material leaves the bucket when it holds more than its pitch allows
(:func:`scaletwin_envs.physics.bucket.capacity_fraction`), except a film of ``carry_back`` × heaped capacity that
adhesion keeps in the bucket (carry-back). It falls from the cutting edge: into the truck when the edge is between
the truck's walls (on the truck leg), onto the pile when over the pile (pile leg), else on the ground (spill). Pile
(strip) + bucket + truck + spill is conserved to round-off (``info["mass_balance"]``).

Slumping. A face cut steeper than the pile's repose slope collapses to it (:func:`slump`, every control step) where
the soil cannot stand in a vertical cut as tall as the pile (Culmann / Terzaghi critical height
4c/γ·tan(45° + φ/2), :func:`critical_height`): cohesionless gravel and sand slump, the presets' cohesive soils
(critical height 5 m for sandy loam, 10 m for clay loam) stand. The dig env's pile never slumps (one dig); over
several passes in gravel its vertical faces, 0.5 L tall on the mini, stalled every dig after the second at 0.2-0.3
of a bucket (2026-11-28). The truck's payload, its
centre of mass (along the body, and height above the floor for a strip as wide as the bucket) and the passes are
tracked. The episode terminates once the truck holds ``done_fraction`` of its target payload and the bucket has
backed out of the body; it is truncated at ``max_episode_time`` or on a physics blow-up (``info["sim_error"]``).

Units: SI in ``info``; observation dimensionless (lengths / boom length L, speeds / √(gL), time / Froude time
√(L/g) scaled as below), so one policy acts at every scale.

Action: ``[lift, tilt, drive]`` in [-1, 1] (positive raises the boom, curls the bucket back, drives forward).

Observation (:data:`OBS_NAMES`): entries 0–18 are the dig env's observation (:data:`wheel_loader_dig.OBS_NAMES`)
for the current pass, so a bucket-fill policy trained on the dig env runs unchanged inside the cycle: ``time``,
``spilled`` and ``advance`` count from the start of the pass (the last switch to the pile leg), ``edge_x_to_pile``
is measured to the current face of the pile, and on the truck leg the pile entries read "no pile" (``edge_x_to_pile``
−1, ``edge_depth`` = −edge height, surfaces 0). Then:

=================== ===================================================================================
``leg``             0 pile leg, 1 truck leg
``edge_x_to_truck`` cutting edge x − inside of the truck's near wall, / L (positive: over the body)
``clearance``       lowest of edge, heel and back top of the bucket − top of the truck's side, / L
``truck_fill``      truck payload / target payload
``to_apex``         frame x − apex x, / L (reversing below 0 switches leg)
=================== ===================================================================================

Reward terms (``info["reward_terms"]``, summing to the reward): ``payload`` + delivered mass / target,
``time`` − dt / Froude time, ``energy`` − (hydraulic + drive work) / (heaped bucket of soil lifted by L),
``spill`` − ground spill / heaped bucket of soil, ``overload`` − payload above the target / target; each × its
weight. Phases (``info["phase"]``, from the machine's state): approach, penetrate, curl, lift, reverse_loaded,
haul (forward on the truck leg), dump (edge over the truck's body), reverse_empty, carry (loaded, at rest,
outside pile and truck), idle.

Version history:
    v0 (2026-11-26): initial release.
    v0 (2026-11-26, dynamics changed where the timestep did): the default timestep follows ``WheelLoaderDig-v0``'s
    rule (:func:`scaletwin_envs.builder.timestep_substeps`) with the variant's tilt slide as built (its oil column
    included): the ER12's Froude step in 2 parts (0.5 ms; the ratio is 21.1 against the rule's 21), the mini's in 3
    (0.126 ms), the WA475's whole. The first pass's dig is not converged at these steps: halving them moves its
    F21 by 2.8 % (ER12), 1.7 % (mini), 2.4 % (WA475), where a quarter of the Froude step gives 0.12 %, 0.48 %,
    0.57 % (scripted cycle, seed 0, commands replayed open loop); the tilt servo relays at relief (known limit).
    v1 (2026-11-26, with ``WheelLoaderDig-v1``; ``WheelLoaderLoadTruck-v0`` is no longer registered): the cylinders'
    servo is ``WheelLoaderDig-v1``'s constraint servo
    (:data:`scaletwin_envs.builder.SERVO_KINDS`), tuned to the variant's tilt slide as built
    (:func:`scaletwin_envs.builder.tune_relief`); the timestep is the Froude step at every scale (ER12 1 ms, mini
    0.378 ms, WA475 1.414 ms), where halving it moves the first pass's dig F21 by 0.33 %, 0.22 %, 1.0 % (scripted
    cycle in gravel, seed 0, dig rows up to the first dump, commands replayed open loop; 0.27 %, 1.07 %, 2.38 % at
    the old steps, measured the same way; both before the soil-refresh fix of ``WheelLoaderDig-v1``, which applies
    here too).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import mujoco
import numpy as np
from gymnasium import spaces

from scaletwin_envs.builder import build_spec, tune_relief
from scaletwin_envs.envs.dump_linkage import bucket_stops, dump_capable
from scaletwin_envs.envs.phases import DigPhase
from scaletwin_envs.envs.wheel_loader_dig import OBS_INDEX as DIG_INDEX
from scaletwin_envs.envs.wheel_loader_dig import OBS_LIMIT, WheelLoaderDigEnv
from scaletwin_envs.envs.wheel_loader_dig import OBS_NAMES as DIG_OBS_NAMES
from scaletwin_envs.physics.bucket import capacity_fraction
from scaletwin_envs.specs import make_loader
from scaletwin_envs.specs.laws import PRODUCT_LINE, ScalingLaw
from scaletwin_envs.specs.loader import GRAVITY, LoaderSpec
from scaletwin_envs.specs.soil import SoilSpec, make_soil

ENV_ID = "WheelLoaderLoadTruck-v1"
OBS_NAMES = (*DIG_OBS_NAMES, "leg", "edge_x_to_truck", "clearance", "truck_fill", "to_apex")
OBS_INDEX = {n: i for i, n in enumerate(OBS_NAMES)}
REWARD_TERMS = ("payload", "time", "energy", "spill", "overload")
PHASES = ("approach", "penetrate", "curl", "lift", "reverse_loaded", "haul", "dump", "reverse_empty", "carry", "idle")
DIG_TIME = 60.0  # Froude times: the dig env's default horizon, by which its ``time`` observation is normalised
WALL = 0.03  # truck wall and floor thickness, boom lengths (visual and contact; 7 cm on the ER12)
TRUCK_CELLS = 24  # bins of the truck's load profile along the body (for its centre of mass)
SPILL_SPREAD = 0.3  # boom lengths: width over which spill from the edge lands on the pile (the dig env's value)
LEG_REARM = 0.1  # boom lengths past the apex before another reversal can switch leg again (no chatter)
# Height that makes a face, boom lengths: lower layers (spill and the floor left in front of the face by earlier
# passes; up to ~0.12 L on the mini in gravel) are scraped up on the way in. At 2 % of L such a layer counted as the
# face, and the dig, which penetrates a set distance past the face, curled at the real face half empty (2026-11-27).
FACE_LEVEL = 0.15
MOVING = 0.02  # × √(gL): travel speed below which the machine counts as stopped (the dig phases' threshold)
# Carry-back: film kept by adhesion, fraction of heaped capacity: 1 % for cohesionless soil plus 0.3 % per kPa of
# soil-metal adhesion (gravel 1 %, clay loam 5.5 %; estimate in the range of the 1-10 % carry-back reported for
# dry to sticky materials).
CARRY_BACK_BASE, CARRY_BACK_PER_KPA = 0.01, 0.003
SLUMP_TOL = 1e-4  # boom lengths: material above the repose envelope left in place (no work on round-off)
SLUMP_ROUNDS = 8  # collapses (runs of over-steep columns) resolved per control step at most, per direction
BISECT = 60  # bisection steps placing a collapse's deposit (the volume then matches to round-off)


def critical_height(soil: SoilSpec) -> float:
    """Height (m) of a vertical cut the soil stands in (Culmann / Terzaghi): 4c/γ·tan(45° + φ/2); 0 without
    cohesion."""
    return 4.0 * soil.cohesion / soil.unit_weight * math.tan(0.25 * math.pi + 0.5 * soil.friction_angle)


def _collapse_left(h: np.ndarray, step: float, tol: float) -> bool:
    """Collapse the run of columns rising more than ``step`` (m per cell) from the lowest surface on their left
    that holds the most material: it slides to the left and settles as a slope of ``step`` per cell in front of
    the cut (a line shifted until its volume is the material cut, by bisection). Edits ``h`` (m) in place,
    keeping its sum to round-off; returns whether anything moved."""
    ramp = step * np.arange(h.size)
    envelope = np.minimum.accumulate(h - ramp) + ramp  # the highest surface no steeper than step from the left
    cut = h - envelope
    over = cut > tol
    if not over.any():
        return False
    edges = np.flatnonzero(np.diff(np.concatenate(([0], over.astype(np.int8), [0]))))
    runs = list(zip(edges[::2], edges[1::2] - 1, strict=True))
    lo, hi = max(runs, key=lambda r: float(cut[r[0] : r[1] + 1].sum()))
    volume = float(cut[lo : hi + 1].sum())
    base = h[: hi + 1].copy()
    base[lo:] = envelope[lo : hi + 1]
    cap = np.full(hi + 1, np.inf)
    cap[lo:] = h[lo : hi + 1]  # the cut columns settle no higher than they stood
    idx = np.arange(hi + 1)

    def settled(foot: float) -> np.ndarray:
        return np.maximum(base, np.minimum(step * (idx - foot), cap))

    near, far = float(hi), float(-hi - 1 - h.max() / step)  # deposit none / more than volume
    for _ in range(BISECT):
        mid = 0.5 * (near + far)
        if float((settled(mid) - base).sum()) > volume:
            far = mid
        else:
            near = mid
    new = settled(near)
    gain = new - base
    new[int(np.argmax(gain))] += volume - float(gain.sum())  # bisection's remainder (round-off)
    h[: hi + 1] = new
    return True


def slump(h: np.ndarray, step: float, tol: float) -> None:
    """Let over-steep faces of the height field ``h`` (m, one value per cell) collapse to slopes of ``step`` m per
    cell, both ways (:func:`_collapse_left` and its mirror), at most :data:`SLUMP_ROUNDS` collapses each; the
    sum of ``h`` is kept to round-off."""
    for flip in (False, True):
        view = h[::-1].copy() if flip else h
        for _ in range(SLUMP_ROUNDS):
            if not _collapse_left(view, step, tol):
                break
        if flip:
            h[:] = view[::-1]


def _number(name: str, value: Any, low: float = 0.0, strict: bool = True) -> float:
    ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or (value <= low if strict else value < low):
        raise ValueError(f"{name} must be a finite number {'>' if strict else '>='} {low}, got {value!r}")
    return float(value)


class WheelLoaderLoadTruckEnv(WheelLoaderDigEnv):
    """Load a truck over several passes (see module docstring).

    Args:
        scale, law, distortion, soil, pile_distance, pile_height, frame_skip, external_force_substeps,
            two_route_check, render_mode, width, height, timestep: as in ``WheelLoaderDig-v1`` (the default timestep
            reads the variant's tilt slide with its oil column, see ``_tilt_oil_ratio``).
        dump_linkage: build the dump-capable tilt linkage (:func:`dump_capable`); False keeps the machine's own,
            which cannot dump above ground height.
        truck_distance: cutting edge at the start to the outside of the truck's near wall, along the truck leg, L.
        truck_height: top of the truck's side above the ground, L.
        truck_width: inside length of the body along the travel direction (loading from the side: its width), L.
        truck_depth: top of the side to the body's floor, L.
        truck_payload: target payload, in heaped buckets of the soil (4 ≈ the usual 3-5 pass match).
        done_fraction: fraction of the target payload that ends the episode (once backed out of the body).
        turn_back: apex of the V behind the start position, L.
        carry_back: fraction of heaped capacity kept in the bucket by adhesion; None: from the soil's adhesion.
        max_episode_time: truncation, Froude times √(L/g).
        reset_noise_scale: start pose and pile perturbations as in the dig env (0 = none).
        payload_weight, time_cost_weight, energy_cost_weight, spill_cost_weight, overload_cost_weight: weights.
    """

    def __init__(
        self,
        scale: float | str | LoaderSpec = "er12",
        law: str | ScalingLaw = PRODUCT_LINE,
        distortion: Mapping[str, float] | None = None,
        soil: str | SoilSpec = "gravel",
        dump_linkage: bool = True,
        pile_distance: float = 0.5,
        pile_height: float = 0.7,
        truck_distance: float = 1.2,
        truck_height: float = 0.8,
        truck_width: float = 0.9,
        truck_depth: float = 0.4,
        truck_payload: float = 4.0,
        done_fraction: float = 0.95,
        turn_back: float = 0.8,
        carry_back: float | None = None,
        max_episode_time: float = 600.0,
        reset_noise_scale: float = 1.0,
        payload_weight: float = 1.0,
        time_cost_weight: float = 0.002,
        energy_cost_weight: float = 0.02,
        spill_cost_weight: float = 1.0,
        overload_cost_weight: float = 1.0,
        frame_skip: int | None = None,
        external_force_substeps: int | None = None,
        two_route_check: bool | None = None,
        render_mode: str | None = None,
        width: int = 640,
        height: int = 480,
        timestep: float | None = None,
    ) -> None:
        if not isinstance(dump_linkage, bool):
            raise ValueError(f"dump_linkage must be True or False, got {dump_linkage!r}")
        spec = make_loader(scale, law, distortion)
        self.truck = {
            k: _number(k, v)
            for k, v in (
                ("truck_distance", truck_distance),
                ("truck_height", truck_height),
                ("truck_width", truck_width),
                ("truck_depth", truck_depth),
            )
        }
        if self.truck["truck_depth"] >= self.truck["truck_height"]:
            raise ValueError(
                f"truck_depth ({truck_depth}) must be < truck_height ({truck_height}): the floor is above the ground"
            )
        self.truck_payload = _number("truck_payload", truck_payload)
        self.done_fraction = _number("done_fraction", done_fraction)
        if self.done_fraction > 1.0:
            raise ValueError(f"done_fraction must be in (0, 1], got {done_fraction!r}")
        self.turn_back = _number("turn_back", turn_back)
        soil_spec = make_soil(soil)
        if carry_back is None:
            carry_back = CARRY_BACK_BASE + CARRY_BACK_PER_KPA * soil_spec.adhesion / 1e3
        self.carry_back = _number("carry_back", carry_back, strict=False)
        if self.carry_back >= 1.0:
            raise ValueError(f"carry_back must be in [0, 1), got {carry_back!r}")
        self.load_weights = {
            "payload": payload_weight,
            "time": time_cost_weight,
            "energy": energy_cost_weight,
            "spill": spill_cost_weight,
            "overload": overload_cost_weight,
        }
        for k, v in self.load_weights.items():
            _number(f"{k} weight", v, strict=False)
        self.cycle_time_limit = _number("max_episode_time", max_episode_time)
        # Oil column of the tilt circuit (the tilt slide's armature, builder.cylinder_armature): the variant's
        # cylinder has ~4x the piston area, so ~4x the oil moving with the piston. Scaled with the area it keeps the
        # servo stiffness (kv ∝ relief force) to armature ratio of the machine's own cylinder; with the legacy
        # actuator servo, left at the original value, a 4x stiffer servo on the same armature, once at relief,
        # locked into a relay oscillation between its force limits every physics step (MuJoCo drops the servo's
        # implicit damping while it is clamped), in which the tilt command had no effect: on the mini the loaded
        # bucket then neither dumped nor held its pitch (2026-11-27). The constraint servo does not relay; the ratio
        # stays as the physics of the larger cylinder.
        self._tilt_oil_ratio = 1.0
        if dump_linkage:
            variant = dump_capable(spec)
            self._tilt_oil_ratio = variant.tilt.bore_area / spec.tilt.bore_area
            spec = variant
        self._truck_geoms: list[str] = []
        super().__init__(
            spec,
            law,
            None,
            soil=soil_spec,
            pile_distance=pile_distance,
            pile_height=pile_height,
            max_episode_time=DIG_TIME,
            reset_noise_scale=reset_noise_scale,
            frame_skip=frame_skip,
            external_force_substeps=external_force_substeps,
            two_route_check=two_route_check,
            render_mode=render_mode,
            width=width,
            height=height,
            timestep=timestep,
        )
        self.horizon = math.ceil(self.cycle_time_limit * self.loader.froude_time / self.dt - 1e-9)
        self.observation_space = spaces.Box(-OBS_LIMIT, OBS_LIMIT, shape=(len(OBS_NAMES),), dtype=np.float32)
        self._truck_ids = np.array([self.model.geom(n).id for n in self._truck_geoms[:3]])
        self._bucket_geoms = np.nonzero(self.model.geom_bodyid == self._bucket)[0]
        self._drive_act = self.model.actuator("drive").id
        self._heel_top = (self.model.site("bucket_heel").id, self.model.site("bucket_back_top").id)
        self._last_obs = np.zeros(len(OBS_NAMES), dtype=np.float32)

    def _tilt_armature_factor(self) -> float:
        return self._tilt_oil_ratio

    # -- model: the loader plus the truck's body -------------------------------------------------------------
    def _truck_x(self) -> tuple[float, float, float]:
        """Outside of the near wall, inside of the near wall, inside of the far wall (m, world x)."""
        L = self.loader.characteristic_length
        near = self.loader.geometry.bucket_edge[0] + self.truck["truck_distance"] * L
        inner = near + WALL * L
        return near, inner, inner + self.truck["truck_width"] * L

    def _initialize_simulation(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        s = build_spec(self.loader, self.build_options)
        L, opt = self.loader.characteristic_length, self.build_options
        hinge = s.joint("bucket_hinge")  # bucket stops on the boom: keep link B off its toggle (bucket_stops)
        hinge.limited = mujoco.mjtLimited.mjLIMITED_TRUE
        stops = bucket_stops(self.loader)  # rad; the spec reads joint ranges in degrees unless told otherwise
        hinge.range = [math.degrees(v) for v in stops] if s.compiler.degree else list(stops)
        s.joint("tilt_cylinder").armature *= self._tilt_oil_ratio  # the variant's oil column (see __init__)
        near, inner, far = self._truck_x()
        top, floor = self.truck["truck_height"] * L, (self.truck["truck_height"] - self.truck["truck_depth"]) * L
        half_w = 0.5 * WALL * L
        boxes = (
            ("truck_near_wall", near + half_w, 0.5 * (floor + top), half_w, 0.5 * (top - floor)),
            ("truck_far_wall", far + half_w, 0.5 * (floor + top), half_w, 0.5 * (top - floor)),
            ("truck_floor", 0.5 * (inner + far), floor - half_w, 0.5 * (far - inner), half_w),
            (
                "truck_chassis",
                0.5 * (near + far + WALL * L),
                0.5 * (floor - WALL * L),
                0.5 * (far - near + WALL * L),
                0.5 * (floor - WALL * L),
            ),
        )
        for name, x, z, hx, hz in boxes:
            s.worldbody.add_geom(
                name=name,
                type=mujoco.mjtGeom.mjGEOM_BOX,
                pos=[x, 0.0, z],
                size=[hx, 0.6 * L, hz],
                rgba=[0.2, 0.35, 0.6, 1],
                condim=1,
                contype=1,
                conaffinity=1,
                solref=[opt.constraint_timeconst, 1.0],
                solimp=opt.solimp,
            )
            self._truck_geoms.append(name)
        model = s.compile()  # compiled colliding (MuJoCo refuses to enable it later); _set_leg switches it off
        tune_relief(model, self.loader)  # the relief servo's softness reads the tilt slide's inertia as built
        chassis = model.geom("truck_chassis").id
        model.geom_contype[chassis] = model.geom_conaffinity[chassis] = 0  # below the floor: visual only
        model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
        model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
        return model, mujoco.MjData(model)

    def _set_leg(self, leg: int) -> None:
        """Switch leg: the truck's walls and floor collide with the bucket on the truck leg only."""
        self.leg = leg
        self.model.geom_contype[self._truck_ids] = leg
        self.model.geom_conaffinity[self._truck_ids] = leg
        if leg == 0:  # a new pass starts: the dig view of the observation counts from here
            self._pass_t0, self._pass_x0 = self._t, float(self.data.qpos[0])
            self._pass_spill0 = self.dig.spilled_volume
        self._delivered_this_leg = False

    # -- reset ----------------------------------------------------------------------------------------------
    def reset_model(self) -> np.ndarray:
        self.leg, self._armed = 0, True
        self._pass_t0 = self._pass_x0 = self._pass_spill0 = 0.0
        self.truck_volume = self.ground_spill = self.returned = 0.0
        self.truck_profile = np.zeros(TRUCK_CELLS)
        self.passes, self._delivered_this_leg = 0, False
        self._drive_work = 0.0
        self._t = 0.0
        super().reset_model()  # builds pile and dig model, reads signals and the observation
        self._set_leg(0)
        self._apex = float(self.data.qpos[0]) - self.turn_back * self.length
        # slope the pile was tipped at (the soil's repose angle as perturbed at reset), m per cell; None: faces stand
        stands = critical_height(self.soil) >= float(self.pile.h.max())
        self._slump_step = None if stands else float(np.diff(self.pile.initial).max()) * (1.0 + 1e-9)
        self.total_volume = self.pile.volume + self.dig.load_volume
        self._last_obs = self._get_obs()
        return self._last_obs

    def _get_reset_info(self) -> dict[str, Any]:
        return self._info(dict.fromkeys(REWARD_TERMS, 0.0), self._step_signals(), "idle", None)

    # -- soil, load and dump --------------------------------------------------------------------------------
    def _apply_external_forces(self) -> None:
        if self.leg == 0:
            super()._apply_external_forces()
        else:
            self.model.tendon_damping[self._dampers] = 0.0
            self.data.xfrc_applied[self._bucket] = 0.0

    def _after_physics(self) -> None:
        cavity = np.array([self._site_xz(n) for n in ("bucket_heel", "bucket_edge", "bucket_back_top")])
        held = capacity_fraction(self._bucket_pitch()) * self.dig.capacity
        if self._slump_step is not None:
            slump(self.pile.h, self._slump_step, SLUMP_TOL * self.length)
            self.pile.reshaped()
        if self.leg == 0:
            self._dig_in(cavity, held)
        excess = self.dig.load_volume - max(held, self.carry_back * self.dig.capacity)
        if excess > 0.0:
            self.dig.load_volume -= excess
            self._release(excess, float(cavity[1, 0]))
        self._update_payload()

    def _dig_in(self, cavity: np.ndarray, held: float) -> None:
        """Pile material inside the bucket cavity joins the load, up to what the pitch holds (volumes measured on
        the pile, so what leaves it is exactly what the bucket gains)."""
        room = held - self.dig.load_volume
        if room <= 0.0 or not self.pile.reaches(cavity):
            return
        idx, heights = self.pile.overlap(cavity)
        available = float(heights.sum() * self.pile.dx * self.pile.width)
        if available <= 0.0:
            return
        before = self.pile.volume
        self.pile.remove(idx, heights * min(1.0, room / available))
        self.dig.load_volume += before - self.pile.volume

    def _release(self, volume: float, edge_x: float) -> None:
        """Material leaving the bucket over the cutting edge at ``edge_x`` (m): truck, pile or ground."""
        _, inner, far = self._truck_x()
        if self.leg == 1 and inner < edge_x < far:
            cell = min(int((edge_x - inner) / (far - inner) * TRUCK_CELLS), TRUCK_CELLS - 1)
            self.truck_profile[cell] += volume
            self.truck_volume += volume
            if not self._delivered_this_leg:
                self.passes += 1
                self._delivered_this_leg = True
            return
        self.dig.spilled_volume += volume  # the dig view's ``spilled`` counts every release outside the truck
        if self.leg == 0:
            before = self.pile.volume
            self.pile.deposit(edge_x, volume, spread=SPILL_SPREAD * self.length)
            landed = self.pile.volume - before
            self.returned += landed
            self.ground_spill += volume - landed  # beyond the pile's strip
        else:
            self.ground_spill += volume

    # -- step -----------------------------------------------------------------------------------------------
    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self._check_running()  # stepping on after a sim_error raises EpisodeFinishedError, as in the dig env
        a = self._validate_action(action)
        rho, target = self.soil.density, self.target_mass
        before = {
            "truck": self.truck_volume * rho,
            "spill": self.ground_spill * rho,
            "over": max(self.truck_volume * rho - target, 0.0),
        }
        error = self._simulate(self._command_to_ctrl(a))
        self._t += self.dt
        if error is None:
            sig = self._read_signals(self.soil_force())
            error = None if self._finite(sig) else "non-finite signals"
        if error is not None:
            self.sim_error = error
            info = self._info(dict.fromkeys(REWARD_TERMS, 0.0), dict(self._good_signals), "error", error)
            return self._last_obs.copy(), 0.0, False, True, info
        self.signals = sig
        power = sum(max(sig[f"Pf_{k}"] * self.cylinder_state(k)[1], 0.0) for k in ("lift", "tilt"))
        drive = max(float(self.data.actuator_force[self._drive_act]) * sig["travel_speed"], 0.0)
        self._work += power * self.dt
        self._drive_work += drive * self.dt
        self._max_x = max(self._max_x, float(self.data.qpos[0]))
        self._update_leg()
        terms = self._terms(before, power + drive)
        reward = float(sum(terms.values()))
        obs = self._get_obs()
        self._last_obs = obs
        sig = self._step_signals()
        self.signals = self._good_signals = sig
        _, inner, _ = self._truck_x()
        out_of_body = (
            self.leg == 0 or float(self.data.site_xpos[self._sites["bucket_edge"]][0]) < inner - WALL * self.length
        )
        done = bool(self.truck_volume * rho >= self.done_fraction * target and out_of_body)
        truncated = self._t >= self.cycle_time_limit * self.loader.froude_time - 1e-9
        info = self._info(terms, sig, self.load_phase(), None)
        if self.render_mode == "human":
            self.render()
        return obs, reward, done, bool(truncated and not done), info

    def _update_leg(self) -> None:
        x = float(self.data.qpos[0])
        if self._armed and x < self._apex:
            self._armed = False
            self._set_leg(1 - self.leg)
        elif not self._armed and x > self._apex + LEG_REARM * self.length:
            self._armed = True

    @property
    def target_mass(self) -> float:
        """Target payload, kg."""
        return self.truck_payload * self.dig.capacity * self.soil.density

    def _terms(self, before: Mapping[str, float], power: float) -> dict[str, float]:
        w, rho, target = self.load_weights, self.soil.density, self.target_mass
        bucket_mass = self.dig.capacity * rho
        truck = self.truck_volume * rho
        return {
            "payload": w["payload"] * (truck - before["truck"]) / target,
            "time": -w["time"] * self.dt / self.loader.froude_time,
            "energy": -w["energy"] * power * self.dt / (bucket_mass * GRAVITY * self.length),
            "spill": -w["spill"] * (self.ground_spill * rho - before["spill"]) / bucket_mass,
            "overload": -w["overload"] * (max(truck - target, 0.0) - before["over"]) / target,
        }

    # -- state summaries -------------------------------------------------------------------------------------
    def truck_com(self) -> tuple[float, float]:
        """Centre of mass of the truck's load: along the body from its centre (m, + away from the loader) and
        height above the floor (m, columns of a strip as wide as the bucket); (0, 0) when empty."""
        if self.truck_volume <= 0.0:
            return 0.0, 0.0
        _, inner, far = self._truck_x()
        dx = (far - inner) / TRUCK_CELLS
        centres = inner + dx * (np.arange(TRUCK_CELLS) + 0.5) - 0.5 * (inner + far)
        heights = self.truck_profile / (dx * self.loader.geometry.bucket_width)
        v = self.truck_profile
        return float(v @ centres / v.sum()), float(v @ (0.5 * heights) / v.sum())

    def mass_balance(self) -> dict[str, float]:
        """Where the material is (kg): pile strip, bucket, truck, spill on the ground, and the total at reset."""
        rho = self.soil.density
        return {
            "pile": self.pile.volume * rho,
            "bucket": self.dig.load_volume * rho,
            "truck": self.truck_volume * rho,
            "spill": self.ground_spill * rho,
            "total": self.total_volume * rho,
        }

    def load_phase(self) -> str:
        """Phase label from the machine's state (see module docstring)."""
        speed = self.signals["travel_speed"] / self.speed_scale
        loaded = self.dig.fill() > 0.02 + self.carry_back
        edge_x = float(self.data.site_xpos[self._sites["bucket_edge"]][0])
        _, inner, far = self._truck_x()
        if self.leg == 0:
            dig = self.phase()
            if dig in (DigPhase.PENETRATE, DigPhase.CURL):
                return dig.name.lower()
        elif inner < edge_x < far:
            return "dump"
        if speed < -MOVING:
            return "reverse_loaded" if loaded else "reverse_empty"
        if speed > MOVING:
            if loaded:
                return "haul" if self.leg == 1 else "lift"
            return "approach" if self.leg == 0 else "haul"
        if loaded:
            return "carry"
        return "idle"

    def _info(
        self, terms: Mapping[str, float], sig: Mapping[str, float], phase: str, error: str | None
    ) -> dict[str, Any]:
        rho, target = self.soil.density, self.target_mass
        truck = self.truck_volume * rho
        com_x, com_z = self.truck_com()
        hyd, drv = self._work, self._drive_work
        return {
            "signals": dict(sig),
            "phase": phase,
            "reward_terms": dict(terms),
            "leg": self.leg,
            "passes": self.passes,
            "truck_payload": truck,
            "truck_com_x": com_x,
            "truck_com_z": com_z,
            "target_payload": target,
            "payload_error": (truck - target) / target,
            "fill_factor": float(self.dig.fill()),
            "loaded_mass": self.dig.load_volume * rho,
            "spilled_mass": self.ground_spill * rho,
            "returned_mass": self.returned * rho,
            "hydraulic_work": hyd,
            "drive_work": drv,
            "time": self._t,
            "mass_balance": self.mass_balance(),
            "success": bool(truck >= self.done_fraction * target and error is None),
            "sim_error": error,
            "action_clipped": bool(getattr(self, "action_clipped", False)),
        }

    # -- observation ----------------------------------------------------------------------------------------
    def _pile_face(self) -> float:
        """x of the pile's current face (m): the first column above :data:`FACE_LEVEL` × L, extrapolated down the
        repose slope to the ground (the toe itself on an undug pile)."""
        level = FACE_LEVEL * self.length
        above = np.nonzero(self.pile.h > level)[0]
        if above.size == 0:
            return float(self.pile.x[-1])
        k = int(above[0])
        x = float(self.pile.x[k])
        if k > 0:  # interpolate the crossing inside the cell
            h0, h1 = float(self.pile.h[k - 1]), float(self.pile.h[k])
            x -= self.pile.dx * (h1 - level) / max(h1 - h0, 1e-12)
        return x - level / math.tan(self.soil.repose_angle)

    def _get_obs(self) -> np.ndarray:
        dig = super()._get_obs().astype(np.float64)
        L, TF = self.length, self.loader.froude_time
        edge = self._site_xz("bucket_edge")
        dig[DIG_INDEX["time"]] = (self._t - self._pass_t0) / (DIG_TIME * TF)
        dig[DIG_INDEX["spilled"]] = (self.dig.spilled_volume - self._pass_spill0) / self.dig.capacity
        dig[DIG_INDEX["advance"]] = (float(self.data.qpos[0]) - self._pass_x0) / L
        if self.leg == 0:
            dig[DIG_INDEX["edge_x_to_pile"]] = (edge[0] - self._pile_face()) / L
        else:
            dig[DIG_INDEX["edge_x_to_pile"]] = -1.0
            dig[DIG_INDEX["edge_depth"]] = -edge[1] / L
            dig[DIG_INDEX["surface_ahead_1"]] = dig[DIG_INDEX["surface_ahead_2"]] = 0.0
        _, inner, _ = self._truck_x()
        lowest = min(edge[1], *(float(self.data.site_xpos[s][2]) for s in self._heel_top))
        extra = (
            float(self.leg),
            (edge[0] - inner) / L,
            (lowest - self.truck["truck_height"] * L) / L,
            self.truck_volume * self.soil.density / self.target_mass,
            (float(self.data.qpos[0]) - self._apex) / L if hasattr(self, "_apex") else self.turn_back,
        )
        obs = np.nan_to_num(np.concatenate([dig, extra]), nan=0.0, posinf=OBS_LIMIT, neginf=-OBS_LIMIT)
        return np.clip(obs, -OBS_LIMIT, OBS_LIMIT).astype(np.float32)
