"""Linkage redundancy: identities between recorded channels that physics cannot break but a faulty sensor does.

Each :class:`Identity` is a function d(signals) that is zero (or equal in real and twin) whatever the physics:
a pin force and its components (F = |(F_x, F_z)|), a cylinder force and its pressure (|Pf| = p × area), a cylinder
speed and the rate of its extension. ``gated`` lists the members whose sensor faults break it. Route-2 statics
(Newton–Euler from kinematics and applied loads) are compared too, but reported only: a torque in a hinge (friction,
damping, a spring) also separates route 1 from route 2, so a broken route-2 identity points at a sensor *or* at a
joint-space effect.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from scaletwin_envs.specs.loader import LoaderSpec

Signals = Mapping[str, np.ndarray]
BROKEN_P = 1e-4  # an identity is broken when its real-vs-twin disagreement has a p-value below this
MC_DRAWS = 64


@dataclass(frozen=True)
class Identity:
    """d(signals) that real and twin must share; ``gated``: members whose faults break it."""

    name: str
    members: tuple[str, ...]
    gated: tuple[str, ...]
    fn: Callable[[Signals, float], np.ndarray]
    algebraic: bool = True


def _pressure(cyl: str, piston: float, annulus: float) -> Callable[[Signals, float], np.ndarray]:
    def d(s: Signals, dt: float) -> np.ndarray:
        pf = s[f"Pf_{cyl}"]
        return s[f"p_{cyl}"] * np.where(pf >= 0, piston, annulus) - np.abs(pf)
    return d


def _components(pin: str) -> Callable[[Signals, float], np.ndarray]:
    return lambda s, dt: s[pin] - np.hypot(s[f"{pin}_x"], s[f"{pin}_z"])


def _rate(cyl: str) -> Callable[[Signals, float], np.ndarray]:
    return lambda s, dt: s[f"{cyl}_speed"] - np.gradient(s[f"{cyl}_extension"], dt)


def _route2(name: str) -> Callable[[Signals, float], np.ndarray]:
    return lambda s, dt: s[name] - s[f"{name}_route2"]


def identities(loader: LoaderSpec) -> list[Identity]:
    """The identities of a loader (pressure areas from its cylinders)."""
    out = [Identity(f"{p} = |({p}_x, {p}_z)|", (p, f"{p}_x", f"{p}_z"), (p, f"{p}_x", f"{p}_z"), _components(p))
           for p in ("F21", "F31")]
    for cyl in ("lift", "tilt"):
        c = getattr(loader, cyl)
        out.append(Identity(f"|Pf_{cyl}| = p_{cyl} x area", (f"Pf_{cyl}", f"p_{cyl}"), (f"Pf_{cyl}", f"p_{cyl}"),
                            _pressure(cyl, c.bore_area, c.annulus_area)))
        out.append(Identity(f"{cyl}_speed = d/dt {cyl}_extension", (f"{cyl}_speed", f"{cyl}_extension"),
                            (f"{cyl}_speed",), _rate(cyl)))
    out += [Identity(f"{n} = {n}_route2", (n, f"{n}_route2"), (n,), _route2(n), algebraic=False)
            for n in ("F21", "F31", "Pf_lift", "Pf_tilt")]
    return out


@dataclass(frozen=True)
class Check:
    """One identity checked on real vs twin: RMS of the disagreement (SI), its p-value, and the verdict."""

    identity: Identity
    rms: float
    p_value: float

    @property
    def broken(self) -> bool:
        return self.p_value < BROKEN_P

    def to_dict(self) -> dict[str, object]:
        return {"identity": self.identity.name, "algebraic": self.identity.algebraic, "rms": self.rms,
                "p_value": self.p_value, "broken": self.broken}


def check(identity: Identity, real: Signals, twin: Signals, noise: Mapping[str, float], dt: float) -> Check | None:
    """Compare d(real) with d(twin); None when a member is missing. The disagreement is scaled by the sensor
    noise carried through d (Monte Carlo, seeded)."""
    if any(m not in real or m not in twin for m in identity.members):
        return None
    d_real = identity.fn(real, dt)
    diff = d_real - identity.fn(twin, dt)
    rng = np.random.default_rng(0)
    draws = []
    for _ in range(MC_DRAWS):
        noisy = dict(real)
        for m in identity.members:
            noisy[m] = real[m] + noise.get(m, 0.0) * rng.standard_normal(real[m].shape)
        draws.append(identity.fn(noisy, dt) - d_real)
    bias = np.mean(draws, axis=0)  # e.g. the upward bias of a noisy magnitude
    diff = diff - bias
    scale = np.sqrt(np.maximum(np.mean(np.square(np.asarray(draws) - bias), axis=0), 1e-30))
    scale = np.maximum(scale, 1e-9 * (np.max(np.abs(d_real)) + 1e-30))
    stat = float(np.sum((diff / scale) ** 2))
    return Check(identity, float(np.sqrt(np.mean(diff**2))), float(stats.chi2.sf(stat, len(diff))))


def check_all(loader: LoaderSpec, real: Signals, twin: Signals, noise: Mapping[str, float], dt: float) -> list[Check]:
    return [c for i in identities(loader) if (c := check(i, real, twin, noise, dt)) is not None]


def undo_fault(effect: Any, values: np.ndarray, time: np.ndarray) -> np.ndarray:
    """What a channel read by a sensor with fault ``effect`` (bias, gain or delay) would read without it."""
    p = effect.params
    if effect.name == "sensor_bias":
        return values - p["bias"]
    if effect.name == "sensor_gain":
        return values / (1.0 + p["gain_error"])
    return np.interp(time + max(p["delay"], 0.0), time, values, right=values[-1])


def fault_admissible(effect: Any, checks: list[Check], real: Signals, twin: Signals, noise: Mapping[str, float],
                     time: np.ndarray) -> bool:
    """May a sensor fault on a channel that an intact algebraic identity guards explain it? Yes when undoing the
    fault leaves every such identity intact too: the identity cannot tell the fault from no fault (e.g. a small
    gain error on the smaller component of a pin force barely moves its magnitude). No when undoing it would
    break one: the identity holds, so the channel reads right."""
    dt = float(np.median(np.diff(time)))
    for c in checks:
        if c.identity.algebraic and not c.broken and effect.target in c.identity.gated:
            undone = dict(real)
            undone[effect.target] = undo_fault(effect, np.asarray(real[effect.target], float), time)
            again = check(c.identity, undone, twin, noise, dt)
            if again is not None and again.broken:
                return False
    return True


def sensor_suspects(checks: list[Check], located: set[str]) -> set[str]:
    """Located signals a sensor fault may explain: not gated by any algebraic identity, or gated by a broken one."""
    gated = {m for c in checks if c.identity.algebraic for m in c.identity.gated}
    broken = {m for c in checks if c.identity.algebraic and c.broken for m in c.identity.gated}
    return {s for s in located if s not in gated or s in broken}
