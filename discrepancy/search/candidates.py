"""Physics candidates: a catalogue effect at one target, with its search space (u = log Π, or Π when signed),
bounds and screening grid. Sensor faults are not among them (they are fitted in closed form,
:mod:`discrepancy.search.sensors`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from discrepancy.effects import CATALOGUE, JOINTS, Effect, EffectSpec, Scales, pi_unit
from discrepancy.twin.env import MAX_DELAY


@dataclass(frozen=True)
class Candidate:
    """A catalogue effect at one target, searched in u = log Π (log parameters) or u = Π."""

    name: str
    target: str | None

    @property
    def spec(self) -> EffectSpec:
        return CATALOGUE[self.name]

    @property
    def log(self) -> bool:
        return all(p.log for p in self.spec.params)

    def bounds(self, scales: Scales) -> np.ndarray:
        """(params, 2) bounds in u."""
        rows = []
        for p in self.spec.params:
            lo, hi = p.bounds
            if self.name in ("soil_cohesion", "soil_adhesion"):  # the soil's own term cannot go below zero
                lo = -getattr(scales, self.name.removeprefix("soil_")) / pi_unit(self.name, p.name, None, scales)
            if self.name == "actuator_delay":  # no longer than the twin's valves can hold (a large machine's
                hi = min(hi, MAX_DELAY / pi_unit(self.name, p.name, self.target, scales))  # 1.2 √(L/g) is more)
            rows.append((np.log(max(lo, 1e-12)), np.log(hi)) if p.log else (lo, hi))
        return np.array(rows, dtype=float)

    def grid(self) -> list[np.ndarray]:
        """Screening points in u."""
        params = self.spec.params
        if len(params) == 1:
            return [np.array([np.log(g) if params[0].log else g]) for g in params[0].grid]
        pts = []
        for i, p in enumerate(params):  # along each axis
            for g in p.grid:
                u = np.zeros(len(params))
                u[i] = g
                pts.append(u)
        return pts

    def effect(self, u: np.ndarray, scales: Scales) -> Effect:
        pis = {p.name: float(np.exp(v) if p.log else v) for p, v in zip(self.spec.params, u, strict=True)}
        return Effect.from_pi(self.name, self.target, pis, scales)

    def label(self) -> str:
        return f"{self.name}[{self.target}]" if self.target else self.name


def physics_candidates() -> list[Candidate]:
    """Every simulated catalogue candidate (sensor faults are fitted in closed form elsewhere)."""
    out = []
    for spec in CATALOGUE.values():
        if spec.plant == "sensor":
            continue
        targets = spec.targets if spec.target_kind in ("joint", "cylinder", "pin") else (spec.targets[0],)
        out.extend(Candidate(spec.name, t) for t in targets)
    assert {c.target for c in out if c.name == "coulomb_friction"} == set(JOINTS)
    return out
