"""The final fit on its own: Gauss–Newton started 25 % off a planted parameter brings it back.

The fast diagnoses of ``test_identify`` run no Gauss–Newton step in the final fit (their parameters come from the
scans), so a Gauss–Newton step that went the wrong way would pass them; here
:func:`discrepancy.search.fit.fit` runs on a planted recording from a wrong start, with the pipeline's own context
(replays, null model), in a few seconds.
"""

from __future__ import annotations

import pytest

from discrepancy import Effect, NullSpec, Scales, TwinSpec
from discrepancy.context import Context
from discrepancy.search.fit import fit
from discrepancy.stats.null import calibrate
from discrepancy.twin.runner import CachedReplays, make_runner

#: effect → (target, planted Π, start Π): a physical effect (payload mass, re-simulated) and a sensor model.
CASES = {
    "payload_mass_error": ("payload", {"mass_error": 0.2}, {"mass_error": 0.25}),
    "sensor_gain": ("Pf_lift", {"gain_error": 0.1}, {"gain_error": 0.125}),
}
#: Largest relative error after two Gauss–Newton steps (observed: 1.6 % for the mass, 0.1 % for the gain).
CONVERGED = 0.025


@pytest.mark.parametrize("name", list(CASES))
def test_gauss_newton_pulls_a_wrong_start_back_to_the_planted_value(name: str, twin: TwinSpec, scales: Scales,
                                                                    planted) -> None:
    target, pis, start_pis = CASES[name]
    truth = Effect.from_pi(name, target, pis, scales)
    start = Effect.from_pi(name, target, start_pis, scales)
    real = planted([truth]).noisy  # the recording of test_identify (cached)
    runner = make_runner(twin, 1)
    try:
        ctx = Context.build(real, CachedReplays(runner, real.commands, real.time))
        # as the pipeline: judged under the noise left by the named effect
        ctx = ctx.with_null(calibrate(ctx, NullSpec(runs=3), [start]))
        cost_at_start = ctx.cost(ctx.simulate([start]))
        result = fit(ctx, [start], seed=0, iterations=2)
    finally:
        runner.close()
    (param, planted_value), = truth.params.items()
    value, (lo, hi) = result.effects[0].params[param], result.intervals[0][param]
    assert result.iterations >= 1 and result.cost_after < cost_at_start  # accepted steps, downhill
    assert value == pytest.approx(planted_value, rel=CONVERGED), (value, planted_value, start.params[param])
    assert lo <= planted_value <= hi and lo < value < hi, (planted_value, value, (lo, hi))
