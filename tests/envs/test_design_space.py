"""The product-line design space: valid, reproducible samples, distortions that act as documented, the
tilt-linkage force ratio against the full statics, and sampled machines that dig in the simulator."""

from __future__ import annotations

import dataclasses
import json
import math
import time
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import scaletwin_envs
from scaletwin_envs import design_space
from scaletwin_envs.design_space import (
    BREAKOUT_PER_WEIGHT,
    BUCKET_M3_PER_T,
    MOVABLE_PINS,
    RAISE_TIME_MASS_T,
    RAISE_TIME_S,
    DesignSpace,
    ProductLineMachine,
    assembles_over_workspace,
    build_design,
    check_design,
    reference_workspace,
)
from scaletwin_envs.physics.bucket import heaped_capacity
from scaletwin_envs.physics.kinematics import boom_angle_for_lift_length, solve_pose, tilt_ratio
from scaletwin_envs.physics.statics import static_at
from scaletwin_envs.policies import ScriptedDigPolicy
from scaletwin_envs.recording.sweep import EpisodeTask
from scaletwin_envs.rollout import run_episode
from scaletwin_envs.specs import make_loader
from scaletwin_envs.specs.loader import LoaderSpec

#: Every factor key of a distortion vector and the DesignSpace range that bounds it.
FACTOR_RANGES = {"lift_bore": "bore", "tilt_bore": "bore", "pressure": "pressure", "lift_flow": "flow",
                 "tilt_flow": "flow", "lift_range": "lift_range", "mass": "mass", "boom_mass": "body_mass",
                 "bucket_mass": "body_mass", "bucket_size": "bucket_size", "bucket_depth": "bucket_depth",
                 "traction": "traction", "travel_speed": "travel_speed"}
PIN_KEYS = {f"pin.{p}.{a}" for p in MOVABLE_PINS for a in "xz"}
#: Every design switched off but the size: the law's machine at each λ.
NO_DISTORTION = dict(pin_offset=0.0, bore=1.0, pressure=1.0, flow=1.0, lift_range=1.0, mass=1.0, body_mass=1.0,
                     bucket_size=1.0, bucket_depth=1.0, traction=1.0, travel_speed=1.0)
#: Poses (boom, bucket relative to boom; rad) where the tilt cylinder carries a clear load (far from zero force).
LOADED_POSES = ((0.0, 0.0), (0.3, 0.5), (0.6, 0.3), (0.2, -0.3))


@pytest.fixture(scope="module")
def line() -> list[ProductLineMachine]:
    """Twelve machines of the default design space, seed 3."""
    return DesignSpace().sample(12, seed=3)


def _numbers(d: dict[str, Any], prefix: str = "") -> dict[str, float]:
    """Every numeric leaf of a nested spec dictionary, keyed by its path."""
    out: dict[str, float] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_numbers(v, f"{prefix}{k}."))
        elif isinstance(v, list | tuple):
            out.update({f"{prefix}{k}[{i}]": float(x) for i, x in enumerate(v)})
        elif isinstance(v, int | float) and not isinstance(v, bool):
            out[prefix + k] = float(v)
    return out


def _stroke_bounds(spec: LoaderSpec) -> tuple[float, float]:
    """Boom angles (rad) at the lift cylinder's closed and fully extended lengths."""
    g, lift = spec.geometry, spec.lift
    return boom_angle_for_lift_length(g, lift.closed_length), boom_angle_for_lift_length(
        g, lift.closed_length + lift.stroke)


def _er12_raise() -> tuple[float, float]:
    poses = reference_workspace()
    return min(b for b, _ in poses), max(b for b, _ in poses)


def _massless_linkage(spec: LoaderSpec) -> LoaderSpec:
    """``spec`` with (near) massless bell crank, link B and tilt cylinder: the assumption of :func:`tilt_ratio`."""
    masses = dataclasses.replace(spec.masses, link_b=1e-9, bell_crank=1e-9)
    tilt = dataclasses.replace(spec.tilt, barrel_mass=1e-9, rod_mass=1e-9)
    return dataclasses.replace(spec, masses=masses, tilt=tilt)


# ------------------------------------------------------------------------------------------------- sampling


def test_every_sample_is_valid_and_inside_its_ranges(line: list[ProductLineMachine]) -> None:
    """Each sample assembles over the workspace, passes check_design again, lies in the published bands, and
    its distortion vector has every key with factors in [1/r, r] and pin offsets in ±pin_offset."""
    space = DesignSpace()
    assert len(line) == 12
    for m in line:
        assert assembles_over_workspace(m.spec)
        again = check_design(m.spec)
        assert again.ok, again.reasons
        assert again == m.validity
        m3_per_t = heaped_capacity(m.spec.geometry) / (m.spec.operating_mass / 1000)
        assert BUCKET_M3_PER_T[0] <= m3_per_t <= BUCKET_M3_PER_T[1]
        assert BREAKOUT_PER_WEIGHT[0] <= again.breakout_per_weight <= BREAKOUT_PER_WEIGHT[1]
        raise_s = m.spec.lift.stroke / m.spec.lift.extend_speed
        if RAISE_TIME_MASS_T[0] <= m.spec.operating_mass / 1000 <= RAISE_TIME_MASS_T[1]:
            assert RAISE_TIME_S[0] <= raise_s <= RAISE_TIME_S[1]
        assert set(m.distortion) == {"scale", *PIN_KEYS, *FACTOR_RANGES}
        assert space.scale[0] <= m.scale == m.distortion["scale"] == m.spec.scale <= space.scale[1]
        for key, rng_name in FACTOR_RANGES.items():
            r = getattr(space, rng_name)
            assert 1 / r <= m.distortion[key] <= r, key
        assert all(abs(m.distortion[k]) <= space.pin_offset for k in PIN_KEYS)
        assert m.rejected >= 0 and m.spec.name == m.name
    # the draws really vary (not the law machine twelve times)
    assert len({round(m.distortion["mass"], 9) for m in line}) == 12
    assert max(m.scale for m in line) / min(m.scale for m in line) > 3


def test_sampling_is_reproducible_and_index_stable(line: list[ProductLineMachine]) -> None:
    """Same (seed, index) gives the same machine; another seed another; sample_one(seed, i) is sample(n, seed)[i]."""
    space = DesignSpace()
    a, b = space.sample_one(3, 5), space.sample_one(3, 5)
    assert a.spec.to_dict() == b.spec.to_dict()
    assert dict(a.distortion) == dict(b.distortion)
    assert a.to_dict() == line[5].to_dict()
    assert space.sample_one(3, 11).to_dict() == line[11].to_dict()
    assert space.sample(3, seed=3)[2].to_dict() == line[2].to_dict()
    other = space.sample_one(4, 5)
    assert dict(other.distortion) != dict(a.distortion)
    assert other.spec != a.spec
    assert space.sample(0, seed=3) == []
    with pytest.raises(ValueError, match="n must be"):
        space.sample(-1)


@pytest.mark.parametrize("scale", [0.3, 1.0, 2.2])
def test_undistorted_design_is_the_product_line_law(scale: float) -> None:
    """build_design({"scale": s}) equals make_loader(s) in every numeric field (float rounding only)."""
    built = _numbers(build_design({"scale": scale}).to_dict())
    law = _numbers(make_loader(scale).to_dict())
    assert set(built) == set(law)
    L = make_loader(scale).characteristic_length
    for key, value in law.items():
        assert math.isclose(built[key], value, rel_tol=1e-9, abs_tol=1e-12 * L), key


# ------------------------------------------------------------------------------------------------ distortions


def test_cylinder_and_mass_distortions_act_as_documented() -> None:
    """Bore × with unchanged speed (flow follows), relief ×, pump flow ×, operating mass ×, bucket ×³, traction ×."""
    base = build_design({})
    bore = build_design({"lift_bore": 1.2})
    assert bore.lift.bore == pytest.approx(1.2 * base.lift.bore, rel=1e-12)
    assert bore.lift.max_extend_force == pytest.approx(1.44 * base.lift.max_extend_force, rel=1e-12)
    assert bore.lift.extend_speed == pytest.approx(base.lift.extend_speed, rel=1e-12)
    assert bore.tilt == base.tilt
    pressure = build_design({"pressure": 0.9})
    for cyl, ref in ((pressure.lift, base.lift), (pressure.tilt, base.tilt)):
        assert cyl.relief_pressure == pytest.approx(0.9 * ref.relief_pressure, rel=1e-12)
        assert cyl.bore == ref.bore and cyl.extend_speed == pytest.approx(ref.extend_speed, rel=1e-12)
    flow = build_design({"lift_flow": 1.1})
    assert flow.lift.stroke / flow.lift.extend_speed == pytest.approx(
        base.lift.stroke / base.lift.extend_speed / 1.1, rel=1e-12)
    mass = build_design({"mass": 1.1})
    assert mass.operating_mass == pytest.approx(1.1 * base.operating_mass, rel=1e-12)
    assert mass.linkage_mass == pytest.approx(1.1 * base.linkage_mass, rel=1e-12)
    assert mass.rated_load == pytest.approx(1.1 * base.rated_load, rel=1e-12)
    heavy_boom = build_design({"boom_mass": 1.25})
    assert heavy_boom.masses.boom == pytest.approx(1.25 * base.masses.boom, rel=1e-12)
    assert heavy_boom.masses.bucket == base.masses.bucket
    bucket = build_design({"bucket_size": 1.1})
    assert heaped_capacity(bucket.geometry) == pytest.approx(1.1**3 * heaped_capacity(base.geometry), rel=1e-9)
    assert bucket.rated_load == pytest.approx(1.1**3 * base.rated_load, rel=1e-12)
    deeper = build_design({"bucket_depth": 1.1})
    assert heaped_capacity(deeper.geometry) > heaped_capacity(base.geometry)
    assert build_design({"traction": 0.8}).traction_coefficient == pytest.approx(0.8 * base.traction_coefficient)
    assert build_design({"travel_speed": 1.2}).travel_speed == pytest.approx(1.2 * base.travel_speed)


@pytest.mark.parametrize("key", ["pin.lift_frame_pin.z", "pin.lift_boom_pin.x", "pin.bell_crank_top.z",
                                 "pin.pin_21.x", "pin.tilt_frame_pin.z"])
def test_moving_a_pin_moves_only_it_and_strokes_follow(key: str) -> None:
    """A pin offset moves that pin alone by offset × boom length; the lift stroke is recomputed so that the boom
    still sweeps the ER12's raise angle, and the tilt stroke still spans every workspace pose."""
    base = build_design({})
    moved = build_design({key: 0.02})
    pin, axis = key.split(".")[1], "xz".index(key.split(".")[2])
    L = base.characteristic_length
    assert moved.characteristic_length == pytest.approx(L, rel=1e-12)
    for f in dataclasses.fields(base.geometry):
        a, b = getattr(moved.geometry, f.name), getattr(base.geometry, f.name)
        if f.name == pin:
            assert a[axis] == pytest.approx(b[axis] + 0.02 * L, rel=1e-12)
            assert a[1 - axis] == b[1 - axis]
        else:
            assert a == b, f.name
    lo, hi = _er12_raise()
    assert _stroke_bounds(moved) == pytest.approx((lo, hi), abs=1e-8)  # lengths rounded to 1 nm (LENGTH_DIGITS)
    tilt_lengths = [solve_pose(moved.geometry, b, k).tilt_length for b, k in reference_workspace()]
    assert moved.tilt.closed_length <= min(tilt_lengths) + 1e-9
    assert max(tilt_lengths) <= moved.tilt.closed_length + moved.tilt.stroke + 1e-9
    # which stroke changed says which cylinder the pin belongs to
    lift_pin = pin.startswith("lift_")
    assert (moved.lift.stroke != pytest.approx(base.lift.stroke, rel=1e-6)) == lift_pin
    assert (moved.tilt.stroke != pytest.approx(base.tilt.stroke, rel=1e-6)) == (not lift_pin)


def test_lift_range_stretches_the_raise_angle() -> None:
    """lift_range × stretches the boom's raise angle about the lowered pose."""
    lo, hi = _er12_raise()
    assert _stroke_bounds(build_design({"lift_range": 1.05})) == pytest.approx((lo, lo + 1.05 * (hi - lo)), abs=1e-8)


# ------------------------------------------------------------------------------------------------ invalid input


@pytest.mark.parametrize(("design", "named"), [
    ({"bogus": 1.0}, "bogus"), ({"mass": float("nan")}, "'mass'"), ({"pressure": 0.0}, "'pressure'"),
    ({"lift_bore": -1.2}, "'lift_bore'"), ({"pin.pin_21.x": float("inf")}, "'pin.pin_21.x'"),
    ({"scale": -1.0}, "'scale'"),
])
def test_invalid_design_vector_names_the_key(design: dict[str, float], named: str) -> None:
    """A non-finite, non-positive or unknown entry raises ValueError naming it."""
    with pytest.raises(ValueError, match=named):
        build_design(design)


def test_unassemblable_design_is_refused() -> None:
    """A link-B pin moved so far that link B cannot close over the workspace is a ValueError, not a spec."""
    with pytest.raises(ValueError, match="does not assemble"):
        build_design({"pin.bell_crank_bottom.x": 0.03})


@pytest.mark.parametrize("kwargs", [
    {"bore": 0.9}, {"pressure": 0.5}, {"travel_speed": float("nan")}, {"scale": (0.5, 0.4)},
    {"scale": (0.01, 1.0)}, {"scale": (1.0, 4.0)}, {"pin_offset": 0.2}, {"pin_offset": -0.01},
    {"movable_pins": ("boom_pivot",)},
])
def test_invalid_design_space_is_refused(kwargs: dict[str, Any]) -> None:
    """Range factors < 1, bad scale ranges, pin offsets outside [0, 0.1] and unknown pins are ValueErrors."""
    with pytest.raises(ValueError):
        DesignSpace(**kwargs)


def test_space_the_bands_reject_entirely_raises(monkeypatch: pytest.MonkeyPatch) -> None:
    """Law machines of λ 0.05–0.06 are over-powered (breakout ≈ 1.7 × weight): with nothing to distort them
    back into the band, sampling gives up with RuntimeError (draw limit cut to 10 to keep the test fast)."""
    for s in (0.05, 0.06):
        v = check_design(make_loader(s))
        assert v.breakout_per_weight > BREAKOUT_PER_WEIGHT[1]
        assert any("breakout" in r for r in v.reasons)
    monkeypatch.setattr(design_space, "MAX_DRAWS", 10)
    with pytest.raises(RuntimeError, match="no valid design in 10 draws"):
        DesignSpace(scale=(0.05, 0.06), **NO_DISTORTION).sample_one(0, 0)


# ------------------------------------------------------------------------------------------------ tilt ratio


def test_tilt_ratio_is_the_statics_of_a_massless_linkage(line: list[ProductLineMachine]) -> None:
    """With massless bell crank, link B and tilt cylinder, F21/|Pf_tilt| of the full Newton–Euler statics equals
    tilt_ratio (to solver precision) at every pose and load, for the ER12 and three sampled machines."""
    for spec in (make_loader("er12"), *(m.spec for m in line[:3])):
        light = _massless_linkage(spec)
        for boom, bucket in (*LOADED_POSES, (1.0, 0.6)):
            r = tilt_ratio(spec.geometry, boom, boom + bucket)
            assert math.isfinite(r) and r > 0
            for load in (0.0, spec.rated_load):
                s = static_at(light, boom, bucket, payload_mass=load)
                assert s.F21 / abs(s.Pf_tilt) == pytest.approx(r, rel=1e-6), (spec.name, boom, bucket, load)


def test_tilt_ratio_error_is_the_linkage_weight(line: list[ProductLineMachine]) -> None:
    """With real masses tilt_ratio misses the statics by the bell crank's and link B's own weight: within 2 % at
    rated load, and the miss shrinks monotonically as the payload grows (0, ½, 1, 3 × rated load)."""
    for spec in (make_loader("er12"), *(m.spec for m in line[:3])):
        for boom, bucket in LOADED_POSES:
            r = tilt_ratio(spec.geometry, boom, boom + bucket)
            miss = []
            for load in (0.0, 0.5, 1.0, 3.0):
                s = static_at(spec, boom, bucket, payload_mass=load * spec.rated_load)
                assert s.Pf_tilt > 0  # the tilt cylinder pushes against the loaded bucket's weight
                miss.append(abs(s.F21 / s.Pf_tilt / r - 1))
            where = (spec.name, boom, bucket, miss)
            assert miss[2] < 0.02, where
            assert miss[3] < 0.01, where
            assert miss[0] > miss[1] > miss[2] > miss[3] > 0, where


# ------------------------------------------------------------------------------------------------ simulation


def test_sampled_machines_dig_in_the_simulator(line: list[ProductLineMachine]) -> None:
    """Two sampled machines run the scripted cycle in gravel without a physics error and fill the bucket
    (final load > 0.3 × rated load); the env is built from the very spec given (about 0.3 s each)."""
    for m in line[:2]:
        start = time.perf_counter()
        env = gym.make(scaletwin_envs.ENV_ID, scale=m.spec, soil="gravel")
        try:
            episode = run_episode(env, ScriptedDigPolicy(), seed=0)
            assert env.unwrapped.loader == m.spec
        finally:
            env.close()
        assert episode.kpis is not None and episode.kpis.sim_error is None
        load = episode.signal("m_load")
        assert load[-1] > 0.3 * m.spec.rated_load, (m.name, load[-1] / m.spec.rated_load)
        assert time.perf_counter() - start < 30.0  # generous: the machine is shared with other work


def test_episode_task_carries_a_design_as_its_dictionary(line: list[ProductLineMachine]) -> None:
    """An EpisodeTask with scale=spec.to_dict() gives the spec back, also after a JSON round trip, and two
    designs give two task keys."""
    spec = line[0].spec
    task = EpisodeTask(scale=spec.to_dict(), soil="gravel", pile_distance=0.5, pile_height=0.7, seed=0)
    assert task.machine() == spec
    back = EpisodeTask(**json.loads(json.dumps(task.params())))
    assert back.machine() == spec
    assert back.key() == task.key()
    assert dataclasses.replace(task, scale=line[1].spec.to_dict()).key() != task.key()
    assert EpisodeTask(scale=0.5, soil="gravel", pile_distance=0.5, pile_height=0.7, seed=0).machine() == 0.5
    assert isinstance(task.machine(), LoaderSpec)
    assert np.isfinite(task.machine().operating_mass)
