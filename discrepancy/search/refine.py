"""Fitting one physics candidate's parameters by re-simulating the twin: screening on the catalogue grid, then
refinement. Searches run in lockstep and hand their proposals over in batches, so a pool of workers can replay
them in parallel.

* :class:`ZoomSearch` (one parameter, in log Π when positive): a bracket around the best grid point halves
  around the best point each round; a parabola ends it.
* :class:`DelaySearch` (dead times): zooms on kinematic channels and on the full objective, then fine scans.
* :class:`GaussNewtonSearch` (several parameters: the payload's centre of mass): finite-difference Jacobian of
  the whitened residual, a damped Gauss–Newton step and a halved step.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from discrepancy.context import huber
from discrepancy.effects import Scales
from discrepancy.search.candidates import Candidate

ZOOM_ROUNDS = 3
GN_ROUNDS = 3
#: Smooth kinematic channels on which a dead time shows as a clean lag (forces right after a valve switch are
#: fragile samples of stiff transients, so the delay is bracketed on these first).
KINEMATIC = ("lift_extension", "tilt_extension", "boom_angle", "bucket_pitch")
#: Fine delay scan around the kinematic optimum, in 1/100 of the control step; then a finer one around the best.
FINE_STEPS = (-25.0, -18.0, -12.0, -8.0, -5.0, -3.0, -2.0, -1.0, 1.0, 2.0, 3.0, 5.0, 8.0, 12.0, 18.0, 25.0)
FINER_STEPS = (-0.5, -0.25, 0.25, 0.5)


class Search(Protocol):
    """A fit of one candidate: propose points (u), learn their objective values, report the best."""

    candidate: Candidate

    def propose(self) -> list[np.ndarray]: ...

    def update(self, points: list[np.ndarray], costs: list[float], z: list[np.ndarray]) -> None: ...

    def vertex(self) -> np.ndarray: ...

    @property
    def best(self) -> tuple[np.ndarray, float]: ...


@dataclass
class _Tracked:
    candidate: Candidate
    bounds: np.ndarray
    seen: list[tuple[np.ndarray, float]] = field(default_factory=list)
    rounds: int = 0

    def record(self, points: list[np.ndarray], costs: list[float]) -> None:
        self.seen.extend(zip(points, costs, strict=True))

    @property
    def best(self) -> tuple[np.ndarray, float]:
        return _lowest(self.seen)

    def vertex(self) -> np.ndarray:
        """The refined estimate (the best point seen unless a strategy interpolates)."""
        return self.best[0]


def _lowest(entries: Sequence[tuple[np.ndarray, float]]) -> tuple[np.ndarray, float]:
    u, c = min(entries, key=lambda s: s[1])
    return u.copy(), float(c)


def _bracket(entries: Sequence[tuple[np.ndarray, float]], bounds: np.ndarray) -> list[np.ndarray]:
    """The midpoints between the best 1-D point of ``entries`` and its neighbours (or the bounds)."""
    pts = sorted(entries, key=lambda s: float(s[0][0]))
    xs = [float(p[0][0]) for p in pts]
    k = int(np.argmin([p[1] for p in pts]))
    lo = xs[k - 1] if k > 0 else bounds[0, 0]
    hi = xs[k + 1] if k < len(xs) - 1 else bounds[0, 1]
    return [np.array([0.5 * (lo + xs[k])]), np.array([0.5 * (xs[k] + hi)])]


class ZoomSearch(_Tracked):
    """1-D bracket zoom in log Π (see module docstring)."""

    def propose(self) -> list[np.ndarray]:
        return _bracket(self.seen, self.bounds) if self.rounds < ZOOM_ROUNDS else []

    def update(self, points: list[np.ndarray], costs: list[float], z: list[np.ndarray]) -> None:
        self.record(points, costs)
        self.rounds += 1

    def vertex(self) -> np.ndarray:
        """Vertex of the parabola through the best point and its neighbours (the best point if none)."""
        u, _ = _lowest(self.seen)
        pts = sorted(self.seen, key=lambda s: float(s[0][0]))
        xs, cs = np.array([float(p[0][0]) for p in pts]), np.array([p[1] for p in pts])
        k = int(np.argmin(cs))
        if 0 < k < len(xs) - 1:
            x0, x1, x2 = xs[k - 1:k + 2]
            c0, c1, c2 = cs[k - 1:k + 2]
            denom = (x1 - x0) * (c1 - c2) - (x1 - x2) * (c1 - c0)
            if abs(denom) > 1e-12:
                xv = x1 - 0.5 * ((x1 - x0) ** 2 * (c1 - c2) - (x1 - x2) ** 2 * (c1 - c0)) / denom
                if x0 < xv < x2:
                    return np.array([xv])
        return u


class DelaySearch(ZoomSearch):
    """Dead time: bracket zooms in lockstep on the kinematic channels (a smooth bowl where they show the delay) and
    on the full objective (V-shaped, sharp tip: samples just after a delayed valve switch; it sees delays the
    kinematic channels barely show), then fine scans of the full objective around its best point."""

    focus: np.ndarray
    control_dt: float
    froude_time: float

    def configure(self, focus: np.ndarray, control_dt: float, froude_time: float,
                  screened: Sequence[tuple[np.ndarray, float, np.ndarray]]) -> None:
        self.focus, self.control_dt, self.froude_time = focus, control_dt, froude_time
        self.screened = list(self.seen)  # full objective at the grid points
        self.seen = [(u, self._focus_cost(z)) for u, _, z in screened]  # kinematic objective, for the zoom
        self.full: list[tuple[np.ndarray, float]] = []  # full objective of the fine scans
        self.fine = 0

    def _focus_cost(self, z: np.ndarray) -> float:
        """Objective on the kinematic channels, each with its mean residual removed: a sensor bias on one of them
        would otherwise drag the bracket (at the true delay only the bias and noise are left either way)."""
        if not z.size:
            return float("inf")
        zf = z[:, self.focus]
        return float(np.sum(huber(zf - np.nanmean(zf, axis=0))))

    def propose(self) -> list[np.ndarray]:
        if self.rounds < ZOOM_ROUNDS:  # two brackets: kinematic channels, and the full objective (sharp, V-shaped)
            kinematic = super().propose()
            full = [u for u in _bracket(self.full + self.screened, self.bounds)
                    if all(abs(float(u[0]) - float(k[0])) > 1e-9 for k in kinematic)]
            return kinematic + full
        if self.fine >= 2:
            return []
        center = float(np.exp(_lowest(self.full + self.screened)[0][0]))
        step = self.control_dt / 100.0 / self.froude_time
        offsets = FINE_STEPS if self.fine == 0 else FINER_STEPS
        pts = [center] if self.fine == 0 else []
        pts += [center + k * step for k in offsets if center + k * step > 0]
        lo, hi = self.bounds[0]
        return [np.array([np.clip(np.log(p), lo, hi)]) for p in pts]

    def update(self, points: list[np.ndarray], costs: list[float], z: list[np.ndarray]) -> None:
        self.full.extend(zip(points, costs, strict=True))
        if self.rounds < ZOOM_ROUNDS:
            self.record(points, [self._focus_cost(zz) for zz in z])
            self.rounds += 1
        else:
            self.fine += 1

    @property
    def best(self) -> tuple[np.ndarray, float]:
        """Best full objective seen (fine scans and grid); the kinematic zoom only guides the scans."""
        return _lowest(self.full + self.screened)

    def vertex(self) -> np.ndarray:
        return self.best[0]


class GaussNewtonSearch(_Tracked):
    """Damped Gauss–Newton on the whitened residual with finite differences (see module docstring)."""

    step: float = 0.01
    _z: dict[bytes, np.ndarray]

    def __post_init__(self) -> None:
        self._z = {}
        self._phase = "jacobian"
        self._center: np.ndarray | None = None
        self._delta: np.ndarray | None = None

    def propose(self) -> list[np.ndarray]:
        if self.rounds >= GN_ROUNDS:
            return []
        u, _ = self.best
        if self._phase == "jacobian":
            self._center = u
            return [u + self.step * e for e in np.eye(len(u))]
        assert self._delta is not None
        return [np.clip(u + f * self._delta, self.bounds[:, 0], self.bounds[:, 1]) for f in (1.0, 0.5)]

    def update(self, points: list[np.ndarray], costs: list[float], z: list[np.ndarray]) -> None:
        self.record(points, costs)
        for p, zz in zip(points, z, strict=True):
            self._z[p.tobytes()] = zz
        if self._phase == "jacobian":
            assert self._center is not None
            z0 = self._z.get(self._center.tobytes())
            if z0 is None:  # center not simulated with its residual: nothing to linearise
                self.rounds = GN_ROUNDS
                return
            jac = np.stack([(self._z[p.tobytes()] - z0).ravel() / self.step for p in points], axis=1)
            lam = 1e-6 * np.trace(jac.T @ jac) + 1e-12
            self._delta = np.linalg.solve(jac.T @ jac + lam * np.eye(jac.shape[1]), -jac.T @ z0.ravel())
            self._phase = "line"
        else:
            self._phase = "jacobian"
            self.rounds += 1


def make_search(candidate: Candidate, scales: Scales, seen: Sequence[tuple[np.ndarray, float, np.ndarray]],
                names: Sequence[str] = (), control_dt: float = 0.1) -> Search:
    """The search strategy for ``candidate``, seeded with its screening points (u, objective, residual)."""
    bounds = candidate.bounds(scales)
    if candidate.name == "actuator_delay" and all(k in names for k in KINEMATIC):
        ds = DelaySearch(candidate, bounds, [(u, c) for u, c, _ in seen])
        ds.configure(np.array([list(names).index(k) for k in KINEMATIC]), control_dt, scales.froude_time, seen)
        return ds
    if len(candidate.spec.params) == 1:  # 1-D: a bracket zoom is robust to the objective's jumps
        s: Search = ZoomSearch(candidate, bounds, [(u, c) for u, c, _ in seen])
    else:
        gn = GaussNewtonSearch(candidate, bounds, [(u, c) for u, c, _ in seen])
        gn.__post_init__()
        gn.step = 0.01 * float(np.max(np.abs(bounds)))
        for u, _, z in seen:
            gn._z[u.tobytes()] = z
        s = gn
    return s


Evaluator = Callable[[list[tuple[Candidate, np.ndarray]]], list[tuple[float, np.ndarray]]]


def run_searches(searches: list[Search], evaluate: Evaluator, stop: Callable[[], bool] = lambda: False) -> None:
    """Advance all searches in lockstep; ``evaluate`` simulates a batch of (candidate, u) → (objective, z). Before
    each batch ``stop()`` may end them all (the budget): each keeps the best point it has seen."""
    while True:
        batch = [(s, p) for s in searches for p in s.propose()]
        if not batch or stop():
            return
        results = evaluate([(s.candidate, p) for s, p in batch])
        for s in searches:
            mine = [(p, r) for (t, p), r in zip(batch, results, strict=True) if t is s]
            if mine:
                s.update([p for p, _ in mine], [res[0] for _, res in mine], [res[1] for _, res in mine])
