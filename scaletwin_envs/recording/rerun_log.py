"""rerun logs of dig episodes: live (an ``on_step`` callback) or saved as ``.rrd`` with a default layout.

Entities (timelines ``step`` and ``sim_time``):

* ``/world/loader/<body>``: static geometry once, then one ``Transform3D`` per step
  (:mod:`~scaletwin_envs.recording.rerun_scene`); ``/world/pile``: the pile surface whenever it changes;
  ``/world/bucket_load``: the load as a sphere of its volume, labelled with its mass.
* ``/signals/<name>``: every signal (SI; the unit is in the series name), one sample per step;
  ``/signals/groups/<name>``: the dimensionless groups of :mod:`~scaletwin_envs.recording.groups`;
  ``/signals/route2_minus_route1/<name>``: for each force obtained by both routes, route 2 − route 1 (N), what a
  reviewer checks (the two routes agree to ~1e-8 of the weight, so their own lines lie on top of each other).
* ``/phases``: a ``TextLog`` annotation at every dig-phase change; ``/phase``: the same as ``StateChange``.

The blueprint (3D view, phase timeline and log, tabs of time-series views, one plot per unit within a tab so no
axis mixes units) is stored in every saved file.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from scaletwin_envs.recording.atomic import atomic_path
from scaletwin_envs.recording.groups import GROUPS, dimensionless_groups
from scaletwin_envs.recording.recorder import env_provenance
from scaletwin_envs.recording.recording import Provenance, Recording
from scaletwin_envs.recording.rerun_scene import SceneLogger, log_pile, send_load
from scaletwin_envs.recording.schema import SCHEMA_VERSION, TRUCK_UNITS
from scaletwin_envs.signal_units import SIGNAL_UNITS

APP_ID = "scaletwin"
SIGNALS_PATH, GROUPS_PATH, PHASE_PATH, PHASE_LOG_PATH = "/signals", "/signals/groups", "/phase", "/phases"
RESIDUALS_PATH = "/signals/route2_minus_route1"
#: Forces obtained by both routes: route 1 name → route 2 name (their difference is logged under RESIDUALS_PATH).
TWO_ROUTE_FORCES = {n: f"{n}_route2" for n in ("F21", "F31", "Pf_lift", "Pf_tilt")}
#: The pile is logged again when its surface moved by more than this fraction of its height.
PILE_TOLERANCE = 0.01
#: Time-series tabs of the default layout: title → signals.
SIGNAL_PANELS: dict[str, tuple[str, ...]] = {
    "Pin forces": ("F21", "F31", "F21_route2", "F31_route2"),
    "Cylinder forces": ("Pf_lift", "Pf_tilt", "Pf_lift_route2", "Pf_tilt_route2"),
    "Bucket and load": ("m_b", "m_load", "x_b", "y_b"),
    "Bucket motion": ("a1", "alpha1", "V1", "w1"),
    "Soil force": ("R_x", "R_z"),
    "Cylinders": ("lift_extension", "tilt_extension", "lift_speed", "tilt_speed", "p_lift", "p_tilt"),
}
#: The tab of a loading-cycle recording (``WheelLoaderLoadTruck-v1``): the truck's payload against its target, the
#: material returned to the pile, the payload's centre of mass and the passes.
TRUCK_PANEL: dict[str, tuple[str, ...]] = {
    "Truck": ("truck_payload", "target_payload", "returned_mass", "truck_com_x", "truck_com_z", "passes"),
}


def panel_plots(units: Mapping[str, str] = SIGNAL_UNITS,
                truck: bool = False) -> dict[str, list[tuple[str, str, tuple[str, ...]]]]:
    """The plots of each tab: (plot name, unit, entity paths), one plot per unit, in the order of first use.

    A tab of :data:`SIGNAL_PANELS` whose signals share a unit is one plot; otherwise it is split by unit, so a
    pressure never flattens a stroke on a shared axis. The force tabs get a second plot of route 2 − route 1.
    ``truck``: add the :data:`TRUCK_PANEL` tab (loading-cycle recordings)."""
    out: dict[str, list[tuple[str, str, tuple[str, ...]]]] = {}
    units = {**TRUCK_UNITS, **units} if truck else units
    for title, names in {**SIGNAL_PANELS, **(TRUCK_PANEL if truck else {})}.items():
        by_unit: dict[str, list[str]] = {}
        for n in names:
            by_unit.setdefault(units.get(n, "?"), []).append(f"{SIGNALS_PATH}/{n}")
        plots = [(title if len(by_unit) == 1 else f"{title} [{unit}]", unit, tuple(paths))
                 for unit, paths in by_unit.items()]
        residuals = tuple(f"{RESIDUALS_PATH}/{n}" for n in names if n in TWO_ROUTE_FORCES)
        if residuals:
            plots.append((f"{title}: route 2 − route 1 [N]", "N", residuals))
        out[title] = plots
    return out


def blueprint(truck: bool = False) -> rrb.Blueprint:
    """Default layout: the 3D scene and phases on the left, tabs of signal plots (one per unit) on the right; with
    ``truck`` the loading cycle's truck tab too."""
    tabs: list[Any] = []
    for title, plots in panel_plots(truck=truck).items():
        views = [rrb.TimeSeriesView(origin=SIGNALS_PATH, contents=list(paths), name=name) for name, _, paths in plots]
        tabs.append(views[0] if len(views) == 1 else rrb.Vertical(*views, name=title))
    tabs.append(rrb.TimeSeriesView(origin=GROUPS_PATH, name="Dimensionless groups"))
    left = rrb.Vertical(rrb.Spatial3DView(origin="/world", name="Loader"),
                        rrb.StateTimelineView(origin=PHASE_PATH, name="Dig phase"),
                        rrb.TextLogView(origin=PHASE_LOG_PATH, name="Phase changes"), row_shares=[4, 1, 1])
    return rrb.Blueprint(rrb.Horizontal(left, rrb.Tabs(*tabs), column_shares=[1, 1]), collapse_panels=True)


def open_stream(path: str | Path | None = None, *, spawn: bool = False, name: str | None = None,
                truck: bool = False) -> rr.RecordingStream:
    """A new recording stream that saves to ``path`` and/or streams to a spawned viewer, with the layout
    (``truck``: of a loading-cycle recording)."""
    rec = rr.RecordingStream(APP_ID)
    if path is not None:
        rec.save(path, default_blueprint=blueprint(truck))
    if spawn:
        rec.spawn(default_blueprint=blueprint(truck))
    if name:
        rec.send_recording_name(name)
    return rec


def send_provenance(rec: rr.RecordingStream, provenance: Provenance) -> None:
    """Store the provenance (JSON) and the schema/package versions as the recording property ``scaletwin``."""
    doc = json.dumps(provenance.to_dict(), sort_keys=True)
    rec.send_property("scaletwin", rr.AnyValues(provenance=doc, schema_version=SCHEMA_VERSION,
                                                package_version=provenance.package_version))


def time_indexes(steps: Iterable[int], times: Iterable[float]) -> list[rr.TimeColumn]:
    """The ``step`` (sequence) and ``sim_time`` (s) index columns."""
    return [rr.TimeColumn("step", sequence=np.asarray(list(steps), dtype=np.int64)),
            rr.TimeColumn("sim_time", duration=np.asarray(list(times), dtype=np.float64))]


def route_residuals(signals: Mapping[str, Any]) -> dict[str, tuple[Any, Any]]:
    """(route 1, route 2) values of every force present by both routes (a force NaN throughout is left out)."""
    out = {}
    for name, name2 in TWO_ROUTE_FORCES.items():
        if name in signals and name2 in signals and not np.all(np.isnan(np.asarray(signals[name2], float))):
            out[name] = (signals[name], signals[name2])
    return out


class SignalSender:
    """Sends signal, group and phase columns; styles each series once (static ``SeriesLines``)."""

    def __init__(self, rec: rr.RecordingStream, units: Mapping[str, str], length: float | None) -> None:
        self.rec, self.units, self.length = rec, dict(units), length
        self._styled: set[str] = set()
        self._phase: str | None = None

    def send(self, steps: np.ndarray, times: np.ndarray, signals: Mapping[str, np.ndarray],
             phases: list[str] | None = None) -> None:
        """Send one block of steps: signals (SI arrays by name), their groups and phase changes."""
        idx = time_indexes(steps, times)
        for name, values in signals.items():
            self._series(f"{SIGNALS_PATH}/{name}", f"{name} [{self.units.get(name, '?')}]", idx, values)
        for name, values in dimensionless_groups(signals, self.length).items():
            self._series(f"{GROUPS_PATH}/{name}", GROUPS[name][0], idx, np.broadcast_to(values, steps.shape))
        for name, (route1, route2) in route_residuals(signals).items():
            unit = self.units.get(name, "N")
            self._series(f"{RESIDUALS_PATH}/{name}", f"{name} route 2 − route 1 [{unit}]", idx,
                         np.asarray(route2, float) - np.asarray(route1, float))
        if phases:
            self._send_phases(steps, times, phases)

    def _series(self, path: str, label: str, idx: list[rr.TimeColumn], values: np.ndarray) -> None:
        if path not in self._styled:
            self.rec.log(path, rr.SeriesLines(names=label), static=True)
            self._styled.add(path)
        self.rec.send_columns(path, indexes=idx, columns=rr.Scalars.columns(scalars=np.asarray(values, float)))

    def _send_phases(self, steps: np.ndarray, times: np.ndarray, phases: list[str]) -> None:
        prev = [self._phase, *phases[:-1]]
        at = [k for k, (p, q) in enumerate(zip(prev, phases, strict=True)) if p != q]
        self._phase = phases[-1]
        if not at:
            return
        idx = time_indexes(steps[at], times[at])
        text = [f"phase: {phases[k]}" for k in at]
        self.rec.send_columns(PHASE_LOG_PATH, indexes=idx, columns=rr.TextLog.columns(text=text,
                                                                                      level=["INFO"] * len(at)))
        self.rec.send_columns(PHASE_PATH, indexes=idx, columns=rr.StateChange.columns(state=[phases[k] for k in at]))


class RerunLogger:
    """An ``on_step`` callback (see :func:`scaletwin_envs.rollout.run_episode`) that logs an env to rerun.

    Steps are buffered and sent as columns every ``flush_every`` steps and on :meth:`close` (columns cost a
    fraction of per-step ``log`` calls); ``flush_every=1`` sends every step at once for a live viewer.

    Args:
        env: the env being stepped (its MuJoCo model, pile and soil are read).
        rec: the stream (see :func:`open_stream`; ``rr.RecordingStream.spawn`` for a live viewer).
        signals, scene: what to log.
        seed, policy: stored in the provenance sent at reset (None: no provenance is sent).
    """

    def __init__(self, env: gym.Env, rec: rr.RecordingStream, *, signals: bool = True, scene: bool = True,
                 flush_every: int = 64, seed: int | None = None, policy: str = "unknown") -> None:
        self.env, self.unwrapped, self.rec = env, env.unwrapped, rec
        self.seed, self.policy = seed, policy
        self.do_signals, self.do_scene, self.flush_every = signals, scene, max(1, int(flush_every))
        loader = getattr(self.unwrapped, "loader", None)
        length = loader.characteristic_length if loader is not None else None
        self.sender = SignalSender(rec, {**SIGNAL_UNITS, **TRUCK_UNITS}, length)
        self.scene = SceneLogger(self.unwrapped.model)
        self._pile_h: np.ndarray | None = None
        request = getattr(self.unwrapped, "request_two_route_check", None)
        if signals and request is not None:  # the route-2 residual plots need route 2 (unless the env refuses it)
            request()
        self._clear()

    def _clear(self) -> None:
        self._steps: list[int] = []
        self._times: list[float] = []
        self._signals: dict[str, list[float]] = {}
        self._phases: list[str] = []
        self._pose: list[tuple[np.ndarray, np.ndarray]] = []
        self._load: list[tuple[np.ndarray, float, float]] = []

    def __call__(self, step: int, action: np.ndarray, info: dict[str, Any]) -> None:
        if step == 0:
            self._on_reset()
            return
        self._steps.append(step)
        self._times.append(float(info.get("time", step * self.unwrapped.dt)))
        if self.do_signals:
            for k, v in info.get("signals", {}).items():
                self._signals.setdefault(k, []).append(v)
            for k in TRUCK_UNITS:  # the loading cycle's truck columns (the "Truck" tab), as in its recordings
                if k in info:
                    self._signals.setdefault(k, []).append(float(info[k]))
            self._phases.append(str(info.get("phase", "")))
        if self.do_scene:
            self._log_scene_step(step, info)
        if len(self._steps) >= self.flush_every:
            self.flush()

    def _on_reset(self) -> None:
        self._pile_h = None
        if self.seed is not None:
            send_provenance(self.rec, env_provenance(self.env, self.seed, self.policy))
        if self.do_scene:
            self.scene.log_geometry(self.rec)
            self._log_pile(0, 0.0)

    def _log_scene_step(self, step: int, info: Mapping[str, Any]) -> None:
        data = self.unwrapped.data
        self._pose.append(self.scene.poses(data))
        mass = float(info.get("loaded_mass", info.get("signals", {}).get("m_load", 0.0)))
        soil = getattr(self.unwrapped, "soil", None)
        centre, radius = self.scene.load_point(data, mass, soil.density if soil is not None else 0.0)
        self._load.append((centre, radius, mass))
        self._log_pile(step, self._times[-1])

    def _log_pile(self, step: int, time: float, force: bool = False) -> None:
        pile = getattr(self.unwrapped, "pile", None)
        if pile is None:
            return
        if not force and self._pile_h is not None:
            tolerance = PILE_TOLERANCE * float(np.max(pile.initial, initial=0.0))
            if float(np.max(np.abs(pile.h - self._pile_h), initial=0.0)) <= tolerance:
                return
        self._pile_h = np.array(pile.h, copy=True)
        self.rec.set_time("step", sequence=step)
        self.rec.set_time("sim_time", duration=time)
        log_pile(self.rec, pile)

    def flush(self) -> None:
        """Send the buffered steps."""
        if not self._steps:
            return
        steps, times = np.asarray(self._steps), np.asarray(self._times)
        if self.do_signals:
            signals = {k: np.asarray(v, dtype=np.float64) for k, v in self._signals.items() if len(v) == len(steps)}
            self.sender.send(steps, times, signals, self._phases)
        if self.do_scene:
            idx = time_indexes(steps, times)
            self.scene.send_poses(self.rec, idx, np.stack([p for p, _ in self._pose]),
                                  np.stack([q for _, q in self._pose]))
            centres, radii, masses = (np.asarray(v) for v in zip(*self._load, strict=True))
            send_load(self.rec, idx, centres, radii, masses)
        self._clear()

    def close(self) -> None:
        """Send what is buffered (and the final pile) and flush the stream."""
        if self.do_scene and self._steps:
            self._log_pile(self._steps[-1], self._times[-1], force=True)
        self.flush()
        self.rec.flush()


def send_recording(rec: rr.RecordingStream, recording: Recording) -> None:
    """Log a recording's signals, groups and phases as columns (works for imported recordings too)."""
    data = recording.data
    spec = recording.provenance.machine_spec()
    sender = SignalSender(rec, recording.units, spec.characteristic_length if spec is not None else None)
    names = [c for c in (*SIGNAL_UNITS, *TRUCK_UNITS) if c in data.columns and not data[c].isna().all()]
    phases = [str(p) for p in data["phase"]] if "phase" in data.columns else None
    sender.send(data["step"].to_numpy(), data["time"].to_numpy(dtype=np.float64),
                {n: data[n].to_numpy(dtype=np.float64) for n in names}, phases)


def log_episode_rrd(recording: Recording, path: str | Path, env: gym.Env | None = None, *,
                    scene: bool = True) -> Path:
    """Save a recording as an ``.rrd`` file (atomically) with the default layout.

    Signals, groups and phases come from the recording itself. The 3D scene comes from replaying the stored
    commands in ``env`` (default: the twin rebuilt from the provenance); for a simulated recording this is
    the recorded motion exactly. It is left out when ``scene`` is False or the recording has neither a
    machine spec nor a seed (an external log).
    """
    prov = recording.provenance
    name = f"{(prov.machine or {}).get('name', 'external')} seed {prov.seed}"
    with atomic_path(path) as tmp:
        rec = open_stream(tmp, name=name, truck="truck_payload" in recording.data.columns)
        send_provenance(rec, prov)
        send_recording(rec, recording)
        if scene and prov.seed is not None and (env is not None or prov.machine is not None):
            _replay_scene(rec, recording, env)
        rec.flush()
        rec.disconnect()
    return Path(path)


def _replay_scene(rec: rr.RecordingStream, recording: Recording, env: gym.Env | None) -> None:
    from scaletwin_envs.recording.recorder import record_episode
    from scaletwin_envs.recording.replay import CommandPlayback, make_twin  # replay imports the recorder

    twin = env if env is not None else make_twin(recording.provenance)
    logger = RerunLogger(twin, rec, signals=False)
    record_episode(twin, CommandPlayback(recording.commands), recording.provenance.seed,
                   max_steps=len(recording), on_step=logger, policy_name="rerun scene replay")
    logger.flush()
