"""The paper's three machines, three designs: each its own linkage layout and hydraulics (not one layout at three
sizes), each valid by :func:`scaletwin_envs.design_space.check_design`. Every value names its source; *estimate*
marks values without a public spec. Cylinder closed lengths and strokes of the mini and the WA475 are fitted to
their layouts so that the boom sweeps the ER12's raise angle and the bucket its tilt range
(:func:`scaletwin_envs.design_space.build_design`'s rule), so the same scripted cycle runs on all three.

Sources: [paper] Karanfil & Ravani, "Scaling Digital Twin Models" (shared/paper), Table 2 and section 2.6;
[physics] shared/reference/physics.md (public spec sheets and handbook ranges).
"""

from __future__ import annotations

from dataclasses import replace

from scaletwin_envs.specs.loader import CylinderSpec, LinkageGeometry, LoaderSpec, MassProperties

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

# The miniature's own layout (m), *estimate*: an RC copy keeps the look of its full-size original but not its
# pin proportions (pins sized for the material, cylinders for the parts on the market). Relative to the ER12
# layout × 1/7, in boom lengths L: bell-crank pivot 0.02 L forward, its lower arm 0.02 L shorter, link B's bucket
# pin 0.02 L back, tilt cylinder's frame pin 0.03 L lower, lift cylinder's boom pin 0.02 L higher and frame pin
# 0.03 L forward. Assembles over the dig workspace, tilt force ratio 0.85–1.07 over both strokes (ER12 1.02–1.33),
# breakout / weight 0.95; at rest with its rated load F21 / weight is 3–4 % below the ER12 layout × 1/7
# (scaletwin_envs.design_space.check_design; tests/envs/test_presets.py).
MINI_GEOMETRY = LinkageGeometry(
    boom_pivot=(0.0, 0.2143), pin_O=(0.2786, 0.0429), bell_crank_pivot=(0.1708, 0.1571),
    bell_crank_top=(0.1357, 0.2314), bell_crank_bottom=(0.1929, 0.0820), pin_21=(0.2620, 0.0886),
    lift_frame_pin=(-0.0259, 0.0786), lift_boom_pin=(0.1571, 0.1037), tilt_frame_pin=(-0.0214, 0.2273),
    bucket_heel=(0.2886, 0.0), bucket_edge=(0.3886, 0.0), bucket_back_top=(0.2843, 0.0943), bucket_width=0.2143,
)

MINI = LoaderSpec(
    name="mini", scale=_MINI_LENGTH, geometry=MINI_GEOMETRY,
    masses=MassProperties(bucket=0.23 + 0.09, link_b=0.01, bell_crank=0.04, boom=0.32,
                          chassis=11.0 - (0.32 + 0.01 + 0.04 + 0.32 + 0.02 + 0.01 + 0.02 + 0.02)),
    lift=CylinderSpec(bore=0.010, rod_diameter=0.005, closed_length=0.1739, stroke=0.1293,
                      relief_pressure=2.5e6, pump_flow=6.7e-6, barrel_mass=0.02, rod_mass=0.01, count=2),
    tilt=CylinderSpec(bore=0.012, rod_diameter=0.006, closed_length=0.1347, stroke=0.0566,
                      relief_pressure=2.5e6, pump_flow=4.8e-6, barrel_mass=0.02, rod_mass=0.02),
    travel_speed=0.4, traction_coefficient=0.6, rated_load=4.0,
    provenance={
        "operating_mass": "11 kg [paper, section 2.6]",
        "masses": "bucket 0.23 + base 0.09, link B 0.01, link A 0.04, main arm 0.32 kg [paper, Table 2]",
        "cylinder_masses": "rods A1 0.02 / A2 0.01, B1 0.02 / B2 0.02 kg [paper, Table 2]",
        "rated_load": "4 kg maximum test load [paper, section 4]",
        "relief_pressure": "2.5 MPa *estimate* [physics: 1.5-3 MPa hobby hydraulics]",
        "geometry": "its own layout *estimate* (see MINI_GEOMETRY)",
        "cylinders_lengths": "closed lengths and strokes fitted to MINI_GEOMETRY (see MINI_GEOMETRY)",
        "cylinders": "10/12 mm bores, RC pump ~0.4 L/min *estimate*",
        "travel_speed": "0.4 m/s *estimate*",
    },
)

_WA_LENGTH = 2.0  # *estimate*: WA475 boom about twice the ER12's (operating mass 26 t / 3.3 t = 2.0³)

# The WA475's own layout (m), *estimate*: the large-loader pattern of lift cylinders anchored low on the front
# frame and far out on the boom (more lift force per bore) and a longer upper bell-crank arm (more breakout per
# tilt bore). Relative to the ER12 layout × 2, in boom lengths L: lift frame pin 0.03 L lower, lift boom pin 0.03 L
# forward, bell-crank top 0.03 L higher, tilt frame pin 0.02 L higher, link B's bucket pin 0.015 L back. Bucket:
# the 4.7 m³ test bucket [physics]. Assembles over the dig workspace, tilt force ratio 1.19–1.65 over both strokes
# (ER12 1.02–1.33), breakout / weight 0.75 (physics.md: 0.7–1.0 for 3–20 t, lower above); at rest with its rated
# load F21 / weight is within −3 to +3 % of the ER12 layout × 2 (link B's line of action barely turns), while the
# cylinder forces that hold that load differ (tests/envs/test_presets.py).
WA475_GEOMETRY = LinkageGeometry(
    boom_pivot=(0.0, 3.0), pin_O=(3.9, 0.6), bell_crank_pivot=(2.3, 2.2), bell_crank_top=(1.9, 3.377),
    bell_crank_bottom=(2.7, 1.24), pin_21=(3.691, 1.24), lift_frame_pin=(-0.5, 0.963), lift_boom_pin=(2.337, 1.36),
    tilt_frame_pin=(-0.3, 3.412), bucket_heel=(4.045, 0.0), bucket_edge=(5.496, 0.0), bucket_back_top=(3.983, 1.368),
    bucket_width=3.109,
)
_WA_MASS = 26000.0 / 3300.0  # component masses = ER12's × operating-mass ratio *estimate*
_WA_RAISE_TIME = 6.0  # s *estimate*, inside the 5–7 s band of physics.md (cycle times nearly constant in seconds)
# stroke fitted to WA475_GEOMETRY (ER12 raise angle); pump flow set below for the raise time
_WA_LIFT = CylinderSpec(bore=0.14, rod_diameter=0.08, closed_length=2.704, stroke=1.892, relief_pressure=32e6,
                        pump_flow=1.0, barrel_mass=ER12.lift.barrel_mass * _WA_MASS,
                        rod_mass=ER12.lift.rod_mass * _WA_MASS, count=2)

WA475 = LoaderSpec(
    name="wa475", scale=_WA_LENGTH, geometry=WA475_GEOMETRY, masses=ER12.masses.scaled(_WA_MASS),
    lift=replace(_WA_LIFT, pump_flow=_WA_LIFT.bore_area * _WA_LIFT.stroke / _WA_RAISE_TIME),
    tilt=CylinderSpec(bore=0.14, rod_diameter=0.08, closed_length=1.760, stroke=1.020, relief_pressure=32e6,
                      pump_flow=6.0e-3, barrel_mass=ER12.tilt.barrel_mass * _WA_MASS,
                      rod_mass=ER12.tilt.rod_mass * _WA_MASS),
    travel_speed=2.0, traction_coefficient=0.6, rated_load=8500.0,
    provenance={
        "operating_mass": "~26 000 kg [paper, section 2.6]; component masses = ER12 x 26000/3300 *estimate*",
        "bucket": "4.7 m3 test bucket [physics: WA475-10 field test]",
        "rated_load": "8.5 t *estimate* [physics: 8-9 t, <= 50 % of tipping load]",
        "relief_pressure": "32 MPa *estimate* [physics: 30-35 MPa]",
        "geometry": "its own layout *estimate* (see WA475_GEOMETRY)",
        "cylinders": "2x140 / 140 mm bores *estimate*; lift flow set for a 6.0 s full raise (5-7 s band [physics]), "
                     "tilt ~360 L/min *estimate*; closed lengths and strokes fitted to WA475_GEOMETRY",
        "travel_speed": "2.0 m/s *estimate*",
    },
)

PRESETS: dict[str, LoaderSpec] = {"mini": MINI, "er12": ER12, "wa475": WA475}
