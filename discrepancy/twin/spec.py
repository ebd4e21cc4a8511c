"""The twin: which machine, soil and env settings it is (:class:`TwinSpec`), and replaying a recording's commands
on it with any planted effects (:class:`Simulator`).

The replay is open loop: the twin receives exactly the commands of the real machine, step by step, from the
recorded reset seed, and runs for as many steps as the recording has (it does not stop where the twin's own
cycle would end). Envs are built once per model structure and reused.
"""

from __future__ import annotations

import inspect
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from discrepancy.data.channels import COMPARED, ROUTE2, RecordingError
from discrepancy.data.episode import EpisodeData
from discrepancy.data.fieldlog import antialias_filter, delayed, first_order_filter, resampling_operator
from discrepancy.twin.env import Structure, TwinDigEnv
from discrepancy.twin.plant import Plan, apply_sensors
from scaletwin_envs.envs.wheel_loader_dig import WheelLoaderDigEnv
from scaletwin_envs.specs import LoaderSpec, SoilSpec, make_loader, make_soil

#: Env arguments that do not change the physics of a replay (and are not passed on).
_IGNORED = {"render_mode", "width", "height", "two_route_check", "scale", "law", "distortion", "soil"}
DT_TOLERANCE = 0.02  # relative mismatch of the recording's sampling step and the twin's control step


@dataclass(frozen=True)
class TwinSpec:
    """The nominal twin: machine, soil, env arguments (JSON values), the reset seed, and what a field log needs
    instead of a seed.

    ``start``: reset options (``WheelLoaderDigEnv.RESET_OPTIONS``: start pose and pile) estimated from a log that
    has no seed; given values replace what the seed would draw. ``sensor_tau``: time constant (s) of a first-order
    sensor filter the log's channels went through, applied to every twin signal (0: none); ``sensor_taus``:
    ``(channel, time constant s)`` where a channel's own filter differs from ``sensor_tau`` (estimated only where
    the log shows a common filter, :func:`~discrepancy.twin.align.align`); ``time_offset``: s by which the log's
    signals lag its commands, applied to every twin signal after the filter (:func:`~discrepancy.data.fieldlog.
    delayed`; the twin read at the log's times, rather than the log shifted: a shift of a sampled step leaves an
    interpolation error the twin's own reading does not); ``start_draws``: starts as uncertain as
    the estimated ``start`` (reset options each), which the null's runs start from (:meth:`null_starts`);
    ``offset_spread``: s, the standard deviation of a time offset the log leaves open (one estimated but not
    applied; one applied, its standard error), which the null's runs carry (:func:`~discrepancy.stats.null.
    offset_deviations`); ``command_tail``: commands ``[lift, tilt, drive]`` the log carries after the last row
    compared, replayed after the log's own (a log whose signals lead its commands reads, on its last rows, the
    machine under commands logged later: those rows are not compared, :func:`~discrepancy.twin.align.align`, but
    their commands drive the rows that are); ``log_step``, ``log_span``: s, the sampling step and the length of a
    log resampled to the control step (0: not resampled): every twin signal is read between the control steps too,
    then offset, filtered and resampled as the log was (:func:`~discrepancy.data.fieldlog.resampling_operator`).
    A log at the control step with a sensor filter or a time offset is read between the control steps as well
    (:attr:`reads_between`): a sensor filters, and a late clock reads, the signal between the samples, not a
    curve through them.
    """

    loader: LoaderSpec
    soil: SoilSpec
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    start: tuple[tuple[str, float], ...] = ()
    sensor_tau: float = 0.0
    sensor_taus: tuple[tuple[str, float], ...] = ()
    start_draws: tuple[tuple[tuple[str, float], ...], ...] = ()
    time_offset: float = 0.0
    offset_spread: float = 0.0
    command_tail: tuple[tuple[float, float, float], ...] = ()
    log_step: float = 0.0
    log_span: float = 0.0

    @property
    def reads_between(self) -> bool:
        """Whether a replay reads the twin between its control steps to give the log's samples: a resampled log,
        or one whose channels went through a sensor filter or lag their commands. Filtered or offset from the
        control-step samples alone (a cubic or a line between them) a force jumping inside a step as a cylinder
        reaches relief came out a median 14–18 % (offset) or 1–12 % (filter) of a channel's range off the log at
        the worst row, up to several ranges for an acceleration (ER12 and mini, offsets 0.05–0.2 s, filters
        0.05–0.3 s)."""
        return self.log_step > 0.0 or self.time_offset != 0.0 or self.sensor_tau > 0.0 or bool(self.sensor_taus)

    def lead_steps(self, dt: float) -> int:
        """Control steps (of ``dt`` s) by which the log's signals lead its commands: the rows at its end that read
        the machine after its last command (0 unless ``time_offset`` < 0)."""
        return math.ceil(-self.time_offset / dt - 1e-9) if self.time_offset < 0 else 0

    def resampling_reach(self, dt: float) -> int:
        """Control steps (of ``dt`` s) over which the log's resampling mixes samples, on either side (0 unless
        resampled, :attr:`log_step`): a replay cut short differs from the whole one over that many last rows."""
        if self.log_step <= 0.0:
            return 0
        taps, _ = antialias_filter(self.log_step, dt)
        return math.ceil((len(taps) // 2) * self.log_step / dt) + 1

    def channel_taus(self, names: Sequence[str]) -> np.ndarray:
        """The sensor-filter time constant (s) applied to each of ``names`` (0: not filtered)."""
        own = dict(self.sensor_taus)
        return np.array([own.get(n, self.sensor_tau) for n in names], dtype=float)

    def null_starts(self, runs: int) -> list[tuple[tuple[str, float], ...]] | None:
        """The starts of ``runs`` null runs (cycling through :attr:`start_draws`), or None when the start is not
        uncertain."""
        if not self.start_draws:
            return None
        return [self.start_draws[k % len(self.start_draws)] for k in range(runs)]

    @classmethod
    def from_episode(cls, ep: EpisodeData) -> TwinSpec:
        """The twin described by a recording's provenance.

        Raises:
            RecordingError: the recording has no machine spec (pass a twin explicitly).
        """
        if ep.machine is None:
            raise RecordingError(f"{ep.name}: the provenance has no machine; give the twin (--twin SPEC)")
        return cls(ep.machine, ep.soil or make_soil("gravel"), _physics_kwargs(ep.env_kwargs),
                   ep.seed if ep.seed is not None else 0)

    @classmethod
    def parse(cls, text: str, ep: EpisodeData | None = None) -> TwinSpec:
        """A twin from ``text``: a JSON file ``{"scale", "soil", "env_kwargs", "seed"}`` (``scale`` a preset, a
        float or a LoaderSpec dict; ``soil`` a name or a SoilSpec dict) or ``SCALE[:SOIL[:SEED]]`` (e.g.
        ``er12:gravel:3``). Missing fields come from the recording's provenance (seed, env arguments); the reset
        seed fixes the twin's start pose and pile, so it should be the recording's."""
        path = Path(text)
        if path.suffix == ".json" or path.is_file():
            try:
                doc = json.loads(path.read_text())
            except (OSError, json.JSONDecodeError) as exc:
                raise ValueError(f"cannot read twin spec {text}: {exc}") from exc
        else:
            scale, _, rest = text.partition(":")
            soil, _, seed = rest.partition(":")
            doc = {"scale": scale, "soil": soil or None}
            if seed:
                try:
                    doc["seed"] = int(seed)
                except ValueError as exc:
                    raise ValueError(f"twin spec {text!r}: the seed must be an integer") from exc
        return cls.from_dict(doc, ep)

    @classmethod
    def from_dict(cls, doc: dict[str, Any], ep: EpisodeData | None = None) -> TwinSpec:
        scale = doc.get("scale")
        loader = LoaderSpec.from_dict(scale) if isinstance(scale, dict) else make_loader(_scale(scale))
        soil_doc = doc.get("soil")
        soil = (SoilSpec(**soil_doc) if isinstance(soil_doc, dict) else make_soil(soil_doc) if soil_doc
                else (ep.soil if ep is not None and ep.soil else make_soil("gravel")))
        kwargs = _physics_kwargs(doc.get("env_kwargs", ep.env_kwargs if ep is not None else {}))
        seed = doc.get("seed", ep.seed if ep is not None and ep.seed is not None else 0)
        start = tuple(sorted((str(k), float(v)) for k, v in dict(doc.get("start", {})).items()))
        taus = tuple(sorted((str(k), float(v)) for k, v in dict(doc.get("sensor_taus", {})).items()))
        draws = tuple(tuple(sorted((str(k), float(v)) for k, v in dict(d).items()))
                      for d in doc.get("start_draws", []))
        tail = tuple((float(a), float(b), float(c)) for a, b, c in doc.get("command_tail", []))
        return cls(loader, soil, kwargs, int(seed), start, float(doc.get("sensor_tau", 0.0)), taus, draws,
                   float(doc.get("time_offset", 0.0)), float(doc.get("offset_spread", 0.0)), tail,
                   float(doc.get("log_step", 0.0)), float(doc.get("log_span", 0.0)))

    def to_dict(self) -> dict[str, Any]:
        return {"scale": self.loader.to_dict(), "soil": self.soil.to_dict(), "env_kwargs": dict(self.env_kwargs),
                "seed": self.seed, "start": dict(self.start), "sensor_tau": self.sensor_tau,
                "sensor_taus": dict(self.sensor_taus), "start_draws": [dict(d) for d in self.start_draws],
                "time_offset": self.time_offset, "offset_spread": self.offset_spread,
                "command_tail": [list(c) for c in self.command_tail], "log_step": self.log_step,
                "log_span": self.log_span}


def _scale(value: Any) -> float | str:
    if value is None:
        raise ValueError("the twin spec needs a scale (preset name, float or LoaderSpec dict)")
    try:
        return float(value)
    except (TypeError, ValueError):
        return str(value)


def _physics_kwargs(kwargs: dict[str, Any]) -> dict[str, Any]:
    accepted = set(inspect.signature(WheelLoaderDigEnv.__init__).parameters) - {"self"}
    return {k: v for k, v in kwargs.items() if k in accepted and k not in _IGNORED}


@dataclass(frozen=True)
class Between:
    """A replay's signals read between its control steps too (:meth:`TwinDigEnv.read_between
    <discrepancy.twin.env.TwinDigEnv.read_between>`): every ``dt`` s (a whole fraction of the control step), the
    sample at ``dt · (j + 1)`` s after the start, so that every ``control_dt / dt``-th one is a control-step sample;
    SI signals by name, after the same sensor models, filter and offset as the control-step ones."""

    dt: float
    signals: dict[str, np.ndarray]


@dataclass
class SimResult:
    """A replay: SI signals by name (steps,), phases, the first physics error (None when it ran through), and, where
    asked for, the signals between the control steps (:class:`Between`)."""

    signals: dict[str, np.ndarray]
    phases: np.ndarray
    error: str | None = None
    between: Between | None = None


class Simulator:
    """Replays commands on a twin with planted effects; one env per model structure, built on first use."""

    def __init__(self, twin: TwinSpec, two_routes: bool = False) -> None:
        self.twin, self.two_routes = twin, two_routes
        self._envs: dict[tuple[Structure, bool], TwinDigEnv] = {}
        self.runs = 0

    def env(self, structure: Structure, two_routes: bool | None = None) -> TwinDigEnv:
        key = (structure, self.two_routes if two_routes is None else two_routes)
        if key not in self._envs:
            self._envs[key] = TwinDigEnv(structure=structure, scale=self.twin.loader, soil=self.twin.soil,
                                         two_route_check=key[1], **self.twin.env_kwargs)
        return self._envs[key]

    @property
    def control_dt(self) -> float:
        return float(self.env(Structure()).dt)

    def run(self, commands: np.ndarray, plan: Plan | None = None, two_routes: bool | None = None,
            start: tuple[tuple[str, float], ...] | None = None, between: bool = False) -> SimResult:
        """Replay ``commands`` (steps, 3) with ``plan`` from the twin's seed and start (``start`` overrides the
        twin's); signals after sensor models, the twin's sensor filter and its time offset, and, for a resampled
        log (:attr:`TwinSpec.log_step`), its resampling; with ``between``, also read between the control steps
        (:attr:`SimResult.between`, None if the replay did not run through).

        A log whose signals lead its commands (``time_offset`` < 0) ends with rows read after its last command:
        the replay runs on over that span with the twin's :attr:`~TwinSpec.command_tail` (the commands logged
        after the rows compared), and past it with the last command held, rather than reading the twin's last
        sample as if the machine had stopped there."""
        plan = plan or Plan()
        n = len(commands)
        resampled = self.twin.log_step > 0.0 and n > 0
        lead = self.twin.lead_steps(self.control_dt) if n else 0
        # a replay of a resampled log's every row runs on to its last sample, up to a control step past the last
        # row: the anti-alias filter of that row reads it, so the replay runs on as far (the last command held); a
        # replay of its first rows only (a start fit) carries its own margin (TwinSpec.resampling_reach)
        end = math.ceil(1.0 + self.twin.log_span / self.control_dt - 1e-9)
        past = max(lead, end - n) if resampled and n >= end - 1 else lead
        if past:
            tail = np.asarray(self.twin.command_tail[:lead], dtype=float).reshape(-1, 3)
            held = np.repeat(tail[-1:] if len(tail) else np.asarray(commands)[-1:], past - len(tail), axis=0)
            commands = np.concatenate((commands, tail, held))
        env = self.env(plan.structure, two_routes)
        env.set_physics(plan.physics)
        options = dict(self.twin.start if start is None else start)
        env.read_between(between or self.twin.reads_between)
        try:
            env.reset(seed=self.twin.seed, options=options or None)
        except ValueError as exc:  # a start the machine cannot take (a cylinder beyond its stroke): a failed replay
            nan = np.full(n, np.nan)
            return SimResult({k: nan.copy() for k in (*COMPARED, *ROUTE2)}, np.full(n, "error", dtype=object),
                             f"start refused: {exc}")
        self.runs += 1
        rows: list[dict[str, float]] = []
        phases: list[str] = []
        error = None
        for a in np.asarray(commands, dtype=np.float32):
            *_, info = env.step(a)
            if info.get("sim_error"):
                error = str(info["sim_error"])
                break
            rows.append(info["signals"])
            phases.append(info["phase"])
        names = [k for k in (*COMPARED, *ROUTE2) if rows and k in rows[0]]
        # a replay that diverged only in the steps after the log's end holds its last sample over them
        hold = len(rows) >= n
        fine, signals = None, None
        if env.between is not None and error is None and len(rows) == n + past:
            fine_dt, merged = env.readings(rows)
            parts = round(env.dt / fine_dt)
            read = {k: np.array([r[k] for r in merged]) for k in names}
            fine = Between(fine_dt, self._sensed(read, fine_dt, n * parts, plan)) if between else None
            if resampled:  # the sensor filter acts on the signal between the readings, on the log's grid
                taus = dict(zip(names, self.twin.channel_taus(names), strict=True))
                unfiltered = self._sensed(read, fine_dt, (n + past) * parts, plan, filtered=False)
                signals = {k: (resampling_operator(n + past, parts, float(env.dt), self.twin.log_step,
                                                   self.twin.log_span, float(taus[k])) @ v)[:n]
                           for k, v in unfiltered.items()}
            elif self.twin.reads_between:  # filtered and offset between the readings, then sampled at the steps
                sensed = fine.signals if fine is not None else self._sensed(read, fine_dt, n * parts, plan)
                signals = {k: v[parts - 1::parts] for k, v in sensed.items()}
        if signals is None:  # the control-step samples (a replay of a resampled log that did not run through too)
            signals = self._sensed({k: _padded([r[k] for r in rows], n + past, hold) for k in names}, env.dt, n,
                                   plan)
        env.read_between(False)
        phases = phases[:n]
        if hold:
            error = None
        return SimResult(signals, np.asarray(phases + ["error"] * (n - len(phases)), dtype=object), error, fine)

    def _sensed(self, signals: dict[str, np.ndarray], dt: float, n: int, plan: Plan, filtered: bool = True
                ) -> dict[str, np.ndarray]:
        """``signals`` sampled every ``dt`` s (the first at ``dt``) through ``plan``'s sensor models, the twin's
        sensor filters (unless not ``filtered``) and its time offset, cut to their first ``n`` samples."""
        time = dt * np.arange(1, len(next(iter(signals.values()), ())) + 1)
        signals = apply_sensors(signals, time, plan.sensors) if plan.sensors else signals
        if filtered and (self.twin.sensor_tau > 0.0 or self.twin.sensor_taus):
            own = dict(self.twin.sensor_taus)
            signals = {k: first_order_filter(v, dt, own.get(k, self.twin.sensor_tau)) for k, v in signals.items()}
        if self.twin.time_offset:
            signals = {k: delayed(v, dt, self.twin.time_offset) for k, v in signals.items()}
        return {k: v[:n] for k, v in signals.items()}


def _padded(values: list[float], n: int, hold: bool = False) -> np.ndarray:
    """``values`` padded to ``n`` with NaN (or their last value, ``hold``)."""
    out = np.full(n, values[-1] if hold and values else np.nan)
    out[: len(values)] = values
    return out


def check_compatible(ep: EpisodeData, sim: Simulator) -> None:
    """The recording must be sampled at the twin's control step.

    Raises:
        RecordingError: a sampling step that differs from the twin's (a recording of another machine or rate).
    """
    dt = sim.control_dt
    if abs(ep.dt - dt) > DT_TOLERANCE * dt:
        raise RecordingError(f"{ep.name}: sampled every {ep.dt:.4g} s but the twin "
                             f"({sim.twin.loader.name}) steps every {dt:.4g} s; wrong machine or resampled data?")
