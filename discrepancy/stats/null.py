"""The null: repeated perturbed twin runs give the noise model and the calibration of every test statistic.

:func:`calibrate` does it around the nominal twin (before anything is known) or around a twin that already
includes effects (to judge whether what is left after modelling them is still beyond noise); then the fitted
parameters are perturbed too (relative :data:`PARAM_JITTER`), so that moments where the corrected twin itself is
fragile (e.g. samples taken just after a delayed valve switch) are not mistaken for a residual. A twin whose start
was estimated from a log without seed draws each run's start from the estimate's spread
(:meth:`~discrepancy.twin.spec.TwinSpec.null_starts`): later in a dig, what a slightly different pile does is
not a discrepancy; a resampled log's runs replay its commands with their switching times moved within what the
log's sampling leaves uncertain (:func:`~discrepancy.data.fieldlog.jittered_commands`): a dig meets events
(a cylinder stalling at relief, the wheels slipping) whose timing a command a hundredth of a step off moves. A twin
whose sensor filters were estimated from the log (a low-passed log) has each run's filters moved within what
the estimate leaves open (:func:`filter_deviations`): a channel's time constant a tenth off leaves a residual at
every quick change of that channel (a valve reversal), which is not a discrepancy. A log whose time offset
was estimated but not applied, or applied to within its standard error (``TwinSpec.offset_spread``), has each run
read that much earlier or later (:func:`offset_deviations`): the samples at a valve's switch move by most of the
switch where the log is a fraction of a step off.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from discrepancy.context import Context, NullModel, huber
from discrepancy.data.fieldlog import command_timing, filter_sensitivity, jittered_commands
from discrepancy.effects import Effect
from discrepancy.stats.locate import NullCalibration, Window, window_stats
from discrepancy.stats.noise import NoiseModel, NullSpec, sensor_noise
from discrepancy.twin.plant import Plan, plan
from discrepancy.twin.spec import SimResult

PARAM_JITTER = 0.02  # relative perturbation of fitted parameters in the null runs around a corrected twin
#: Relative standard deviation of each channel's estimated sensor-filter time constant in the null runs. Fitted
#: on the log's first rows against a start the log leaves uncertain, the time constants of a noise-free 500 Hz log
#: (benchmark seed 15 case 5, channels filtered at 0.08–0.30 s each) came out 0–25 % short, median 10 %.
FILTER_SPREAD = 0.15
#: ... per effect where it should differ (none at present).
JITTER: dict[str, float] = {}


def _jittered(effects: Sequence[Effect], rng: np.random.Generator) -> list[Effect]:
    out = []
    for e in effects:
        size = JITTER.get(e.name, PARAM_JITTER)
        out.append(Effect(e.name, e.target, tuple((k, v * (1.0 + size * rng.standard_normal())) for k, v in e.values)))
    return out


def _plans(ctx: Context, spec: NullSpec, effects: Sequence[Effect]) -> tuple[list[Plan], list[tuple[Effect, ...]]]:
    """One plan per null run and the (jittered) effects it replays."""
    plans, replayed = [], []
    for k, base in enumerate(spec.plans(ctx.scales)):
        jittered = _jittered(effects, np.random.default_rng([spec.seed, k, 31])) if effects else []
        plans.append(plan(jittered, ctx.replays.runner.twin.soil, base.physics) if effects else base)
        replayed.append(tuple(jittered))
    return plans, replayed


def calibrate(ctx: Context, spec: NullSpec | None = None, effects: Sequence[Effect] = ()) -> NullModel:
    """The null model of the twin with ``effects`` (nominal twin when empty), from ``spec.runs`` replays."""
    spec = spec or NullSpec()
    center_result = ctx.replays.get(list(effects))
    center = ctx.matrix(center_result)
    plans, replayed = _plans(ctx, spec, effects)
    runs = _null_runs(ctx, spec, plans)
    ctx.replays.runs += len(runs)
    dev = np.stack([ctx.matrix(r) - center for r in runs])
    dev = np.where(np.isfinite(dev), dev, 0.0)
    twin = ctx.replays.runner.twin
    taus = twin.channel_taus(ctx.names)
    if np.any(taus > 0.0):
        dev = dev + filter_deviations(np.nan_to_num(center), ctx.real.dt, taus, len(runs),
                                      np.random.default_rng([spec.seed, 83]))
    if twin.offset_spread > 0.0:
        dev = dev + offset_deviations(np.nan_to_num(center), ctx.real.dt, twin.offset_spread, len(runs),
                                      np.random.default_rng([spec.seed, 89]))
    spread = np.array([ctx.scales.signal_scale[s] for s in ctx.names])
    residual = np.nan_to_num(ctx.real_matrix - center)
    regressors = np.nan_to_num(center)  # what the twin's own signals explain is not noise (sensor_noise)
    noise, calibration, cost, drift = null_from_arrays(ctx.names, residual, dev, spread, regressors, ctx.windows(),
                                                       np.random.default_rng([spec.seed, 7919]))
    uncertain_inputs = (twin.start_draws or twin.offset_spread > 0.0 or np.any(taus > 0.0)
                        or command_timing(ctx.real.input_report) > 0)
    return NullModel(noise, calibration, cost, _channel_noise(ctx, center_result.signals), drift,
                     dev if uncertain_inputs else None, tuple(replayed))


def filter_deviations(twin: np.ndarray, dt: float, taus: np.ndarray, runs: int, rng: np.random.Generator
                      ) -> np.ndarray:
    """(runs, steps, signals): what moving each channel's sensor-filter time constant ``taus`` (s, per signal; 0:
    not filtered) by a relative normal draw of :data:`FILTER_SPREAD` does to the filtered ``twin`` (steps,
    signals, sampled every ``dt`` s), to first order: ``δτ · ∂y/∂τ``
    (:func:`~discrepancy.data.fieldlog.filter_sensitivity`)."""
    out = np.zeros((runs, *twin.shape))
    for j in np.flatnonzero(taus > 0.0):
        sensitivity = filter_sensitivity(twin[:, j], dt, float(taus[j]))
        out[:, :, j] = (FILTER_SPREAD * taus[j] * rng.standard_normal(runs))[:, None] * sensitivity[None, :]
    return out


def offset_deviations(twin: np.ndarray, dt: float, spread: float, runs: int, rng: np.random.Generator
                      ) -> np.ndarray:
    """(runs, steps, signals): what reading the ``twin`` (steps, signals, sampled every ``dt`` s) at a time offset
    drawn normal with standard deviation ``spread`` s does to it, to first order: ``−δt · ẏ`` (central
    differences)."""
    rate = np.gradient(np.asarray(twin, dtype=np.float64), dt, axis=0)
    return -(spread * rng.standard_normal(runs))[:, None, None] * rate[None]


def _null_runs(ctx: Context, spec: NullSpec, plans: list[Plan]) -> list[SimResult]:
    """The null's replays: one per plan, from the twin's start draws (a log without seed), each with the log's
    commands moved within their timing uncertainty (a resampled log, :func:`command_timing`)."""
    runner = ctx.replays.runner
    starts = runner.twin.null_starts(len(plans))
    timing = command_timing(ctx.real.input_report)
    if timing <= 0:
        return runner.run_many(ctx.real.commands, plans, ctx.replays.seed, starts=starts)
    return [runner.run_many(jittered_commands(ctx.real.commands, timing, np.random.default_rng([spec.seed, k, 59])),
                            [p], ctx.replays.seed, starts=None if starts is None else [starts[k]])[0]
            for k, p in enumerate(plans)]


def null_from_arrays(names: tuple[str, ...], residual: np.ndarray, dev: np.ndarray, spread: np.ndarray,
                     regressors: np.ndarray, wins: list[Window], rng: np.random.Generator
                     ) -> tuple[NoiseModel, NullCalibration, float, NullCalibration]:
    """Noise model, window calibration, expected objective and the window calibration under the whitening with
    drift (:meth:`~discrepancy.stats.noise.NoiseModel.whiten_drift`) from arrays (what :func:`calibrate` replays).

    Args:
        names: signal names.
        residual: real minus twin, (steps, signals), signal units.
        dev: perturbed twin runs minus the twin, (runs, steps, signals), signal units (finite).
        spread: each signal's spread, (signals,), signal units (floors the noise).
        regressors: the twin's signals (steps, signals), whose fit is not noise.
        wins: the windows tested.
        rng: draws the null runs' sensor noise.
    """
    noise = NoiseModel.build(names, sensor_noise(residual, spread, regressors), dev)
    sizes = np.array([w.size for w in wins])
    null_stats, costs, offsets, gains, drift_stats = [], [], [], [], []
    for k in range(len(dev)):
        sensed = noise.sample(rng)  # sensor noise as modelled (drift included)
        fake = dev[k] + sensed  # scored like the recording: a noise model re-estimated (from the noise: the
        # twin's deviations would pass for coloured noise and make the null too narrow), with the spread of all
        # runs (a run's own rare jump left out would look like a huge residual and make that signal blind)
        model = NoiseModel.build(names, sensor_noise(sensed, spread, regressors), dev)
        z = model.whiten(fake)
        null_stats.append(window_stats(z, wins))
        drift_stats.append(window_stats(np.nan_to_num(model.whiten_drift(fake)), wins))
        costs.append(float(np.sum(huber(z))))
        offsets.append(model.bias_evidence(fake))  # what a constant offset gains on noise alone
        gains.append(model.gain_evidence(fake, regressors))  # ... and a gain (a drift can resemble the twin)
    noise.bias_null = np.mean(offsets, axis=0) if offsets else None
    noise.gain_null = np.mean(gains, axis=0) if gains else None
    return (noise, NullCalibration.fit(null_stats, sizes), float(np.mean(costs)),
            NullCalibration.fit(drift_stats, sizes))


def _channel_noise(ctx: Context, twin: dict[str, np.ndarray]) -> dict[str, float]:
    """Sensor noise of every channel real and twin share (compared and route-2 signals)."""
    out = {}
    for name, values in ctx.real.signals.items():
        if name in twin and np.all(np.isfinite(twin[name])):
            r = (values - twin[name])[:, None]
            out[name] = sensor_noise(r, np.array([max(float(np.std(values)), 1e-12)]))[0].sd
    return out
