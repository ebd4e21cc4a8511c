"""Column names and SI units of a recording, and the schema version.

A recording has one row per control step (the reset state is not a row: it is reproduced from the seed).
Row ``k`` (``step`` = k, 1-based) holds the command applied over the control interval ending at ``time`` and
the state and signals read at ``time``. Columns, in order:

* ``step`` (1), ``time`` (s, end of the control interval);
* :data:`COMMAND_COLUMNS`: normalised ``[lift, tilt, drive]`` commands in [-1, 1];
* every signal of :data:`scaletwin_envs.signal_units.SIGNAL_UNITS` (Eq. (10)/(23), both routes, cylinder states,
  pressures, ``m_load`` = loaded mass); a signal the env does not report is NaN;
* joint states of the MuJoCo model: ``q_<joint>`` (rad or m) and ``qd_<joint>`` (rad/s or m/s);
* :data:`EPISODE_UNITS`: fill factor, spilled mass, hydraulic work (cumulative), reward and the dig ``phase``
  (:class:`~scaletwin_envs.envs.phases.DigPhase` name in lower case, ``"error"`` after a physics blow-up).

Units are pint-parsable strings; ``"1"`` marks a pure number and ``"-"`` a non-quantity (text, flags).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from scaletwin_envs.signal_units import EQ10, EQ23, SIGNAL_UNITS

#: Version of the column layout and metadata; bumped on any incompatible change.
SCHEMA_VERSION = 1
#: Key of the JSON document in the Parquet key-value metadata.
METADATA_KEY = b"scaletwin.recording"

NON_QUANTITY = "-"
INDEX_UNITS: dict[str, str] = {"step": "1", "time": "s"}
COMMAND_COLUMNS = ("cmd_lift", "cmd_tilt", "cmd_drive")
COMMAND_UNITS: dict[str, str] = dict.fromkeys(COMMAND_COLUMNS, "1")
EPISODE_NUMERIC = ("fill_factor", "spilled_mass", "hydraulic_work", "reward")
EPISODE_UNITS: dict[str, str] = {
    "fill_factor": "1", "spilled_mass": "kg", "hydraulic_work": "J", "reward": "1", "phase": NON_QUANTITY,
}
#: Columns of the loading-cycle task (``WheelLoaderLoadTruck-v1``), after :data:`EPISODE_UNITS`, in recordings of
#: envs whose reset ``info`` has these keys (recordings of other envs have none of them).
TRUCK_UNITS: dict[str, str] = {
    "truck_payload": "kg", "target_payload": "kg", "truck_com_x": "m", "truck_com_z": "m", "passes": "1",
    "leg": "1", "returned_mass": "kg", "drive_work": "J",
}
#: Columns that are not float64.
DTYPES: dict[str, str] = {"step": "int64", "phase": "str"}

#: Columns an imported (external) recording must provide: time, the commands, and the Eq. (10)/(23) signals.
REQUIRED_IMPORT: tuple[str, ...] = ("time", *COMMAND_COLUMNS, *dict.fromkeys((*EQ10, *EQ23)))

if TYPE_CHECKING:
    import mujoco


def joint_units(model: mujoco.MjModel) -> dict[str, str]:
    """``q_<joint>`` and ``qd_<joint>`` columns of every hinge and slide joint of ``model``, with units.

    Raises:
        ValueError: a joint is unnamed or of a type with more than one degree of freedom (free, ball).
    """
    import mujoco  # here, not at the top: reading and writing recordings must not load the simulator

    _JOINT_UNITS = {mujoco.mjtJoint.mjJNT_HINGE: ("rad", "rad/s"), mujoco.mjtJoint.mjJNT_SLIDE: ("m", "m/s")}
    out: dict[str, str] = {}
    for j in range(model.njnt):
        name, kind = model.joint(j).name, mujoco.mjtJoint(model.jnt_type[j])
        if not name or kind not in _JOINT_UNITS:
            raise ValueError(f"joint {j} ({name or 'unnamed'}, {kind.name}): recordings support named hinge and "
                             "slide joints only")
        out[f"q_{name}"], out[f"qd_{name}"] = _JOINT_UNITS[kind]
    return out


def column_units(joints: dict[str, str]) -> dict[str, str]:
    """All columns of a simulated recording, in order, with their SI units (``joints`` from :func:`joint_units`)."""
    return {**INDEX_UNITS, **COMMAND_UNITS, **SIGNAL_UNITS, **joints, **EPISODE_UNITS}


def known_units() -> dict[str, str]:
    """Every fixed column (all but the model-dependent joint columns) with its SI unit."""
    return column_units({})

