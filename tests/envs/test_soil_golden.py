"""Golden values for the soil model, from calculations written here independently of the package.

The package (:mod:`scaletwin_envs.physics.earthmoving`, :mod:`scaletwin_envs.physics.dig`) evaluates the closed-form
N-factors of the fundamental earthmoving equation (Reece 1964; McKyes, *Soil Cutting and Tillage*, 1985, ch. 4;
``shared/reference/physics.md``) on a tabulated grid of rake and failure angles. The reference below does not use
those formulas: it writes the force balance of McKyes' trial wedge as vectors (weight, cohesion on the failure plane,
adhesion on the blade, the failure plane's reaction at φ from its normal and the blade's at δ from its normal), solves
the 2×2 system for the blade force and minimises it by brute force over the failure angle β at the actual depth.

The reference is itself pinned to published handbook numbers where the trial wedge has a closed form:

* a vertical wall (rake 90°) in cohesionless soil is Coulomb's passive wedge, P = ½ γ d² K_p w with K_p from the
  Coulomb table (Das, *Principles of Geotechnical Engineering*, Coulomb passive earth-pressure coefficient for a
  vertical wall and horizontal backfill): φ = 30°: K_p = 3.000 (δ = 0, Rankine), 4.977 (δ = 15°), 6.105 (δ = 20°);
* a smooth vertical wall in c–φ soil is Rankine's passive state with cohesion, P = (½ γ d² K_p + 2 c d √K_p) w;
* the edge bearing factors are Prandtl–Reissner's, as tabulated (Das, *Principles of Foundation Engineering*,
  bearing capacity factors): N_c, N_q = 5.14, 1.00 (φ = 0), 8.35, 2.47 (10°), 30.14, 18.40 (30°), 46.12, 33.30 (35°),
  61.35, 48.93 (38°).

Every comparison with the package is to 0.3 % or better, so a 2 % change in the cutting, edge or side force fails.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scaletwin_envs.physics.bucket import heaped_capacity
from scaletwin_envs.physics.dig import DigModel
from scaletwin_envs.physics.earthmoving import bearing_pressure, blade_force, n_factors, side_drag
from scaletwin_envs.physics.pile import Pile
from scaletwin_envs.specs import make_loader, make_soil
from scaletwin_envs.specs.soil import SoilSpec

REL = 3e-3  # package vs. reference; the package's tabulation error is < 0.02 %
_BETAS = np.linspace(1e-4, math.pi / 2 - 1e-4, 200_001)


# -- the independent reference --------------------------------------------------------------------------------------
def wedge_force(gamma: float, c: float, c_a: float, q: float, phi: float, delta: float, rake: float, depth: float,
                beta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Blade force P (N per m of width, at δ from the blade normal) and failure-plane normal force N, per β.

    x along travel, z up; blade tip at (0, -d). The blade rises backwards from the tip along (-cos ρ, sin ρ), the
    failure plane forwards along (cos β, sin β); the wedge between them slides up both.
    """
    d = depth
    cb, sb = np.cos(beta), np.sin(beta)
    cr, sr = math.cos(rake), math.sin(rake)
    top = d * (cb / sb + cr / sr)  # length of the wedge's free surface
    weight = 0.5 * gamma * d * top + q * top  # soil weight and surcharge, downwards
    cohesion = c * d / sb  # on the failure plane, opposing the wedge's slide along (cos β, sin β)
    adhesion = c_a * d / sr  # on the blade face, opposing the slide up the blade, i.e. along (cos ρ, -sin ρ)
    known_x = -cohesion * cb + adhesion * cr
    known_z = -weight - cohesion * sb - adhesion * sr
    # unknowns: N on the failure plane, along (-sin β, cos β) + tan φ (-cos β, -sin β);
    #           Pn on the blade, along (sin ρ, cos ρ) + tan δ (cos ρ, -sin ρ)
    tp, td = math.tan(phi), math.tan(delta)
    a11, a21 = -sb - tp * cb, cb - tp * sb
    a12, a22 = sr + td * cr, cr - td * sr
    with np.errstate(divide="ignore", invalid="ignore"):
        det = a11 * a22 - a12 * a21
        normal = (-known_x * a22 + a12 * known_z) / det
        p_normal = (-a11 * known_z + a21 * known_x) / det
    return p_normal / math.cos(delta), normal


def reference_blade(soil: SoilSpec, width: float, depth: float, rake: float) -> tuple[float, float, float]:
    """(resistance along travel, press into the soil, critical β) from the trial wedge minimised over β."""
    p, normal = wedge_force(soil.unit_weight, soil.cohesion, soil.adhesion, 0.0, soil.friction_angle,
                            soil.wall_friction_angle, rake, depth, _BETAS)
    p = np.where(np.isfinite(p) & (p > 0) & (normal > 0), p, np.inf)  # wedges that exist and are loaded
    k = int(np.argmin(p))
    total = width * float(p[k])
    return total * math.sin(rake + soil.wall_friction_angle), total * math.cos(rake + soil.wall_friction_angle), \
        float(_BETAS[k])


def reference_bearing_factors(phi: float) -> tuple[float, float]:
    """Prandtl (N_c) and Reissner (N_q) bearing capacity factors."""
    n_q = math.exp(math.pi * math.tan(phi)) * math.tan(math.radians(45.0) + phi / 2) ** 2
    return ((n_q - 1) / math.tan(phi) if phi > 0 else math.pi + 2), n_q


def _soil(phi_deg: float, delta_deg: float, gamma: float = 17e3, c: float = 0.0, c_a: float = 0.0) -> SoilSpec:
    return SoilSpec("test", gamma, c, math.radians(phi_deg), math.radians(delta_deg), adhesion=c_a)


# -- the reference against the handbooks ----------------------------------------------------------------------------
@pytest.mark.parametrize(("delta_deg", "kp"), [(0.0, 3.000), (15.0, 4.977), (20.0, 6.105)])
def test_reference_reproduces_coulomb_passive_coefficients(delta_deg: float, kp: float) -> None:
    """Vertical wall, cohesionless soil: min over β of P / (γ d² w) = K_p / 2 (Coulomb; Das's table)."""
    p, _ = wedge_force(1.0, 0.0, 0.0, 0.0, math.radians(30), math.radians(delta_deg), math.pi / 2, 1.0, _BETAS)
    assert np.nanmin(np.where(p > 0, p, np.nan)) == pytest.approx(kp / 2, rel=2e-4)


def test_reference_reproduces_rankine_with_cohesion() -> None:
    soil = _soil(30.0, 0.0, c=10e3)
    along, press, beta = reference_blade(soil, 1.0, 0.5, math.pi / 2)
    kp = 3.0
    assert along == pytest.approx(0.5 * 17e3 * 0.5**2 * kp + 2 * 10e3 * 0.5 * math.sqrt(kp), rel=1e-6)
    assert press == pytest.approx(0.0, abs=1e-6 * along)  # smooth vertical wall: horizontal force
    assert beta == pytest.approx(math.radians(45 - 30 / 2), abs=1e-3)  # Rankine's failure plane


# -- the package against the handbooks and the reference ------------------------------------------------------------
@pytest.mark.parametrize(("delta_deg", "kp"), [(0.0, 3.000), (15.0, 4.977), (20.0, 6.105)])
def test_blade_force_reproduces_coulomb_passive_force(delta_deg: float, kp: float) -> None:
    """A vertical 1.5 m blade at 0.4 m in φ = 30° sand: |P| = ½ γ d² K_p w (Das's Coulomb table)."""
    soil, width, depth = _soil(30.0, delta_deg), 1.5, 0.4
    along, press = blade_force(soil, width, depth, math.pi / 2)
    assert math.hypot(along, press) == pytest.approx(0.5 * 17e3 * depth**2 * kp * width, rel=REL)
    # at δ from the wall's normal; the wedge rises along the wall, so its friction lifts the blade (press < 0)
    assert math.atan2(-press, along) == pytest.approx(math.radians(delta_deg), abs=1e-9)


# Stated case: the ER12's 1.5 m bucket at rake 45° and 0.3 m depth. Golden values from the reference (β in degrees).
GOLDEN = {  # soil: (N_γ, N_c, N_ca at the critical β, β, resistance along travel N, press N)
    "sandy_loam": (1.6640, 2.1427, 0.7483, 32.27, 13527.3, 5742.0),
    "gravel": (1.8571, 2.3157, 0.8016, 29.82, 4096.0, 1572.3),
}


@pytest.mark.parametrize("soil_name", sorted(GOLDEN))
def test_golden_n_factors_and_blade_force(soil_name: str) -> None:
    """Fundamental earthmoving equation, F = (γ d² N_γ + c d N_c + c_a d N_ca) w, at the stated case."""
    soil, width, depth, rake = make_soil(soil_name), 1.5, 0.3, math.radians(45.0)
    n_gamma, n_c, n_ca, beta_deg, along_golden, press_golden = GOLDEN[soil_name]
    along, press, beta = reference_blade(soil, width, depth, rake)
    assert math.degrees(beta) == pytest.approx(beta_deg, abs=0.01)
    # the N-factors at the critical β, each as the wedge's force per unit load (one load at a time)
    one = {"gamma": (1.0, 0.0, 0.0), "c": (0.0, 1.0, 0.0), "ca": (0.0, 0.0, 1.0)}
    n = {k: float(wedge_force(*loads, 0.0, soil.friction_angle, soil.wall_friction_angle, rake, 1.0,
                              np.array([beta]))[0][0]) for k, loads in one.items()}
    assert (n["gamma"], n["c"], n["ca"]) == pytest.approx((n_gamma, n_c, n_ca), abs=1e-4)
    total = width * (soil.unit_weight * depth**2 * n_gamma + soil.cohesion * depth * n_c
                     + soil.adhesion * depth * n_ca)
    assert math.hypot(along, press) == pytest.approx(total, rel=1e-4)
    assert (along, press) == pytest.approx((along_golden, press_golden), rel=1e-4)
    package = blade_force(soil, width, depth, rake)
    assert package == pytest.approx((along, press), rel=REL)
    # the package's closed-form N-factors at the same β
    ng, nc, nq, nca = n_factors(rake, soil.friction_angle, soil.wall_friction_angle, beta)
    assert (float(ng), float(nc), float(nca)) == pytest.approx((n_gamma, n_c, n_ca), abs=1e-4)
    assert float(nq) == pytest.approx(float(wedge_force(0.0, 0.0, 0.0, 1.0, soil.friction_angle,
                                                        soil.wall_friction_angle, rake, 1.0,
                                                        np.array([beta]))[0][0]), rel=1e-9)


@pytest.mark.parametrize("soil_name", ["gravel", "sand", "sandy_loam", "clay_loam"])
@pytest.mark.parametrize(("rake_deg", "depth"), [(20.0, 0.05), (43.3, 0.3), (61.7, 1.2), (90.0, 0.4)])
def test_blade_force_matches_the_trial_wedge(soil_name: str, rake_deg: float, depth: float) -> None:
    """Every shipped soil, rakes on and between the package's table rows, shallow to deep cuts."""
    soil, rake = make_soil(soil_name), math.radians(rake_deg)
    along, press, _ = reference_blade(soil, 1.5, depth, rake)
    assert blade_force(soil, 1.5, depth, rake) == pytest.approx((along, press), rel=REL)


@pytest.mark.parametrize(("phi_deg", "n_c", "n_q"),
                         [(0.0, 5.14, 1.00), (10.0, 8.35, 2.47), (30.0, 30.14, 18.40), (35.0, 46.12, 33.30),
                          (38.0, 61.35, 48.93)])
def test_bearing_pressure_uses_the_tabulated_factors(phi_deg: float, n_c: float, n_q: float) -> None:
    """Edge bearing q_u = c N_c + γ d N_q with Das's tabulated Prandtl–Reissner factors."""
    assert reference_bearing_factors(math.radians(phi_deg)) == pytest.approx((n_c, n_q), abs=6e-3)
    soil = _soil(phi_deg, 0.6 * phi_deg, gamma=16e3, c=12e3)
    assert bearing_pressure(soil, 0.25) == pytest.approx(12e3 * n_c + 16e3 * 0.25 * n_q, rel=REL)
    assert bearing_pressure(soil, -0.1) == pytest.approx(12e3 * n_c, rel=REL)  # above the surface: no overburden


@pytest.mark.parametrize("soil_name", ["gravel", "sandy_loam", "clay_loam"])
def test_side_drag_is_at_rest_friction_and_adhesion_on_two_plates(soil_name: str) -> None:
    """Two plates buried d over length l: 2 (½ K0 γ d² l tan δ + c_a d l), K0 = 1 - sin φ (Jaky)."""
    soil, depth, length = make_soil(soil_name), 0.35, 0.6
    k0 = 1.0 - math.sin(soil.friction_angle)
    expected = 2 * (0.5 * k0 * soil.unit_weight * depth**2 * length * math.tan(soil.wall_friction_angle)
                    + soil.adhesion * depth * length)
    assert side_drag(soil, depth, length) == pytest.approx(expected, rel=REL)
    assert side_drag(soil, 0.0, length) == 0.0 and side_drag(soil, depth, 0.0) == 0.0


# -- the bucket: cutting, edge and side terms together --------------------------------------------------------------
@pytest.mark.parametrize("soil_name", ["gravel", "sand", "sandy_loam", "clay_loam"])
@pytest.mark.parametrize("depth", [0.2, 0.4])
def test_dig_resistance_components(soil_name: str, depth: float) -> None:
    """ER12 bucket (1.5 m wide) moving forward at 0.5 m/s with its edge ``depth`` into a flat-topped pile.

    The blade rises from the edge to (-0.7, 0.66) m: rake atan(0.66/0.7) = 43.3°. The edge is 0.012 L thick (a
    28 mm edge on the ER12); the side plates are buried ``depth`` over the shorter of the floor (0.7 m) and the
    pile's slope run-out ``depth / tan(repose)``.
    """
    spec = make_loader("er12")
    soil, width, length = make_soil(soil_name), 1.5, spec.characteristic_length
    pile = Pile(toe_x=-5.0, height=depth, repose=math.radians(35), length=10.0, width=width)
    dig = DigModel(soil, pile, width, heaped_capacity(spec.geometry), length)
    f = dig.resistance((0.0, 0.0), (-0.7, 0.66), (-0.7, 0.0), (0.5, 0.0))
    along, press, _ = reference_blade(soil, width, depth, math.atan2(0.66, 0.7))
    n_c, n_q = reference_bearing_factors(soil.friction_angle)
    bearing = width * 0.012 * length * (soil.cohesion * n_c + soil.unit_weight * depth * n_q)
    buried = min(0.7, depth / math.tan(soil.repose_angle))
    k0 = 1.0 - math.sin(soil.friction_angle)
    side = 2 * (0.5 * k0 * soil.unit_weight * depth**2 * buried * math.tan(soil.wall_friction_angle)
                + soil.adhesion * depth * buried)
    assert f.depth == pytest.approx(depth, rel=1e-9) and f.travel == (1.0, 0.0)
    assert f.cutting == pytest.approx(along, rel=REL)
    assert f.press == pytest.approx(press, rel=REL)
    assert f.bearing == pytest.approx(bearing, rel=REL)
    assert f.side == pytest.approx(side, rel=REL)
    assert f.resist == pytest.approx(along + bearing + side, rel=REL)
