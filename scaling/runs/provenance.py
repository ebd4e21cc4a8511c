"""Provenance stamped on every artefact of :mod:`scaling`: code version, parameters, seed, data hash, machine.

:func:`provenance` returns a JSON-serialisable dict; :func:`write_json` writes any payload atomically.
"""

from __future__ import annotations

import datetime as _dt
import json
import platform
import subprocess
import sys
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from scaletwin_envs.recording.atomic import atomic_path

PACKAGE_ROOT = Path(__file__).resolve().parent.parent


@lru_cache(maxsize=1)
def code_version() -> str:
    """``git describe --always --dirty`` of the source tree, or ``"unknown"`` outside a git checkout."""
    try:
        out = subprocess.run(["git", "-C", str(PACKAGE_ROOT), "describe", "--always", "--dirty", "--abbrev=12"],
                             capture_output=True, text=True, timeout=10, check=True)
        return out.stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def versions() -> dict[str, str]:
    """Versions of the packages that shape the numbers."""
    import pandas
    import torch

    import scaletwin_envs

    out = {"python": platform.python_version(), "numpy": np.__version__, "pandas": pandas.__version__,
           "torch": torch.__version__, "scaletwin_envs": scaletwin_envs.__version__}
    try:
        import mujoco

        out["mujoco"] = mujoco.__version__
    except ImportError:  # pragma: no cover - a dependency
        pass
    return out


def machine() -> dict[str, Any]:
    """Where it ran (:func:`scaletwin_envs.host.host`: the CPU model matters for bit-for-bit reproduction)."""
    from scaletwin_envs.host import host

    return host()


def provenance(kind: str, params: Mapping[str, Any] | None = None, seed: int | None = None,
               data_hashes: Mapping[str, str] | None = None, **extra: Any) -> dict[str, Any]:
    """The provenance record of an artefact of ``kind`` (``"model"``, ``"run"``, ``"validation"``, ...)."""
    return {"kind": kind, "code_version": code_version(), "created": _dt.datetime.now(_dt.UTC).isoformat(),
            "command": " ".join(sys.argv), "params": dict(params or {}), "seed": seed,
            "data_hashes": dict(data_hashes or {}), "versions": versions(), "machine": machine(), **extra}


def to_jsonable(value: Any) -> Any:
    """NumPy scalars and arrays, tuples and paths as plain JSON values (recursively)."""
    if isinstance(value, Mapping):
        return {str(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_jsonable(value.tolist())
    if isinstance(value, np.generic):
        return to_jsonable(value.item())
    if isinstance(value, float) and not np.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    return value


def write_json(path: str | Path, payload: Any) -> Path:
    """Write ``payload`` (made JSON-safe by :func:`to_jsonable`) atomically, pretty-printed; returns the path."""
    text = json.dumps(to_jsonable(payload), indent=2, sort_keys=True, allow_nan=False) + "\n"
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def read_json(path: str | Path) -> Any:
    return json.loads(Path(path).read_text())
