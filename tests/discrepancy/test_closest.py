"""A lone catalogue effect that leaves an unexplained rest is named only when it removed most of the excess."""

from __future__ import annotations

from discrepancy import Effect
from discrepancy.search.identify import CREDIBLE, Identification, Round, only_closest


def _identification(gains: list[float], accepted: int) -> Identification:
    rounds = [Round(base_cost=0.0, trials=[], winner=None, confounded=[], confidence=1.0, gain_fraction=g)
              for g in gains]
    effect = Effect.make("viscous_damping", "boom_hinge", {"damping": 100.0})  # N·m·s/rad
    return Identification(effects=[effect] * accepted, rounds=rounds, unexplained=True)


def test_partial_lone_effect_is_only_the_closest() -> None:
    assert only_closest(_identification([0.6, 0.04], 1), cut=None)
    assert only_closest(_identification([CREDIBLE - 1e-3, 0.04], 1), cut=None)


def test_lone_effect_that_removed_most_is_kept() -> None:
    assert not only_closest(_identification([CREDIBLE, 0.04], 1), cut=None)


def test_two_effects_and_cut_searches_are_kept() -> None:
    assert not only_closest(_identification([0.6, 0.5, 0.02], 2), cut=None)  # e.g. two real effects, each partial
    assert not only_closest(_identification([0.6], 1), cut="replays")  # the rest was never searched
    assert not only_closest(_identification([0.6], 1), cut="time")
