"""A sensor fault on a channel that an intact identity guards is admitted only when the identity cannot tell it
from no fault (undoing it leaves the identity intact too)."""

from __future__ import annotations

import numpy as np

from discrepancy import Effect
from discrepancy.stats.redundancy import Check, Identity, _components, check, fault_admissible


def _signals(fz_gain: float = 1.0) -> dict[str, np.ndarray]:
    t = np.linspace(0.0, 20.0, 201)
    fx = 1e5 * (1.5 + np.sin(0.3 * t))
    fz = 2e4 * (1.0 + 0.5 * np.cos(0.5 * t))
    return {"F31": np.hypot(fx, fz), "F31_x": fx, "F31_z": fz * fz_gain}


def _setup(real: dict[str, np.ndarray]) -> tuple[list[Check], dict[str, float], np.ndarray]:
    ident = Identity("F31 = |(F31_x, F31_z)|", ("F31", "F31_x", "F31_z"), ("F31", "F31_x", "F31_z"),
                     _components("F31"))
    noise = {k: 0.01 * float(np.std(v)) for k, v in real.items()}
    c = check(ident, real, _signals(), noise, 0.1)
    assert c is not None
    return [c], noise, np.linspace(0.0, 20.0, 201)


def test_undetectable_gain_on_a_guarded_component_is_admitted() -> None:
    real = _signals(fz_gain=0.95)  # a −5 % gain on the smaller component: the magnitude barely moves
    checks, noise, time = _setup(real)
    assert not checks[0].broken
    fault = Effect.make("sensor_gain", "F31_z", {"gain_error": -0.05})
    assert fault_admissible(fault, checks, real, _signals(), noise, time)


def test_fault_the_identity_would_see_is_refused() -> None:
    real = _signals()
    checks, noise, time = _setup(real)
    assert not checks[0].broken
    fault = Effect.make("sensor_bias", "F31", {"bias": 0.2 * float(np.std(real["F31"]))})
    assert not fault_admissible(fault, checks, real, _signals(), noise, time)
