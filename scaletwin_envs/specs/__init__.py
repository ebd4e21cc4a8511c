"""Machine and soil specifications: what a loader and a pile are, independent of any simulator."""

from scaletwin_envs.specs.laws import FROUDE, PRODUCT_LINE, ScalingLaw
from scaletwin_envs.specs.loader import (
    CylinderSpec,
    LinkageGeometry,
    LoaderSpec,
    MassProperties,
)
from scaletwin_envs.specs.machines import make_loader, preset_names
from scaletwin_envs.specs.soil import SOILS, SoilSpec, make_soil

__all__ = [
    "FROUDE",
    "PRODUCT_LINE",
    "SOILS",
    "CylinderSpec",
    "LinkageGeometry",
    "LoaderSpec",
    "MassProperties",
    "ScalingLaw",
    "SoilSpec",
    "make_loader",
    "make_soil",
    "preset_names",
]
