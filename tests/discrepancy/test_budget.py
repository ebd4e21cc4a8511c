"""The search budget: a tiny replay or time budget stops the search early, says so, and the output stays valid;
the replay budget is deterministic."""

from __future__ import annotations

import dataclasses

import pytest

from discrepancy import Effect, NullSpec, diagnose
from discrepancy.context import Context
from discrepancy.effects import UNEXPLAINED
from discrepancy.report.document import markdown, to_json
from discrepancy.report.schema import validate
from discrepancy.search.budget import Budget
from discrepancy.stats.null import calibrate
from discrepancy.twin.runner import CachedReplays, make_runner

from .conftest import FAST

TWO = (("payload_mass_error", "payload", {"mass_error": 0.2}), ("sensor_bias", "F31", {"bias": 0.2}))


def _effects(scales) -> list[Effect]:
    return [Effect.from_pi(n, t, p, scales) for n, t, p in TWO]


def test_budget_object_marks_the_first_cut() -> None:
    spent = [0]
    b = Budget(replays=10, seconds=1e9, spent=lambda: spent[0])
    assert not b.exhausted() and b.cut is None
    assert b.exhausted(reserve=10) and b.cut == "replays"  # not enough left for a further round
    b2 = Budget(replays=10, seconds=0.0, spent=lambda: 0)
    assert b2.exhausted() and b2.cut == "time" and b2.cut_at is not None
    assert b2.to_dict()["cut"] == "time"


@pytest.mark.slow  # ~25-50 s on 2 cores; the time-budget test below covers the same cut-and-report path
def test_tiny_replay_budget_stops_early_and_reports_it(scales, planted, twin) -> None:
    real = planted(_effects(scales)).noisy
    opts = dataclasses.replace(FAST, budget=40)
    d = diagnose(real, twin, options=opts)
    assert d.budget is not None and d.budget.cut == "replays"
    # one screening batch of the whole catalogue and a judgement may run past the cap, no search after it
    assert d.budget.spent() < 40 + 120
    doc = to_json(d)  # validated against the schema
    assert doc["search"]["cut"] == "replays" and doc["search"]["replay_budget"] == 40
    assert "cut short" in markdown(d)
    assert len([e for e in d.effects if e.effect != UNEXPLAINED]) <= 1
    # deterministic: the same budget gives the same answer
    again = diagnose(real, twin, options=opts)
    assert [(e.effect, e.target) for e in again.effects] == [(e.effect, e.target) for e in d.effects]
    assert again.budget is not None and again.budget.spent() == d.budget.spent()


def test_tiny_time_budget_stops_early_and_reports_it(scales, planted, twin) -> None:
    d = diagnose(planted(_effects(scales)).noisy, twin, options=dataclasses.replace(FAST, time_budget=0.01))
    assert d.budget is not None and d.budget.cut == "time"
    doc = to_json(d)
    validate(doc)
    assert doc["search"]["cut"] == "time" and doc["search"]["cut_at_s"] >= 0.01


def test_generous_budget_is_not_reported_as_a_cut(diagnosed) -> None:
    d = diagnosed([])  # a null: nothing to search
    assert d.budget is not None and d.budget.cut is None
    assert "search" not in to_json(d)  # an uncut report has only the keys


def test_bad_budget_is_rejected(planted, twin) -> None:
    with pytest.raises(ValueError, match="budget"):
        diagnose(planted([]).noisy, twin, options=dataclasses.replace(FAST, budget=0))


def test_one_budget_counts_every_context_of_a_diagnosis(planted, twin) -> None:
    """A context is immutable: a re-estimated null gives a new context on the same replays and the same budget,
    which counts every replay made through either (the pipeline owns the budget; no step replaces it)."""
    real = planted([]).noisy
    runner = make_runner(twin, 1)
    try:
        budget = Budget(replays=50, seconds=1e9)
        ctx = Context.build(real, CachedReplays(runner, real.commands, real.time), budget)
        assert ctx.null is None and ctx.noise is None and ctx.null_cost == 0.0
        with pytest.raises(dataclasses.FrozenInstanceError):
            ctx.names = ()  # type: ignore[misc]
        judged = ctx.with_null(calibrate(ctx, NullSpec(runs=2)))
        assert ctx.null is None  # the context it came from is untouched
        assert judged.budget is budget and judged.replays is ctx.replays and judged.noise is not None
        before = budget.spent()
        assert before == ctx.replays.runs >= 3  # the nominal replay and the null's runs
        judged.simulate([Effect.make("sensor_bias", "F31", {"bias": 1.0})])
        assert budget.spent() == ctx.replays.runs  # counted once, through the shared replays
        assert budget.left() == 50 - budget.spent()
    finally:
        runner.close()
