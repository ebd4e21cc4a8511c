"""Synthetic "real" recordings: the twin with physics planted and hidden, driven in closed loop by the scripted
dig policy, read through faulty sensors and measurement noise.

:func:`simulate` gives the truth at the control step; :func:`record` adds white noise (the tests' recordings);
:func:`field_recording` delivers a benchmark case's recording under its input condition
(:mod:`discrepancy.bench.logs`) and noise family (:mod:`discrepancy.bench.sensor_noise`). The diagnosis only ever
sees the returned :class:`EpisodeData` or log file (commands, noisy signals, and what the condition lets through of
the provenance), never the planted physics.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from discrepancy.bench.logs import Condition, logged_channels, resample, write_csv, write_twin_json
from discrepancy.bench.sensor_noise import NoiseSpec, apply_noise
from discrepancy.data.channels import COMPARED, ROUTE2
from discrepancy.data.episode import EpisodeData, load_episode, signal_spread
from discrepancy.effects import Effect
from discrepancy.twin.env import PhysicsParams, TwinDigEnv
from discrepancy.twin.plant import apply_sensors, plan
from discrepancy.twin.spec import Between, Simulator, TwinSpec
from scaletwin_envs.policies import ScriptedDigPolicy


@dataclass
class Synthetic:
    """A planted recording: what the tool sees (``noisy``) and the truth (``clean``, before noise)."""

    noisy: EpisodeData
    clean: EpisodeData
    noise_sd: dict[str, float]
    control_dt: float = float("nan")
    path: Path | None = None  # the field log the tool reads (None: ``noisy`` is handed over in memory)
    meta: dict[str, object] = field(default_factory=dict)
    #: what the case's sensors read without their additive noise (filtered, offset, at the log's rate), delivered
    #: the same way as ``noisy`` (through the tool's loader for a field log): what the tool would get from
    #: noise-free sensors of this kind (the scoring's truth, :func:`~discrepancy.bench.scoring.truth_pairs`)
    reading: EpisodeData | None = None


#: Instants per control step at which the benchmark's sensor filter acts on the truth between the control steps:
#: four times the twin's readings (5 per step, ``TwinDigEnv.read_between``), cubic between those, so that the
#: generator's sensor is finer than the tool's model of it (a filter over the tool's readings, linear between them).
FILTER_PARTS = 20


def simulate(twin: TwinSpec, effects: Sequence[Effect], seed: int, extra: PhysicsParams | None = None,
             name: str = "real") -> tuple[EpisodeData, float]:
    """One closed-loop dig cycle of the twin with ``effects`` (and out-of-catalogue ``extra`` physics), noise-free.

    Returns:
        The truth at the control step (signals after planted sensor faults; provenance: the nominal twin and
        ``seed``) and the control step, s.
    """
    clean, control_dt, _ = simulate_between(twin, effects, seed, extra, name)
    return clean, control_dt


def simulate_between(twin: TwinSpec, effects: Sequence[Effect], seed: int, extra: PhysicsParams | None = None,
                     name: str = "real") -> tuple[EpisodeData, float, Between]:
    """:func:`simulate`, and the truth between the control steps too: the planted twin read at each of its soil
    refreshes (``TwinDigEnv.read_between``), what a log sampled faster than the control step sees between them
    (:func:`~discrepancy.bench.logs.resample`); the control-step truth is the same to the bit."""
    p = plan(effects, twin.soil, extra)
    env = TwinDigEnv(structure=p.structure, scale=twin.loader, soil=twin.soil, two_route_check=True,
                     **twin.env_kwargs)
    env.set_physics(p.physics)
    policy = ScriptedDigPolicy()
    policy.reset()
    env.read_between()
    obs, _ = env.reset(seed=seed)
    commands, rows, phases, times = [], [], [], []
    done = False
    while not done:
        action = np.asarray(policy(obs), dtype=np.float32)
        obs, _, terminated, truncated, info = env.step(action)
        if info.get("sim_error"):
            break
        commands.append(action.astype(np.float64))
        rows.append(info["signals"])
        phases.append(info["phase"])
        times.append(info["time"])
        done = terminated or truncated
    names = [k for k in (*COMPARED, *ROUTE2) if k in rows[0]]
    time = np.asarray(times)
    signals = apply_sensors({k: np.array([r[k] for r in rows]) for k in names}, time, p.sensors)
    clean = EpisodeData(time, np.asarray(commands), signals, np.asarray(phases, dtype=object), seed, twin.loader,
                        twin.soil, dict(twin.env_kwargs), name)
    fine_dt, merged = env.readings(rows)
    fine_time = fine_dt * np.arange(1, len(merged) + 1)
    between = Between(fine_dt, apply_sensors({k: np.array([r[k] for r in merged]) for k in names}, fine_time,
                                             p.sensors))
    return clean, float(env.dt), between


def record(twin: TwinSpec, effects: Sequence[Effect], noise: float, seed: int, extra: PhysicsParams | None = None,
           name: str = "real") -> Synthetic:
    """One closed-loop dig cycle (:func:`simulate`) read with white noise.

    Args:
        twin: the nominal twin (its provenance is what the recording carries).
        effects: planted catalogue effects.
        noise: white noise standard deviation per signal, as a fraction of that signal's spread.
        seed: reset seed of the episode and seed of the noise.
        extra: run-time physics to start from (out-of-catalogue terms such as ``stiffness``/``edge_drag``).
    """
    clean, control_dt = simulate(twin, effects, seed, extra, name)
    time, signals = clean.time, clean.signals
    rng = np.random.default_rng([seed, 104729])
    sd = {k: noise * v for k, v in signal_spread(signals).items()}
    noisy_signals = {k: v + sd[k] * rng.standard_normal(v.shape) for k, v in signals.items()}
    noisy = EpisodeData(time, clean.commands.copy(), noisy_signals, clean.phases.copy(), seed, twin.loader, twin.soil,
                        dict(twin.env_kwargs), name)
    return Synthetic(noisy, clean, sd, control_dt)


def field_recording(clean: EpisodeData, control_dt: float, noise: NoiseSpec, cond: Condition,
                    ranges: Mapping[str, float], sub_seed: int, folder: Path | None = None,
                    between: Between | None = None) -> Synthetic:
    """A case's recording as the tool receives it under ``cond``, read through the sensors of ``noise``.

    Args:
        clean: the truth at the control step (:func:`simulate`).
        control_dt: the twin's control step, s.
        noise: the case's sensor noise.
        cond: the input condition; a field log is written to ``folder / f"{clean.name}.csv"``.
        ranges: channel ranges (SI) the noise amplitudes are fractions of.
        sub_seed: distinguishes the noise of the case's recordings.
        folder: where field logs go (needed unless ``cond`` is ``native``).
        between: the truth between the control steps (:func:`simulate_between`), which a log faster than the
            control step, a log at an offset and a sensor filter see; None: interpolated between the control
            steps.

    Returns:
        ``noisy`` is the in-memory recording (native) or what the tool's loader made of the log (field logs:
        ``path`` set); ``noise_sd`` is the standard deviation per channel of the additive noise after averaging it
        over each control step (what a perfect anti-aliasing filter leaves), used by the scoring only.

    Raises:
        RecordingError: the tool's loader refused the log (e.g. a rate it cannot resample yet).
    """
    # between the control steps, the physics (a log sampled faster, or late, reads it there); a sensor filter acts
    # on it at FILTER_PARTS instants per control step at least
    h = 1.0 / cond.rate_hz if cond.rate_hz else control_dt
    parts = max(1, math.ceil(FILTER_PARTS * h / control_dt - 1e-9)) if noise.family == "lowpass" else 1
    log = resample(clean.time, clean.commands, clean.signals, cond, control_dt, between, parts)
    channels = logged_channels(log.truth, cond) if cond.field_log else list(log.truth)
    noisy = apply_noise(noise, {k: log.truth[k] for k in channels}, log.h, control_dt, ranges, sub_seed,
                        {k: log.fine[k] for k in channels}, log.parts)
    sd = {k: _control_step_sd(log.time, v, control_dt) for k, v in noisy.noise.items()}
    if not cond.field_log:
        ep, reading = (EpisodeData(clean.time.copy(), clean.commands.copy(), signals, clean.phases.copy(), clean.seed,
                                   clean.machine, clean.soil, dict(clean.env_kwargs), clean.name)
                       for signals in (noisy.measured, noisy.sensor))
        return Synthetic(ep, clean, sd, control_dt, reading=reading)
    if folder is None:
        raise ValueError(f"condition {cond.name!r} writes a field log: give a folder")
    path = write_csv(Path(folder) / f"{clean.name}.csv", log.time, log.commands, noisy.measured)
    quiet = write_csv(Path(folder) / "noise-free" / f"{clean.name}.csv", log.time, log.commands, noisy.sensor)
    return Synthetic(_load(path, control_dt), clean, sd, control_dt, path, {"rows": len(log.time), "h": log.h},
                     _load(quiet, control_dt))


def nominal_replay(twin: TwinSpec, clean: EpisodeData) -> tuple[EpisodeData, Between]:
    """The nominal ``twin`` replaying the commands of the recording ``clean`` open loop from its true start (its
    reset seed), noise-free, at the control step and between the steps: what the recording would have been without
    the planted physics, for the same commands (the scoring's reference; the tool itself never has the seed).

    Raises:
        RuntimeError: the nominal twin did not run through the commands.
    """
    sim = Simulator(dataclasses.replace(twin, seed=clean.seed)).run(clean.commands, between=True)
    if sim.error or sim.between is None:
        raise RuntimeError(f"{clean.name}: the nominal twin failed replaying the recording's commands ({sim.error})")
    signals = {k: np.asarray(v, float) for k, v in sim.signals.items() if k in clean.signals}
    ep = EpisodeData(clean.time.copy(), clean.commands.copy(), signals, np.asarray(sim.phases, dtype=object),
                     clean.seed, clean.machine, clean.soil, dict(clean.env_kwargs), f"{clean.name}_nominal")
    return ep, Between(sim.between.dt, {k: v for k, v in sim.between.signals.items() if k in signals})


def twin_file(twin: TwinSpec, folder: Path) -> Path:
    """The twin as a field user describes it (JSON without a seed)."""
    return write_twin_json(Path(folder) / "twin.json", twin.loader.to_dict(), twin.soil.to_dict(),
                           dict(twin.env_kwargs))


def _load(path: Path, control_dt: float) -> EpisodeData:
    """The tool's loader on a field log; the control step is passed where the loader takes it (field-log support)."""
    if "control_dt" in inspect.signature(load_episode).parameters:
        return load_episode(path, control_dt=control_dt)  # type: ignore[call-arg]
    return load_episode(path)


def _control_step_sd(time: np.ndarray, noise: np.ndarray, control_dt: float) -> float:
    """Standard deviation of ``noise`` averaged over each control step (one value if sampled at that step)."""
    bins = np.floor((np.asarray(time) - time[0]) / control_dt + 1e-6).astype(int)
    counts = np.bincount(bins)
    means = np.bincount(bins, weights=noise)[counts > 0] / counts[counts > 0]
    return float(np.std(means))


def aligned(clean: EpisodeData, time: np.ndarray) -> EpisodeData:
    """The truth at the tool's sample times (linear interpolation; phases of the nearest control step). The same
    object when the times agree (native rate)."""
    time = np.asarray(time, float)
    if len(time) == len(clean.time) and np.allclose(time, clean.time):
        return clean
    signals = {k: np.interp(time, clean.time, v, left=np.nan, right=np.nan) for k, v in clean.signals.items()}
    idx = np.clip(np.searchsorted(clean.time, time), 0, len(clean.time) - 1)
    return EpisodeData(time, clean.commands[idx], signals, clean.phases[idx], clean.seed, clean.machine, clean.soil,
                       dict(clean.env_kwargs), clean.name)
