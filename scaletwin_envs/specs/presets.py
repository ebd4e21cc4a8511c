"""The paper's three machines. Every value names its source; *estimate* marks values without a public spec.

Sources: [paper] Karanfil & Ravani, "Scaling Digital Twin Models" (shared/paper), Table 2 and section 2.6;
[physics] shared/reference/physics.md (public spec sheets and handbook ranges).
"""

from __future__ import annotations

from scaletwin_envs.specs.loader import CylinderSpec, LinkageGeometry, LoaderSpec, MassProperties, scale_spec

# ER12 linkage in the reference pose (m). *estimate*: laid out for a 3.3 t Z-bar loader (2.3 m boom, ~2.9 m
# hinge-pin height at full lift, 0.53 m³ heaped bucket of 1.5 m width) and checked for assembly over the
# dig-cycle workspace by tests/envs/test_kinematics.py.
ER12_GEOMETRY = LinkageGeometry(
    boom_pivot=(0.0, 1.50), pin_O=(1.95, 0.30), bell_crank_pivot=(1.15, 1.10), bell_crank_top=(0.95, 1.62),
    bell_crank_bottom=(1.35, 0.62), pin_21=(1.88, 0.62), lift_frame_pin=(-0.25, 0.55), lift_boom_pin=(1.10, 0.68),
    tilt_frame_pin=(-0.15, 1.66), bucket_heel=(2.02, 0.0), bucket_edge=(2.72, 0.0), bucket_back_top=(1.99, 0.66),
    bucket_width=1.5,
)

_ER12_PROVENANCE = {
    "operating_mass": "3300 kg [paper, section 2.6]",
    "masses": "bucket 205.8 + base 84.8, link B 8.99, link A 33.9, main arm 294.6 kg [paper, Table 2]",
    "cylinder_masses": "rods A1 20.3 / A2 13.1 taken as lift barrel / rod, B1 19.6 / B2 14.7 as tilt [paper, Table 2; "
                       "the barrel/rod reading is an estimate]",
    "chassis": "operating mass minus linkage [derived]",
    "rated_load": "1200 kg = 4/11 x 3300 [physics, follows from the paper]",
    "relief_pressure": "17 MPa *estimate* [physics: 16-18 MPa]",
    "geometry": "*estimate* (see ER12_GEOMETRY)",
    "cylinders": "bores, strokes, pump flow *estimate* (52 L/min class; ~6 s full raise)",
    "travel_speed": "1.5 m/s digging gear *estimate*",
    "traction_coefficient": "0.6 rimpull/weight *estimate*",
}

ER12 = LoaderSpec(
    name="er12", scale=1.0, geometry=ER12_GEOMETRY,
    masses=MassProperties(bucket=205.8 + 84.8, link_b=8.99, bell_crank=33.9, boom=294.6,
                          chassis=3300.0 - (290.6 + 8.99 + 33.9 + 294.6 + 20.3 + 13.1 + 19.6 + 14.7)),
    lift=CylinderSpec(bore=0.063, rod_diameter=0.035, closed_length=1.28, stroke=0.90, relief_pressure=17e6,
                      pump_flow=8.7e-4, barrel_mass=20.3, rod_mass=13.1, count=2),
    tilt=CylinderSpec(bore=0.075, rod_diameter=0.040, closed_length=0.92, stroke=0.45, relief_pressure=17e6,
                      pump_flow=8.8e-4, barrel_mass=19.6, rod_mass=14.7),
    travel_speed=1.5, traction_coefficient=0.6, rated_load=1200.0, provenance=_ER12_PROVENANCE,
)

_MINI_LENGTH = 1.0 / 7.0  # Kabolite ~1:14 copy of a ~2x-ER12 Z-bar loader [physics]; linkage proportions *estimate*

MINI = LoaderSpec(
    name="mini", scale=_MINI_LENGTH, geometry=ER12_GEOMETRY.scaled(_MINI_LENGTH),
    masses=MassProperties(bucket=0.23 + 0.09, link_b=0.01, bell_crank=0.04, boom=0.32,
                          chassis=11.0 - (0.32 + 0.01 + 0.04 + 0.32 + 0.02 + 0.01 + 0.02 + 0.02)),
    lift=CylinderSpec(bore=0.010, rod_diameter=0.005, closed_length=1.28 * _MINI_LENGTH, stroke=0.90 * _MINI_LENGTH,
                      relief_pressure=2.5e6, pump_flow=6.7e-6, barrel_mass=0.02, rod_mass=0.01, count=2),
    tilt=CylinderSpec(bore=0.012, rod_diameter=0.006, closed_length=0.92 * _MINI_LENGTH, stroke=0.45 * _MINI_LENGTH,
                      relief_pressure=2.5e6, pump_flow=4.8e-6, barrel_mass=0.02, rod_mass=0.02),
    travel_speed=0.4, traction_coefficient=0.6, rated_load=4.0,
    provenance={
        "operating_mass": "11 kg [paper, section 2.6]",
        "masses": "bucket 0.23 + base 0.09, link B 0.01, link A 0.04, main arm 0.32 kg [paper, Table 2]",
        "cylinder_masses": "rods A1 0.02 / A2 0.01, B1 0.02 / B2 0.02 kg [paper, Table 2]",
        "rated_load": "4 kg maximum test load [paper, section 4]",
        "relief_pressure": "2.5 MPa *estimate* [physics: 1.5-3 MPa hobby hydraulics]",
        "geometry": "ER12 layout x 1/7 *estimate*",
        "cylinders": "10/12 mm bores, RC pump ~0.4 L/min *estimate*",
        "travel_speed": "0.4 m/s *estimate*",
    },
)

_WA_LENGTH = 2.0  # *estimate*: WA475 boom about twice the ER12's
_WA_BUCKET = (4.7 / (0.528 * _WA_LENGTH**3)) ** (1 / 3)  # 4.7 m3 test bucket [physics]
_wa_factors = {"length": _WA_LENGTH, "mass": 26000.0 / 3300.0, "pressure": 32.0 / 17.0, "bore": 1.0,
               "cylinder_speed": 1.0, "travel_speed": 2.0 / 1.5, "bucket_size": _WA_BUCKET, "traction": 1.0}
_wa = scale_spec(ER12, _wa_factors, "wa475", _WA_LENGTH)

WA475 = LoaderSpec(
    name="wa475", scale=_WA_LENGTH, geometry=_wa.geometry, masses=_wa.masses,
    lift=CylinderSpec(bore=0.14, rod_diameter=0.08, closed_length=1.28 * _WA_LENGTH, stroke=0.90 * _WA_LENGTH,
                      relief_pressure=32e6, pump_flow=6.0e-3, barrel_mass=_wa.lift.barrel_mass,
                      rod_mass=_wa.lift.rod_mass, count=2),
    tilt=CylinderSpec(bore=0.14, rod_diameter=0.08, closed_length=0.92 * _WA_LENGTH, stroke=0.45 * _WA_LENGTH,
                      relief_pressure=32e6, pump_flow=6.0e-3, barrel_mass=_wa.tilt.barrel_mass,
                      rod_mass=_wa.tilt.rod_mass),
    travel_speed=2.0, traction_coefficient=0.6, rated_load=8500.0,
    provenance={
        "operating_mass": "~26 000 kg [paper, section 2.6]; component masses = ER12 x 26000/3300 *estimate*",
        "bucket": "4.7 m3 test bucket [physics: WA475-10 field test]",
        "rated_load": "8.5 t *estimate* [physics: 8-9 t, <= 50 % of tipping load]",
        "relief_pressure": "32 MPa *estimate* [physics: 30-35 MPa]",
        "geometry": "ER12 layout x 2.0 *estimate*",
        "cylinders": "2x140 / 140 mm bores, ~360 L/min *estimate*",
        "travel_speed": "2.0 m/s *estimate*",
    },
)

PRESETS: dict[str, LoaderSpec] = {"mini": MINI, "er12": ER12, "wa475": WA475}
