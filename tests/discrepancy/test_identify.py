"""Each catalogue effect planted alone at a clear magnitude is named with the right target, and its fitted
parameters recover the planted ones inside an informative interval; a null names nothing.

The catalogue is restricted to the planted effect's family and close rivals (and the fast options of conftest)
so the suite stays fast; ``test_full_catalogue`` (slow) runs the whole catalogue.
"""

from __future__ import annotations

import numpy as np
import pytest

from discrepancy import DiagnoseOptions, Effect, Scales, diagnose
from discrepancy.bench.cases import ooc_physics
from discrepancy.bench.synth import record
from discrepancy.effects import UNEXPLAINED, pi_unit
from discrepancy.search.fit import RESOLUTION
from discrepancy.search.identify import STRONG_Q, strong
from discrepancy.stats.locate import Located, LocateResult

#: effect → (target, parameters in Π, catalogue the search may choose from)
CLEAR = {
    "coulomb_friction": ("bucket_hinge", {"friction": 0.008},
                         ("coulomb_friction[bucket_hinge]", "coulomb_friction[tilt_cylinder]",
                          "viscous_damping[bucket_hinge]")),
    "viscous_damping": ("lift_cylinder", {"damping": 0.04},
                        ("viscous_damping[lift_cylinder]", "viscous_damping[boom_hinge]",
                         "coulomb_friction[lift_cylinder]")),
    "backlash": ("pin_21", {"clearance": 0.003}, ("backlash", "hydraulic_compliance[tilt_cylinder]")),
    "actuator_delay": ("tilt_cylinder", {"delay": 0.25}, ("actuator_delay", "viscous_damping[tilt_cylinder]")),
    "hydraulic_compliance": ("lift_cylinder", {"compliance": 0.01},
                             ("hydraulic_compliance", "viscous_damping[lift_cylinder]")),
    "payload_mass_error": ("payload", {"mass_error": 0.2}, ("payload_mass_error", "soil_adhesion")),
    "payload_com_offset": ("payload", {"dx": 0.04, "dz": -0.03}, ("payload_com_offset", "payload_mass_error")),
    "soil_cohesion": ("soil", {"cohesion": 0.05}, ("soil_cohesion", "soil_adhesion")),
    "soil_adhesion": ("soil", {"adhesion": 0.06}, ("soil_adhesion", "soil_cohesion")),
    "sensor_bias": ("F31", {"bias": 0.2}, ("sensor_bias", "sensor_gain", "coulomb_friction[bucket_hinge]")),
    "sensor_gain": ("Pf_lift", {"gain_error": 0.1}, ("sensor_gain", "sensor_bias", "viscous_damping[lift_cylinder]")),
    "sensor_delay": ("boom_angle", {"delay": 0.3}, ("sensor_delay", "sensor_bias", "coulomb_friction[boom_hinge]")),
}


#: Effects whose scan alone leaves a parameter imprecise, so their diagnosis runs the final fit: the payload COM's
#: vertical offset shows on the load's height, whose residual the nominal noise model calls drift (the offset lasts
#: while the bucket is loaded); the final fit, under the noise left by the named effect, recovers it.
FINAL_FIT = {"payload_com_offset": 2}


@pytest.mark.parametrize("name", list(CLEAR))
def test_effect_is_named(name: str, scales, diagnosed) -> None:
    target, pis, candidates = CLEAR[name]
    effect = Effect.from_pi(name, target, pis, scales)
    d = diagnosed([effect], candidates, FINAL_FIT.get(name, 0))
    assert d.effects, f"nothing named for {effect.label()} ({len(d.located)} located windows)"
    top = d.effects[0]
    assert top.effect == name, [e.effect for e in d.effects]
    expected = None if effect.spec.target_kind in ("payload", "soil") else target
    assert top.target == expected


#: Largest relative error of a fitted parameter (the planted magnitudes are clear; observed: ≤ 1.4 %).
RECOVERY = 0.05
#: Widest admissible interval, relative to the estimate: coverage of the planted value would mean nothing if the
#: interval spanned most of the catalogue's bounds.
WIDEST = 0.3
#: ... wider for the payload COM: its vertical offset shows on the load's height, a channel the noise model calls
#: drift-like under this offset (see FINAL_FIT), which honestly widens its interval (observed ±20 %; ±28 % since a
#: channel whose colour the record leaves undecided is widened to the largest SD its spectrum allows; ±41 % with v1).
WIDEST_FOR = {"payload_com_offset": 0.9}
#: ... and its vertical offset comes out 9 % off since v1's twin reads the soil force at the state it acts on (the
#: load's height moves a little differently over the dig), with an interval of ±41 % (above) that holds the planted
#: value.
RECOVERY_FOR = {"payload_com_offset": 0.12}


@pytest.mark.parametrize("name", list(CLEAR))
def test_fitted_parameter_brackets_the_planted_one(name: str, scales: Scales, diagnosed) -> None:
    """Every fitted parameter is within a few per cent of the planted one, and its reported interval contains the
    planted value, holds the estimate strictly inside, is at least the documented resolution (± RESOLUTION of Π)
    wide on each side and is not uninformatively wide; the reported group is the fitted value over its unit."""
    target, pis, candidates = CLEAR[name]
    effect = Effect.from_pi(name, target, pis, scales)
    top = diagnosed([effect], candidates, FINAL_FIT.get(name, 0)).effects[0]  # test_effect_is_named's (cached)
    assert top.effect == name
    assert set(top.parameters) == set(top.interval) == set(pis)
    for param, planted in effect.params.items():
        value, (lo, hi) = top.parameters[param], top.interval[param]
        assert value == pytest.approx(planted, rel=RECOVERY_FOR.get(name, RECOVERY)), (param, value, planted)
        assert lo <= planted <= hi, (param, planted, (lo, hi))
        # not degenerate: the estimate strictly inside, each side at least the resolution (2 % of Π, or of log Π)
        side = 0.95 * RESOLUTION * abs(value)
        assert lo < value - side and value + side < hi, (param, value, (lo, hi))
        assert hi - lo < WIDEST_FOR.get(name, WIDEST) * abs(value), (param, value, (lo, hi))
        unit = pi_unit(name, param, target, scales)
        assert top.groups[f"pi_{param}"] == pytest.approx(value / unit, rel=1e-12)
        assert top.groups[f"pi_{param}"] == pytest.approx(pis[param], rel=RECOVERY_FOR.get(name, RECOVERY))


def test_null_names_nothing(planted, twin) -> None:
    d = diagnose(planted([]).noisy, twin)  # the full catalogue: nothing is located, so nothing runs
    assert d.effects == [] and d.located == []
    assert d.comparison.after == d.comparison.before


@pytest.mark.slow
@pytest.mark.parametrize("name", list(CLEAR))
def test_full_catalogue(name: str, scales, planted, twin) -> None:
    target, pis, _ = CLEAR[name]
    effect = Effect.from_pi(name, target, pis, scales)
    d = diagnose(planted([effect]).noisy, twin, options=DiagnoseOptions())
    assert d.effects and d.effects[0].effect == name


@pytest.mark.slow
@pytest.mark.parametrize(("name", "size"), [
    pytest.param("soft_tilt_servo", 0.03, marks=pytest.mark.xfail(
        strict=True, reason="known (issue 14), failing since WheelLoaderDig-v1 (the twin's soil force read at the "
        "state it acts on; 6fedab8): a 3 % softer tilt servo is named as a backlash and a viscous damping before "
        "`unexplained` on this seed-11 ER12 cycle, where only `unexplained` should be")),
    pytest.param("boom_spring", 0.15, marks=pytest.mark.xfail(
        strict=True, reason="known (issue 14), failing since at least 6aab765: Coulomb friction removes more than "
        "CREDIBLE (85 %) of a 0.15 boom spring's excess on this seed-11 ER12 cycle and is named before "
        "`unexplained`, where only `unexplained` should be")),
])
def test_out_of_catalogue_is_unexplained(name: str, size: float, twin) -> None:
    """Physics the catalogue has no entry for is reported as ``unexplained``, not as its closest entry alone."""
    real = record(twin, [], 0.01, twin.seed, ooc_physics(name, size, twin))
    d = diagnose(real.noisy, twin, options=DiagnoseOptions(workers=2))
    assert d.located and d.named == [UNEXPLAINED], d.named
    assert d.effects[0].confounded_with  # the closest catalogue entries are listed, not named


def test_a_lone_short_window_that_barely_passes_is_not_strong_evidence() -> None:
    """A window of one or two steps reaches effect size 3 just by passing BH at 1 %: alone, it is strong evidence of
    missing physics only when it is significant well beyond that level (q ≤ STRONG_Q); three windows always are."""
    def result(*windows: tuple[float, float]) -> LocateResult:
        located = [Located("alpha1", "curl", 3.4, 4.2, size, q) for size, q in windows]
        return LocateResult([], ("alpha1",), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0), located)

    assert not strong(result((3.0, 0.0099)))  # the white 50 Hz null that had a damping named
    assert strong(result((3.0, 1.3e-5)))
    assert not strong(result((2.0, 1e-6)))  # a faint window, however significant, stays faint alone
    assert strong(result((1.5, 0.009), (1.5, 0.009), (1.5, 0.009)))
    assert STRONG_Q < 0.01
