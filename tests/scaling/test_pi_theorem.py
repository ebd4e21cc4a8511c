"""Unit parsing, canonical Buckingham-Pi groups, set enumeration and manifests (oracles: classic problems)."""

from __future__ import annotations

import itertools
import json
import math
import random
from fractions import Fraction

import pytest
import sympy

from scaling import PiGroup, PiSet, enumerate_pi_sets, pi_groups, read_manifest, write_manifest
from scaling.dimensions.pi_theorem import canonical_order, dimension_matrix, lattice_vectors, null_space_rref
from scaling.dimensions.units import conversion_factor, dimension_of, dimension_vector

F = Fraction
PENDULUM = {"T": "s", "L": "m", "m": "kg", "g": "m/s^2"}
DRAG = {"F": "N", "rho": "kg/m^3", "V": "m/s", "b": "m", "mu": "Pa*s"}
FREE_FALL = {"x0": "m", "g": "m/s^2", "t": "s"}
BUBBLE = {"dp": "Pa", "R": "m", "sigma": "N/m"}
PIPE = {"dp": "Pa", "rho": "kg/m^3", "V": "m/s", "D": "m", "L": "m", "mu": "Pa*s", "k": "m"}
EQ10 = {"F21": "N", "F31": "N", "Pf_tilt": "N", "Pf_lift": "N", "x_b": "m", "y_b": "m", "m_b": "kg",
        "a1": "m/s^2", "alpha1": "rad/s^2"}
LENGTHS = {"y": "m", "a": "m", "b": "m", "c": "m"}
EQ23 = {**{k: v for k, v in EQ10.items() if k not in ("a1", "alpha1")}, "V1": "m/s", "w1": "rad/s"}
PROBLEMS = {"pendulum": (PENDULUM, "T"), "drag": (DRAG, "F"), "free_fall": (FREE_FALL, "x0"),
            "bubble": (BUBBLE, "dp"), "pipe": (PIPE, "dp"), "eq10": (EQ10, "F21"), "eq23": (EQ23, "F21")}


def ray(exponents: dict[str, Fraction | int], target: str) -> tuple:
    """A group up to a non-zero power: divide by the target exponent, else by the first variable's (sorted)."""
    exps = {k: F(v) for k, v in exponents.items() if v}
    pivot = exps[target] if target in exps else exps[min(exps)]
    return tuple(sorted((k, v / pivot) for k, v in exps.items()))


def rays(pi_set: PiSet) -> frozenset:
    return frozenset(ray(dict(g.exponents), pi_set.target) for g in pi_set.groups)


def exprs(groups: list[PiGroup]) -> list[str]:
    return [g.expression() for g in groups]


# --- units -----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("unit", "expected"), [
    ("N", {"mass": 1, "length": 1, "time": -2}), ("kN", {"mass": 1, "length": 1, "time": -2}),
    ("m/s^2", {"length": 1, "time": -2}), ("rad/s^2", {"time": -2}), ("kg", {"mass": 1}), ("mm", {"length": 1}),
    ("Pa*s", {"mass": 1, "length": -1, "time": -1}), ("N*m", {"mass": 1, "length": 2, "time": -2}),
    ("1", {}), ("", {}), ("dimensionless", {}), ("rad", {}), ("mol", {"amount": 1}), ("m^0.5", {"length": F(1, 2)}),
])
def test_dimension_vector(unit: str, expected: dict) -> None:
    assert dimension_vector(unit) == {k: F(v) for k, v in expected.items()}


@pytest.mark.parametrize("bad", ["furlongz", "m^", "3 m", "kg m ^ x"])
def test_bad_unit_names_variable_and_unit(bad: str) -> None:
    with pytest.raises(ValueError, match=r"variable 'x_b'.*" + bad.split()[0].replace("^", r"\^")):
        pi_groups({"F21": "N", "x_b": bad, "m_b": "kg"}, "F21")


def test_conversion_factor() -> None:
    assert conversion_factor("mm") == pytest.approx(1e-3)
    assert conversion_factor("kN") == pytest.approx(1e3)
    assert conversion_factor("g") == pytest.approx(1e-3)


# --- canonical groups --------------------------------------------------------------------------------------------


def test_classic_canonical_groups() -> None:
    assert exprs(pi_groups(PENDULUM, "T")) == ["T*g^(1/2)/L^(1/2)"]  # m drops out
    assert exprs(pi_groups(DRAG, "F")) == ["F*rho/mu^2", "V*b*rho/mu"]  # F/(rho V^2 b^2) = pi1/pi2^2, pi2 = Re
    assert exprs(pi_groups(FREE_FALL, "x0")) == ["x0/(g*t^2)"]
    assert exprs(pi_groups(BUBBLE, "dp")) == ["R*dp/sigma"]  # rank 2 with 3 dimensions used: one group
    assert exprs(pi_groups(PIPE, "dp")) == ["dp*k^2*rho/mu^2", "D/k", "L/k", "V*k*rho/mu"]
    assert exprs(pi_groups(PENDULUM)) == ["L/(T^2*g)"]  # no target: primitive integers


@pytest.mark.parametrize("problem", sorted(PROBLEMS))
def test_groups_are_dimensionless_complete_and_hold_target_once(problem: str) -> None:
    variables, target = PROBLEMS[problem]
    groups = pi_groups(variables, target)
    expected = {"pendulum": 1, "drag": 2, "free_fall": 1, "bubble": 1, "pipe": 4, "eq10": 6, "eq23": 6}[problem]
    assert len(groups) == expected
    assert all(dimension_of(g.exponents, variables) == {} for g in groups)
    assert [target in g.exponents for g in groups] == [True] + [False] * (expected - 1)
    assert groups[0].exponents[target] == 1 and groups[0].name == "pi1"
    PiSet(tuple(groups), target, variables).validate()


@pytest.mark.parametrize("problem", ["drag", "pipe", "eq10"])
def test_permuting_inputs_gives_identical_output(problem: str) -> None:
    variables, target = PROBLEMS[problem]
    ref = [g.to_dict() for g in pi_groups(variables, target)]
    ref_sets = [(s.description, s.to_dict()) for s in enumerate_pi_sets(variables, target, max_lattice_sets=20)]
    rng = random.Random(7)
    for _ in range(3):
        items = list(variables.items())
        rng.shuffle(items)
        shuffled = dict(items)
        assert [g.to_dict() for g in pi_groups(shuffled, target)] == ref
        got = [(s.description, s.to_dict()) for s in enumerate_pi_sets(shuffled, target, max_lattice_sets=20)]
        assert got == ref_sets


def test_changing_unit_scales_changes_no_group() -> None:
    scaled = {**EQ10, "F21": "kN", "F31": "mN", "x_b": "mm", "y_b": "km", "m_b": "g", "a1": "mm/ms^2",
              "alpha1": "deg/ms^2"}
    assert [g.to_dict() for g in pi_groups(scaled, "F21")] == [g.to_dict() for g in pi_groups(EQ10, "F21")]
    assert enumerate_pi_sets(scaled, "F21", max_lattice_sets=10) == enumerate_pi_sets(EQ10, "F21", max_lattice_sets=10)


def test_dimensionless_target_is_its_own_group() -> None:
    assert exprs(pi_groups({"eta": "1", "P": "W", "Q": "kW"}, "eta")) == ["eta", "P/Q"]


def test_errors_and_empty_results() -> None:
    with pytest.raises(ValueError, match="target 'Z' is not one of"):
        pi_groups(PENDULUM, "Z")
    with pytest.raises(ValueError, match="cannot be made dimensionless"):
        pi_groups({"F": "N", "theta": "rad", "L": "m"}, "F")
    with pytest.raises(ValueError, match="non-empty mapping"):
        pi_groups({})
    with pytest.warns(UserWarning, match="dimensionally independent"):
        assert pi_groups({"L": "m", "t": "s"}, "L") == []
    with pytest.warns(UserWarning, match="dimensionally independent"):
        assert enumerate_pi_sets({"L": "m", "t": "s", "M": "kg"}, "L") == []


# --- set enumeration ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("problem", sorted(PROBLEMS))
def test_every_enumerated_set_is_valid_and_unique(problem: str) -> None:
    variables, target = PROBLEMS[problem]
    sets = enumerate_pi_sets(variables, target, max_lattice_sets=30)
    assert sets and len(set(sets)) == len(sets) == len({rays(s) for s in sets})
    n_groups = len(pi_groups(variables, target))
    for s in sets:
        s.validate()  # dimensionless, n - rank independent groups, target once with exponent 1
        assert len(s.groups) == n_groups
        assert all(dimension_of(g.exponents, variables) == {} for g in s.groups)
    assert PiSet(tuple(pi_groups(variables, target)), target, variables) in sets  # canonical basis is a candidate


def test_set_identity_is_groups_up_to_powers() -> None:
    base = PiSet((PiGroup({"y": 1, "a": -1}), PiGroup({"a": 1, "b": -1})), "y", LENGTHS)
    powered = PiSet((PiGroup({"y": 2, "a": -2}), PiGroup({"a": -3, "b": 3})), "y", LENGTHS, "other", "origin")
    other = PiSet((PiGroup({"y": 1, "a": -1}), PiGroup({"a": 1, "c": -1})), "y", LENGTHS)
    assert base == powered and hash(base) == hash(powered) and base != other
    assert len({base, powered, other}) == 2


def test_textbook_sets_are_enumerated() -> None:
    drag = {rays(s) for s in enumerate_pi_sets(DRAG, "F")}
    reynolds = ray({"rho": 1, "V": 1, "b": 1, "mu": -1}, "F")
    assert frozenset({ray({"F": 1, "rho": -1, "V": -2, "b": -2}, "F"), reynolds}) in drag
    pipe = {rays(s) for s in enumerate_pi_sets(PIPE, "dp", lattice=False)}
    assert frozenset({ray({"dp": 1, "rho": -1, "V": -2}, "dp"), ray({"L": 1, "D": -1}, "dp"),
                      ray({"rho": 1, "V": 1, "D": 1, "mu": -1}, "dp"), ray({"k": 1, "D": -1}, "dp")}) in pipe
    assert [s.expressions() for s in enumerate_pi_sets(FREE_FALL, "x0")] == [["x0/(g*t^2)"]]
    assert [s.expressions() for s in enumerate_pi_sets(BUBBLE, "dp")] == [["R*dp/sigma"]]


def test_eq10_paper_pi1_arises_when_f31_repeats() -> None:
    sets = enumerate_pi_sets(EQ10, "F21", lattice=False)
    assert all(s.origin == "repeating" for s in sets) and len(sets) >= 20
    with_f31 = [s for s in sets if "F31" in s.description.split(": ")[1].split(", ")]
    assert with_f31 and all(s.target_group.expression() == "F21/F31" for s in with_f31)
    assert all(s.target_group.expression() != "F21/F31" for s in sets if s not in with_f31)
    # the canonical basis picks the lexicographically last repeating variables instead
    assert pi_groups(EQ10, "F21")[0].expression() == "F21/(alpha1*m_b*y_b)"


def test_lattice_search_respects_bounds_and_budget() -> None:
    sets = enumerate_pi_sets(EQ10, "F21", max_exponent=1, max_lattice_sets=150)
    lattice = [s for s in sets if s.origin == "lattice"]
    assert len(lattice) == 150
    for s in lattice:
        for g in s.groups:
            scale = 1 if "F21" not in g.exponents else max(e.denominator for e in g.exponents.values())
            assert all(abs(e * scale) <= 1 for e in g.exponents.values())
    with pytest.warns(UserWarning, match="lattice search skipped"):
        enumerate_pi_sets(EQ10, "F21", max_exponent=3, max_lattice_points=1000)


@pytest.mark.parametrize(("problem", "bound"), [("drag", 2), ("pipe", 1)])
def test_lattice_vectors_are_exhaustive(problem: str, bound: int) -> None:
    variables, target = PROBLEMS[problem]
    order = canonical_order(variables, target)
    d = dimension_matrix(variables, order)
    rows, pivots = null_space_rref(d)
    found = set(lattice_vectors(rows, pivots, bound))
    brute = set()
    for v in itertools.product(range(-bound, bound + 1), repeat=len(order)):
        first = next((x for x in v if x), 0)
        if first > 0 and math.gcd(*v) == 1 and all(x == 0 for x in d * sympy.Matrix(v)):
            brute.add(v)
    assert found == brute and len(found) > len(rows)


def test_manifest_round_trip(tmp_path) -> None:
    sets = enumerate_pi_sets(EQ10, "F21", max_lattice_sets=5)
    path = tmp_path / "sets.json"
    write_manifest(sets, path)
    payload = json.loads(path.read_text())
    assert payload["count"] == len(sets) and payload["variables"] == EQ10 and payload["target"] == "F21"
    exponents = payload["sets"][0]["groups"][0]["exponents"]
    assert payload["n_groups"] == 6 and all(isinstance(e, str) for e in exponents.values())
    back = read_manifest(path)
    assert back == sets
    assert [(s.origin, s.description, s.expressions()) for s in back] == [
        (s.origin, s.description, s.expressions()) for s in sets]


def test_manifest_rejects_tampering(tmp_path) -> None:
    path = tmp_path / "sets.json"
    write_manifest(enumerate_pi_sets(PENDULUM, "T"), path)
    payload = json.loads(path.read_text())
    payload["sets"][0]["groups"][0]["exponents"]["g"] = "1"
    path.write_text(json.dumps(payload))
    with pytest.raises(ValueError, match="not dimensionless"):
        read_manifest(path)
    with pytest.raises(ValueError, match="at least one"):
        write_manifest([], path)
