"""Shared fixtures: one nominal ER12 twin, planted recordings cached per session, fast diagnosis options."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import pytest

from discrepancy import DiagnoseOptions, Diagnosis, Effect, IdentifyOptions, NullSpec, Scales, TwinSpec, diagnose
from discrepancy.bench.synth import Synthetic, record
from discrepancy.data.episode import signal_spread
from scaletwin_envs.specs import make_loader, make_soil

#: Fewer null runs, two refined candidates, one Gauss–Newton step while naming and none in the final fit: the tests
#: stay fast, the pipeline is the same.
FAST = DiagnoseOptions(null=NullSpec(runs=3), identify=IdentifyOptions(refine=2, polish=1, finalists=1),
                       gn_iterations=0)


@pytest.fixture(scope="session")
def twin() -> TwinSpec:
    return TwinSpec(make_loader("er12"), make_soil("gravel"), {}, 11)


@pytest.fixture(scope="session")
def scales(twin: TwinSpec) -> Scales:
    nominal = record(twin, [], 0.0, twin.seed)
    return Scales.of(twin.loader, twin.soil, signal_spread(nominal.clean.signals))


@pytest.fixture(scope="session")
def planted(twin: TwinSpec) -> Callable[[Sequence[Effect], float], Synthetic]:
    cache: dict[tuple, Synthetic] = {}

    def get(effects: Sequence[Effect], noise: float = 0.01) -> Synthetic:
        key = (tuple(effects), noise)
        if key not in cache:
            cache[key] = record(twin, effects, noise, twin.seed, name="real")
        return cache[key]

    return get


@pytest.fixture(scope="session")
def diagnosed(twin: TwinSpec, planted) -> Callable[..., Diagnosis]:
    cache: dict[tuple, Diagnosis] = {}

    def get(effects: Sequence[Effect], candidates: tuple[str, ...] | None = None, gn_iterations: int = 0
            ) -> Diagnosis:
        key = (tuple(effects), candidates, gn_iterations)
        if key not in cache:
            opts = dataclasses.replace(FAST, identify=dataclasses.replace(FAST.identify, candidates=candidates),
                                       gn_iterations=gn_iterations)
            cache[key] = diagnose(planted(effects).noisy, twin, options=opts)
        return cache[key]

    return get
