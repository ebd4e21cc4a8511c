"""The three presets are three machines: each its own linkage layout and hydraulics, each a valid design."""

from __future__ import annotations

from dataclasses import fields, replace

import numpy as np
import pytest

from scaletwin_envs.design_space import MOVABLE_PINS, RAISE_TIME_S, check_design
from scaletwin_envs.physics.statics import static_at
from scaletwin_envs.specs import make_loader
from scaletwin_envs.specs.presets import ER12, PRESETS


def normalised_pins(name: str) -> np.ndarray:
    """Every movable pin relative to the boom pivot, in boom lengths (1): the layout without its size."""
    geo = make_loader(name).geometry
    L, (px, pz) = geo.boom_length, geo.boom_pivot
    return np.array([((x - px) / L, (z - pz) / L) for x, z in (getattr(geo, p) for p in MOVABLE_PINS)])


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_is_a_valid_design(name: str) -> None:
    v = check_design(make_loader(name))
    assert v.ok, v.reasons


def test_the_presets_are_three_layouts_not_one_scaled() -> None:
    names = sorted(PRESETS)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            moved = np.abs(normalised_pins(a) - normalised_pins(b)).max()
            assert moved >= 0.02, f"{a} and {b} share a linkage layout (largest pin difference {moved:.4f} L)"
    for name in ("mini", "wa475"):
        assert "ER12 layout x" not in make_loader(name).provenance["geometry"]


def test_wa475_raises_in_the_published_band() -> None:
    wa = make_loader("wa475")
    raise_s = wa.lift.stroke / wa.lift.extend_speed
    assert RAISE_TIME_S[0] <= raise_s <= RAISE_TIME_S[1]
    assert check_design(wa).raise_time_s == pytest.approx(raise_s)


@pytest.mark.parametrize("name", ["mini", "wa475"])
def test_layout_changes_the_cylinder_forces_that_hold_a_load(name: str) -> None:
    """Statics at rest with the rated load: the machine and the same machine on the ER12 layout (same masses,
    bores, bucket) need different cylinder forces, so a model of the ER12 layout cannot simply be resized."""
    spec = make_loader(name)
    ratio = spec.geometry.boom_length / ER12.geometry.boom_length
    er12_layout = {f.name: getattr(ER12.geometry, f.name) for f in fields(ER12.geometry) if f.name in MOVABLE_PINS}
    resized = replace(spec, geometry=replace(spec.geometry, **{
        k: (v[0] * ratio, v[1] * ratio) for k, v in er12_layout.items()}))
    pose = (0.3, -0.4)  # boom raised, bucket racked back: a carry pose inside every workspace (rad)
    own = static_at(spec, *pose, payload_mass=spec.rated_load)
    other = static_at(resized, *pose, payload_mass=spec.rated_load)
    lift_change = abs(own.Pf_lift / other.Pf_lift - 1)
    tilt_change = abs(own.Pf_tilt / other.Pf_tilt - 1)
    assert max(lift_change, tilt_change) > 0.03, (lift_change, tilt_change)
