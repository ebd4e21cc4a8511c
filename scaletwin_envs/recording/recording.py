"""The typed recording of one episode: a per-step table, the unit of every column, and provenance.

Stored as Parquet: the table as columns, and ``{"schema_version", "units", "provenance"}`` as one JSON document
in the file's key-value metadata (key :data:`~scaletwin_envs.recording.schema.METADATA_KEY`). Files are written
atomically (temporary file + rename).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from scaletwin_envs.recording.atomic import atomic_path
from scaletwin_envs.recording.schema import COMMAND_COLUMNS, METADATA_KEY, SCHEMA_VERSION
from scaletwin_envs.specs.loader import LoaderSpec
from scaletwin_envs.specs.soil import SoilSpec


@dataclass(frozen=True)
class Provenance:
    """Where a recording comes from: enough to rebuild the twin and replay it.

    Attributes:
        machine: the machine spec (:meth:`LoaderSpec.to_dict`), or None for an external recording without one.
        soil: the soil (:meth:`SoilSpec.to_dict`), or None.
        seed: the reset seed (the initial pose and pile perturbation follow from it).
        timestep: physics time step, s.  frame_skip: physics steps per control step.  control_dt: s.
        env_id: Gymnasium id of the env.  env_kwargs: the remaining constructor arguments (JSON values).
        policy: what produced the commands.  package_version: ``scaletwin_envs.__version__``.
        mujoco_version: MuJoCo used.  model_sha256: hash of the compiled MuJoCo model after reset; a model
            altered by hand hashes differently from the twin rebuilt from ``machine``.
        source: ``"simulation"``, ``"replay"`` or ``"import"``.  extra: anything else (JSON values).
    """

    machine: dict[str, Any] | None = None
    soil: dict[str, Any] | None = None
    seed: int | None = None
    timestep: float | None = None
    frame_skip: int | None = None
    control_dt: float | None = None
    env_id: str | None = None
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    policy: str = "unknown"
    package_version: str = ""
    mujoco_version: str = ""
    model_sha256: str | None = None
    source: str = "simulation"
    extra: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # canonical JSON form (tuples -> lists, ...), so that a provenance equals itself read back from a file
        for name in ("machine", "soil", "env_kwargs", "extra"):
            object.__setattr__(self, name, _json_form(getattr(self, name)))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Provenance:
        """Inverse of :meth:`to_dict`; unknown keys are an error (they mean a newer writer)."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown provenance keys {unknown}; known: {sorted(names)}")
        return cls(**dict(d))

    def machine_spec(self) -> LoaderSpec | None:
        """The machine as a :class:`LoaderSpec` (None when not recorded)."""
        return None if self.machine is None else LoaderSpec.from_dict(self.machine)

    def soil_spec(self) -> SoilSpec | None:
        """The soil as a :class:`SoilSpec` (None when not recorded)."""
        return None if self.soil is None else SoilSpec(**self.soil)


@dataclass
class Recording:
    """One episode: ``data`` (one row per control step, SI), ``units`` (column → unit) and ``provenance``.

    Raises:
        ValueError: a column without a unit, a unit without a column, or no ``time``/command columns.
    """

    data: pd.DataFrame
    units: dict[str, str]
    provenance: Provenance
    schema_version: int = SCHEMA_VERSION

    def __post_init__(self) -> None:
        cols = [str(c) for c in self.data.columns]
        no_unit = [c for c in cols if c not in self.units]
        no_col = [c for c in self.units if c not in cols]
        if no_unit or no_col:
            raise ValueError(f"recording columns and units disagree: columns without a unit {no_unit}, "
                             f"units without a column {no_col}")
        missing = [c for c in ("time", *COMMAND_COLUMNS) if c not in cols]
        if missing:
            raise ValueError(f"a recording needs the columns {missing} (time in s, commands in [-1, 1])")
        self.units = {c: self.units[c] for c in cols}

    def __len__(self) -> int:
        return len(self.data)

    @property
    def commands(self) -> np.ndarray:
        """The ``[lift, tilt, drive]`` commands, shape (steps, 3)."""
        return self.data[list(COMMAND_COLUMNS)].to_numpy(dtype=np.float64)

    def signal(self, name: str) -> np.ndarray:
        """One column as floats, in its SI unit (``self.units[name]``)."""
        if name not in self.data.columns:
            raise KeyError(f"recording has no column {name!r}; columns: {list(self.data.columns)}")
        return self.data[name].to_numpy(dtype=np.float64)

    def metadata(self) -> dict[str, Any]:
        """The JSON document stored beside the table."""
        return {"schema_version": self.schema_version, "units": dict(self.units),
                "provenance": self.provenance.to_dict()}

    def to_arrow(self) -> pa.Table:
        """The table (NaN stays NaN, not null) with the metadata document attached."""
        columns = [_arrow_column(self.data[c]) for c in self.data.columns]
        table = pa.Table.from_arrays(columns, names=[str(c) for c in self.data.columns])
        meta = {METADATA_KEY: json.dumps(self.metadata(), sort_keys=True, allow_nan=True).encode()}
        return table.replace_schema_metadata(meta)

    def to_parquet(self, path: str | Path) -> Path:
        """Write the recording to ``path`` atomically (zstd-compressed Parquet); returns the path."""
        with atomic_path(path) as tmp:
            pq.write_table(self.to_arrow(), tmp, compression="zstd")
        return Path(path)

    def equals(self, other: Recording) -> bool:
        """Same table (NaN equal to NaN), units, provenance and schema version."""
        return (self.schema_version == other.schema_version and self.units == other.units
                and self.provenance == other.provenance and self.data.equals(other.data))


def _arrow_column(series: pd.Series) -> pa.Array:
    """Numeric and bool columns through NumPy (fast, NaN kept as NaN); text and others through pandas."""
    if pd.api.types.is_numeric_dtype(series.dtype) or pd.api.types.is_bool_dtype(series.dtype):
        return pa.array(series.to_numpy())
    return pa.array(series, from_pandas=True)


def _json_form(value: Any) -> Any:
    """``value`` as it reads back from JSON (raises TypeError for values JSON cannot hold)."""
    return None if value is None else json.loads(json.dumps(value))


def recording_from_arrow(table: pa.Table, where: str = "table") -> Recording:
    """Rebuild a :class:`Recording` from an Arrow table written by :meth:`Recording.to_arrow`."""
    raw = (table.schema.metadata or {}).get(METADATA_KEY)
    if raw is None:
        raise ValueError(f"{where} is not a scaletwin recording (no {METADATA_KEY.decode()!r} metadata); "
                         "use scaletwin_envs.recording.import_recording for external data")
    meta = json.loads(raw)
    version = int(meta.get("schema_version", -1))
    if version > SCHEMA_VERSION or version < 1:
        raise ValueError(f"{where} has recording schema version {version}; this scaletwin reads versions "
                         f"1..{SCHEMA_VERSION}")
    return Recording(table.to_pandas(), dict(meta["units"]), Provenance.from_dict(meta["provenance"]), version)


def read_recording(path: str | Path) -> Recording:
    """Read a recording written by :meth:`Recording.to_parquet`.

    Raises:
        FileNotFoundError: no such file.
        ValueError: the file is not a scaletwin recording, or its schema version is newer than this code.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no recording at {path}")
    return recording_from_arrow(pq.read_table(path), str(path))

