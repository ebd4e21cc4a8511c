"""Names and SI units of the loader's signals: pure data, importable without MuJoCo (recordings, serving).

The signals themselves are read from a simulation by :class:`scaletwin_envs.signals.SignalReader`.
"""

from __future__ import annotations

#: The paper's Eq. (10) and Eq. (23) variables.
EQ10 = ("F21", "F31", "Pf_tilt", "Pf_lift", "x_b", "y_b", "m_b", "a1", "alpha1")
EQ23 = ("F21", "F31", "Pf_tilt", "Pf_lift", "x_b", "y_b", "m_b", "V1", "w1")

#: Unit of every signal key (SI), used by recordings and importers.
SIGNAL_UNITS: dict[str, str] = {
    "F21": "N", "F31": "N", "Pf_tilt": "N", "Pf_lift": "N", "x_b": "m", "y_b": "m", "m_b": "kg",
    "a1": "m/s^2", "alpha1": "rad/s^2", "V1": "m/s", "w1": "rad/s",
    "F21_x": "N", "F21_z": "N", "F31_x": "N", "F31_z": "N", "R_x": "N", "R_z": "N",
    "p_lift": "Pa", "p_tilt": "Pa", "lift_extension": "m", "tilt_extension": "m",
    "lift_speed": "m/s", "tilt_speed": "m/s", "travel_speed": "m/s", "boom_angle": "rad", "bucket_pitch": "rad",
    "m_load": "kg", "F21_route2": "N", "F31_route2": "N", "Pf_lift_route2": "N", "Pf_tilt_route2": "N",
    "residual_F21": "1", "residual_F31": "1", "residual_Pf_lift": "1", "residual_Pf_tilt": "1",
}

#: Design signals: dimensionless per-row quantities that follow from the machine's drawing and its measured pose
#: and cylinder force (computed by ``scaling.data.product_line.add_design_signals``), with ``F21_linkage`` (N), the pin
#: force of the massless linkage. ``tilt_load`` is the pressure in the tilt cylinder's loaded chamber over its relief
#: pressure (piston side when pushing, rod side when pulling): how hard the bucket is loaded, which the product-line
#: error score reads. Not recorded by the simulator; served models of a product line take them.
DESIGN_SIGNAL_UNITS: dict[str, str] = {"tilt_ratio": "1", "tilt_stroke": "1", "lift_stroke": "1", "fill": "1",
                                       "F21_linkage": "N", "tilt_load": "1"}
#: Every quantity a served model may take: the recorded signals and the design signals.
QUANTITY_UNITS: dict[str, str] = {**SIGNAL_UNITS, **DESIGN_SIGNAL_UNITS}
