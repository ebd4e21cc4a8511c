"""``diagnose``: the whole pipeline on one real recording (plus held-out cycles), timed step by step.

load → replay the commands on the twin → null (noise model and calibration) → locate → linkage redundancy →
identify → fit → compare on held-out cycles. See :class:`Diagnosis` for what comes back and
:mod:`discrepancy.report.document` for the JSON, Markdown and rerun outputs.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from discrepancy.context import Context
from discrepancy.data.episode import EpisodeData, RecordingError, from_recording, load_episode
from discrepancy.effects import UNEXPLAINED, Effect
from discrepancy.search.budget import REPLAYS, SECONDS, Budget
from discrepancy.search.fit import GN_ITERATIONS, Comparison, FitResult, compare, fit
from discrepancy.search.identify import FINALISTS, MAX_EFFECTS, POLISH, Identification, IdentifyOptions, identify
from discrepancy.search.screen import REFINE
from discrepancy.stats.locate import ALPHA, Located, LocateResult, locate
from discrepancy.stats.noise import NoiseModel, NullSpec
from discrepancy.stats.null import calibrate, use
from discrepancy.stats.redundancy import Check, check_all, fault_admissible, sensor_suspects
from discrepancy.twin.runner import CachedReplays, Runner, make_runner
from discrepancy.twin.spec import SimResult, Simulator, TwinSpec, check_compatible
from scaletwin_envs.recording import Recording

Source = EpisodeData | Recording | str | Path


@dataclass(frozen=True)
class DiagnoseOptions:
    """Knobs of a diagnosis (defaults are what the benchmark uses)."""

    workers: int = 1
    null: NullSpec = field(default_factory=NullSpec)
    max_effects: int = MAX_EFFECTS
    alpha: float = ALPHA
    seed: int = 0
    refine: int = REFINE
    candidates: tuple[str, ...] | None = None  # restrict the catalogue (effect names or labels); None: all
    polish: int = POLISH  # Gauss–Newton steps before judging each round
    gn_iterations: int = GN_ITERATIONS  # Gauss–Newton steps of the final fit
    finalists: int = FINALISTS  # rivals refitted before a round's winner is chosen
    budget: int = REPLAYS  # twin replays after which the searches stop (deterministic)
    time_budget: float = SECONDS  # seconds from the start after which the searches stop (safety net)


@dataclass
class ReportedEffect:
    """A named effect as reported: SI parameters and interval, dimensionless groups, confidence, confounding."""

    effect: str
    target: str | None
    parameters: dict[str, float]
    interval: dict[str, tuple[float, float]]
    groups: dict[str, float]
    confidence: float
    confounded_with: list[str]


@dataclass
class Diagnosis:
    """Everything a diagnosis found, with the traces needed to report it."""

    twin: TwinSpec
    names: tuple[str, ...]
    located: list[Located]
    effects: list[ReportedEffect]
    comparison: Comparison
    identification: Identification
    fit_result: FitResult | None
    redundancy: list[Check]
    timings: dict[str, float]
    train: EpisodeData
    held_out: list[EpisodeData]
    traces: dict[str, dict[str, SimResult]]  # episode name → {"twin", "corrected"}
    locate_result: LocateResult | None = None
    simulations: int = 0
    noise: NoiseModel | None = None
    budget: Budget | None = None  # the search budget and whether it cut the search short

    @property
    def named(self) -> list[str]:
        return [e.effect for e in self.effects]


class _Timer:
    def __init__(self) -> None:
        self.steps: dict[str, float] = {}
        self.start = time.perf_counter()

    @contextmanager
    def step(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.steps[name] = self.steps.get(name, 0.0) + time.perf_counter() - t0


def _episode(source: Source) -> EpisodeData:
    if isinstance(source, EpisodeData):
        return source
    if isinstance(source, Recording):
        return from_recording(source)
    return load_episode(source)


def _twin(twin: TwinSpec | str | None, ep: EpisodeData) -> TwinSpec:
    if isinstance(twin, TwinSpec):
        return twin
    return TwinSpec.parse(twin, ep) if twin else TwinSpec.from_episode(ep)


def diagnose(real: Source | Sequence[Source], twin: TwinSpec | str | None = None,
             held_out: Sequence[Source] = (), options: DiagnoseOptions | None = None) -> Diagnosis:
    """Locate, name, model and check the discrepancies of ``real`` against ``twin``.

    Args:
        real: a recording (file, :class:`Recording` or :class:`EpisodeData`), or several: the first is analysed,
            the others are held out for the before/after comparison.
        twin: the twin (:class:`TwinSpec`, a spec string, see :meth:`TwinSpec.parse`); default: the recording's
            provenance.
        held_out: further cycles for the comparison only.
        options: see :class:`DiagnoseOptions`.

    Raises:
        FileNotFoundError, RecordingError: unreadable, corrupted or mismatched recordings.
    """
    opts = options or DiagnoseOptions()
    if opts.budget < 1 or not opts.time_budget > 0:
        raise ValueError(f"budget must be >= 1 replay and time_budget > 0 s, got {opts.budget}, {opts.time_budget}")
    timer = _Timer()
    with timer.step("load"):
        sources = list(real) if isinstance(real, list | tuple) else [real]
        episodes = [_episode(s) for s in sources] + [_episode(s) for s in held_out]
        train, held = episodes[0], episodes[1:]
        spec = _twin(twin, train)
        route2 = Simulator(spec, two_routes=True)
        for ep in episodes:
            check_compatible(ep, route2)
    runner = make_runner(spec, opts.workers)
    try:
        return _run(train, held, spec, route2, runner, opts, timer)
    finally:
        runner.close()


def _run(train: EpisodeData, held: list[EpisodeData], spec: TwinSpec, route2: Simulator, runner: Runner,
         opts: DiagnoseOptions, timer: _Timer) -> Diagnosis:
    replays = CachedReplays(runner, train.commands, train.time)
    with timer.step("replay"):
        ctx = Context.build(train, replays)
        ctx.budget = Budget(opts.budget, opts.time_budget, lambda: replays.runs, timer.start)
        if ctx.nominal.error:
            raise RecordingError(f"{train.name}: the twin diverged replaying the commands ({ctx.nominal.error})")
        if not ctx.names:
            raise RecordingError(f"{train.name}: no signal in common with the twin")
        twin2 = route2.run(train.commands)
    with timer.step("null"):
        null = calibrate(ctx, opts.null)
        use(ctx, null)
    with timer.step("locate"):
        found = locate(ctx.z(ctx.matrix(ctx.nominal)), ctx.time, ctx.windows(), ctx.names, null.calibration,
                       opts.alpha)
    with timer.step("redundancy"):
        checks = check_all(spec.loader, train.signals, twin2.signals, null.channel_noise, train.dt)
        suspects = sensor_suspects(checks, {loc.signal for loc in found.located})
    with timer.step("identify"):
        def guard(e: Effect) -> bool:
            return fault_admissible(e, checks, train.signals, twin2.signals, null.channel_noise, train.time)

        ident = identify(ctx, found, suspects, IdentifyOptions(opts.max_effects, opts.refine, opts.candidates,
                                                               opts.null, opts.polish, opts.finalists,
                                                               opts.budget, opts.time_budget), guard)
    named = ident.effects
    with timer.step("fit"):  # after a cut by the clock, one Gauss–Newton step only
        iterations = min(opts.gn_iterations, 1) if ctx.budget.cut == "time" else opts.gn_iterations
        result = fit(ctx, named, opts.seed, iterations) if named else None
        effects = result.effects if result else []
    with timer.step("compare"):
        eps = held or [train]
        reps = [CachedReplays(runner, ep.commands, ep.time, ep.seed) for ep in held] or [replays]
        comparison = compare(eps, reps, ctx.names, effects, held_out=bool(held))
        traces = {ep.name: {"twin": r.get([]), "corrected": r.get(effects)} for ep, r in zip(eps, reps, strict=True)}
        if held:
            traces[train.name] = {"twin": replays.get([]), "corrected": replays.get(effects)}
    reported = _reported(ctx, ident, result, found)
    timer.steps["total"] = sum(timer.steps.values())
    return Diagnosis(spec, ctx.names, found.located, reported, comparison, ident, result, checks, timer.steps, train,
                     held, traces, found, replays.runs + sum(r.runs for r in reps if r is not replays) + 1, ctx.noise,
                     ctx.budget)


def _reported(ctx: Context, ident: Identification, result: FitResult | None, found: LocateResult
              ) -> list[ReportedEffect]:
    """The accepted effects (fitted), then ``unexplained`` when they (or nothing) leave a residual beyond noise."""
    out = []
    for k, rnd in enumerate(ident.rounds[: len(ident.effects)]):
        assert result is not None
        e: Effect = result.effects[k]
        groups = {f"pi_{n}": v for n, v in e.to_pi(ctx.scales).items()}
        target = e.target if e.spec.target_kind not in ("payload", "soil") else None
        out.append(ReportedEffect(e.name, target, e.params, result.intervals[k], groups, rnd.confidence,
                                  rnd.confounded))
    if ident.unexplained and ident.rounds:
        out.append(_unexplained(ident, found))
    return out


def _unexplained(ident: Identification, found: LocateResult) -> ReportedEffect:
    """What no catalogue effect explains: where it shows most, and the closest candidates."""
    located = ident.after.located if ident.after and ident.after.located else found.located
    top = max(located, key=lambda loc: loc.effect_size).signal if located else None
    last = ident.rounds[len(ident.effects)] if len(ident.rounds) > len(ident.effects) else ident.rounds[-1]
    closest = [last.winner.effect.label(), *last.confounded]
    explained = max(0.0, min(1.0, last.gain_fraction))
    return ReportedEffect(UNEXPLAINED, top, {}, {}, {}, float(1.0 - explained), closest[:5])
