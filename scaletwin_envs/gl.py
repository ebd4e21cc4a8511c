"""Which off-screen OpenGL back end MuJoCo can use on this machine (imported before MuJoCo is)."""

from __future__ import annotations

import ctypes.util
from collections.abc import Callable


def offscreen_gl(find: Callable[[str], str | None] = ctypes.util.find_library) -> str | None:
    """The off-screen OpenGL back end for ``MUJOCO_GL`` whose library this machine has: ``"egl"`` (libEGL), else
    ``"osmesa"`` (libOSMesa), else None. MuJoCo 4 loads the named back end when it is imported, so naming one
    whose library is missing (a bare container) would make ``import mujoco`` fail."""
    for backend, library in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if find(library):
            return backend
    return None
