"""Machine specifications: presets against the paper, scaling laws, validation."""

from __future__ import annotations

import math

import pytest

from scaletwin_envs.physics.statics import breakout_force
from scaletwin_envs.specs import FROUDE, LoaderSpec, make_loader, make_soil, preset_names

PAPER_MASSES = {"mini": 11.0, "er12": 3300.0, "wa475": 26000.0}


@pytest.mark.parametrize("name", sorted(PAPER_MASSES))
def test_preset_operating_mass_matches_paper(name: str) -> None:
    assert make_loader(name).operating_mass == pytest.approx(PAPER_MASSES[name], rel=0.05)


def test_table2_component_masses() -> None:
    er12, mini = make_loader("er12"), make_loader("mini")
    assert er12.masses.bucket == pytest.approx(205.8 + 84.8)
    assert er12.masses.boom == pytest.approx(294.6)
    assert er12.masses.link_b == pytest.approx(8.99)
    assert mini.masses.bell_crank == pytest.approx(0.04)
    assert mini.masses.boom == pytest.approx(0.32)


@pytest.mark.parametrize("name", ["mini", "er12", "wa475"])
def test_breakout_force_per_weight_is_plausible(name: str) -> None:
    spec = make_loader(name)
    assert 0.5 <= breakout_force(spec) / spec.weight <= 1.5


@pytest.mark.parametrize("name", ["mini", "er12", "wa475"])
def test_every_preset_value_names_a_source(name: str) -> None:
    provenance = make_loader(name).provenance
    for key in ("operating_mass", "relief_pressure", "geometry", "rated_load"):
        assert provenance.get(key)


def test_froude_law_is_geometric_similarity() -> None:
    base, big = make_loader(1.0, law=FROUDE), make_loader(2.0, law=FROUDE)
    assert big.operating_mass / base.operating_mass == pytest.approx(8.0, rel=1e-9)
    assert big.characteristic_length / base.characteristic_length == pytest.approx(2.0)
    assert big.tilt.relief_pressure / base.tilt.relief_pressure == pytest.approx(2.0)
    assert big.lift.extend_speed / base.lift.extend_speed == pytest.approx(math.sqrt(2.0))
    assert big.froude_time / base.froude_time == pytest.approx(math.sqrt(2.0))


def test_product_line_law_distorts_like_a_real_line() -> None:
    small, big = make_loader(0.2), make_loader(2.0)
    # hydraulic force per weight falls with size; cycle time in seconds nearly constant
    assert small.tilt.max_extend_force / small.weight > 1.5 * big.tilt.max_extend_force / big.weight
    t_small = small.lift.stroke / small.lift.extend_speed
    t_big = big.lift.stroke / big.lift.extend_speed
    assert t_big / t_small < math.sqrt(2.0 / 0.2)


def test_law_brackets_the_paper_machines() -> None:
    assert make_loader(1 / 7).operating_mass == pytest.approx(11.0, rel=0.1)
    assert make_loader(2.0).operating_mass == pytest.approx(26000.0, rel=0.1)


def test_distortion_overrides_one_factor() -> None:
    plain, heavy = make_loader(0.5), make_loader(0.5, distortion={"mass": 1.2})
    assert heavy.operating_mass == pytest.approx(1.2 * plain.operating_mass)
    assert heavy.tilt.bore == plain.tilt.bore
    preset = make_loader("mini", distortion={"pressure": 2.0})
    assert preset.lift.relief_pressure == pytest.approx(2.0 * make_loader("mini").lift.relief_pressure)


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), 0.01, 5.0, "huge", True, None])
def test_bad_scale_is_rejected_with_what_is_accepted(bad: object) -> None:
    with pytest.raises(ValueError, match="scale"):
        make_loader(bad)  # type: ignore[arg-type]


def test_bad_distortion_and_soil_are_rejected() -> None:
    with pytest.raises(ValueError, match="unknown distortion keys"):
        make_loader(1.0, distortion={"weight": 2.0})
    with pytest.raises(ValueError, match="distortion"):
        make_loader(1.0, distortion={"mass": -1.0})
    with pytest.raises(ValueError, match="gravel"):
        make_soil("mud")


def test_spec_json_round_trip() -> None:
    for name in preset_names():
        spec = make_loader(name)
        back = LoaderSpec.from_dict(spec.to_dict())
        assert back == spec
    with pytest.raises(ValueError, match="LoaderSpec"):
        LoaderSpec.from_dict({"name": "x"})
