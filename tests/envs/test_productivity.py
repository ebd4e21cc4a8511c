"""Published productivity figures: the handbook formula reproduces a published worked example, the band applies the
published cycle times and fill factors, Froude-scaled with the boom, and bad input is refused."""

from __future__ import annotations

import math

import pytest

from scaletwin_envs.productivity import (
    CYCLE_S,
    FILL_FACTOR,
    JOB_HOUR,
    REFERENCE_BOOM_M,
    hourly_production,
    productivity_band,
)

YD3 = 0.764554858  # m³ per cubic yard


def test_formula_reproduces_the_published_truck_count() -> None:
    """Construction Equipment (2010): a 3 yd³ loader on a 30 s cycle, 50 working minutes an hour, fills 133 trucks
    of 9 yd³ in a 4-hour morning (volume rate: density 1)."""
    per_hour = hourly_production(3 * YD3, 1.0, 1.0, 30.0, JOB_HOUR)  # m³/h
    assert 4 * per_hour / (9 * YD3) == pytest.approx(133.3, abs=0.1)


def test_band_applies_the_published_inputs_at_the_reference_size() -> None:
    band = productivity_band(2.0, 1800.0, REFERENCE_BOOM_M)
    assert band.cycle_s == pytest.approx(CYCLE_S)
    assert band.low == pytest.approx(1.8 * 2.0 * FILL_FACTOR[0] * 3600 / CYCLE_S[1])
    assert band.high == pytest.approx(1.8 * 2.0 * FILL_FACTOR[1] * 3600 / CYCLE_S[0])
    assert band.position(band.low * 0.99) == "below" and band.position(band.high * 1.01) == "above"
    assert band.position(math.sqrt(band.low * band.high)) == "inside"


def test_band_is_froude_scaled_with_the_boom() -> None:
    """Four times the boom: cycles twice as long in seconds, the same in Froude times."""
    ref = productivity_band(1.0, 1500.0, REFERENCE_BOOM_M)
    big = productivity_band(1.0, 1500.0, 4 * REFERENCE_BOOM_M)
    assert big.cycle_s == pytest.approx(tuple(2 * c for c in ref.cycle_s))
    assert big.cycle_froude == pytest.approx(ref.cycle_froude)
    assert big.high == pytest.approx(ref.high / 2)


@pytest.mark.parametrize("args", [(0.0, 1.0, 1.0, 30.0), (1.0, -1.0, 1.0, 30.0), (1.0, 1.0, 1.0, math.nan)])
def test_bad_input_is_refused(args: tuple[float, ...]) -> None:
    with pytest.raises(ValueError, match="positive finite"):
        hourly_production(*args)
    with pytest.raises(ValueError, match="boom_m"):
        productivity_band(1.0, 1500.0, 0.0)
