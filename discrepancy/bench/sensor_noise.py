"""Sensor noise of the benchmark's synthetic field logs, drawn per case from several families.

This is the benchmark's own model of real sensors, kept apart from the tool's noise model on purpose (it imports
nothing from :mod:`discrepancy.stats`), so that the benchmark cannot be passed by assuming the tool's model.

Families (one per case, the same for every channel of that case's logs):

* ``white``: independent Gaussian samples, standard deviation ``amplitude``.
* ``ar1``: a stationary first-order autoregression (discretised Ornstein–Uhlenbeck process) with marginal standard
  deviation ``amplitude`` and lag-one autocorrelation ``rho`` *at the twin's control step*; at another log rate the
  per-sample coefficient is ``rho ** (h / control_dt)``, so the physical correlation time does not depend on the rate.
* ``drift``: a random walk (variance growing linearly in time, standard deviation ``amplitude`` after
  :data:`DRIFT_REF_S`) plus white noise of ``WHITE_SHARE × amplitude``.
* ``quantised``: the reading plus small white noise (``SMALL_WHITE × amplitude``) rounded to a grid of
  ``range / 2**bits``.
* ``lowpass``: the true signal through a first-order sensor filter (time constant ``tau`` s, exact discretisation for
  an input linear between samples, so a ramp lags by exactly ``tau`` at any rate) plus white noise ``amplitude``.

Amplitudes are fractions of each channel's range (peak to peak of the nominal signal) times that range, in the
channel's SI unit. Everything is seeded: the same :class:`NoiseSpec` and seed give the same noise.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter, lfilter_zi

FAMILIES = ("white", "ar1", "drift", "quantised", "lowpass")
#: Case noise level, fraction of a channel's range: from a good transducer on a well-used range (0.2 %) to a noisy
#: load pin on a range four times wider than the signal (3 %), log-uniform.
LEVEL_RANGE = (0.002, 0.03)
#: Per-channel spread around the case level: a factor 2**U(-0.5, 0.5) (sensors of one machine differ), clipped back
#: into :data:`LEVEL_RANGE`.
CHANNEL_OCTAVES = 0.5
#: AR(1) lag-one autocorrelation at the control step (issue 14: 0.5–0.95).
RHO_RANGE = (0.5, 0.95)
#: Reference time of the drift amplitude, s: about half a dig cycle of the ER12, so a drift of "1 % of range" has
#: moved by about that much within the cycle.
DRIFT_REF_S = 10.0
#: White noise beside the drift, as a share of the drift amplitude (drift dominates, white is still there).
WHITE_SHARE = 0.5
#: Quantisation grid: range / 2**bits with bits 7–11 (a 12-bit converter on a range 2–16× wider than the signal's),
#: i.e. steps of 0.05–0.8 % of the range.
BITS_RANGE = (7, 11)
#: White noise beside quantisation, as a share of the amplitude (small: the grid is the main effect).
SMALL_WHITE = 0.25
#: First-order sensor filter time constants, s (issue 14: 0.05–0.3 s), drawn per channel.
TAU_RANGE = (0.05, 0.3)


@dataclass(frozen=True)
class NoiseSpec:
    """One case's sensor noise: family, amplitudes (fraction of range) and family parameters per channel.

    Attributes:
        family: one of :data:`FAMILIES`.
        level: the case's noise level, fraction of range (the per-channel amplitudes scatter around it).
        amplitudes: ``(channel, fraction of range)`` pairs; channels not listed get ``level``.
        rho: AR(1) lag-one autocorrelation at the control step (``ar1`` only).
        bits: quantisation grid ``range / 2**bits`` (``quantised`` only).
        taus: ``(channel, time constant s)`` of the sensor filter (``lowpass`` only); unlisted channels get the
            middle of :data:`TAU_RANGE`.
        seed: seed of the noise realisations (a recording adds its own sub-seed).
    """

    family: str
    level: float
    amplitudes: tuple[tuple[str, float], ...] = ()
    rho: float = 0.0
    bits: int = 0
    taus: tuple[tuple[str, float], ...] = ()
    seed: int = 0

    def amplitude(self, channel: str) -> float:
        """Noise amplitude of ``channel``, fraction of its range."""
        return dict(self.amplitudes).get(channel, self.level)

    def tau(self, channel: str) -> float:
        """Sensor filter time constant of ``channel``, s."""
        return dict(self.taus).get(channel, 0.5 * sum(TAU_RANGE))

    def describe(self) -> str:
        """A short label, e.g. ``ar1(rho=0.82, 1.1 %)``."""
        par = {"ar1": f"rho={self.rho:.2f}, ", "quantised": f"{self.bits} bit, ",
               "lowpass": f"tau={np.median([t for _, t in self.taus] or [0.0]):.2f} s, "}.get(self.family, "")
        return f"{self.family}({par}{100 * self.level:.2g} %)"


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))


def draw_noise(rng: np.random.Generator, family: str, channels: Sequence[str]) -> NoiseSpec:
    """A :class:`NoiseSpec` of ``family`` for ``channels`` drawn from ``rng``.

    Raises:
        ValueError: unknown family.
    """
    if family not in FAMILIES:
        raise ValueError(f"unknown noise family {family!r}; known {FAMILIES}")
    level = _log_uniform(rng, *LEVEL_RANGE)
    lo, hi = LEVEL_RANGE
    amps = tuple((c, float(np.clip(level * 2.0 ** rng.uniform(-CHANNEL_OCTAVES, CHANNEL_OCTAVES), lo, hi)))
                 for c in channels)
    rho = float(rng.uniform(*RHO_RANGE)) if family == "ar1" else 0.0
    bits = int(rng.integers(BITS_RANGE[0], BITS_RANGE[1] + 1)) if family == "quantised" else 0
    taus = tuple((c, float(rng.uniform(*TAU_RANGE))) for c in channels) if family == "lowpass" else ()
    return NoiseSpec(family, level, amps, rho, bits, taus, int(rng.integers(0, 2**31 - 1)))


# --- generators (pure functions of an rng and sizes; each with its stated property) ------------------------------


def white(rng: np.random.Generator, n: int, sd: float) -> np.ndarray:
    """``n`` independent N(0, sd²) samples."""
    return sd * rng.standard_normal(n)


def ar1(rng: np.random.Generator, n: int, sd: float, rho: float) -> np.ndarray:
    """A stationary AR(1) series: x_k = rho x_{k−1} + e_k, marginal standard deviation ``sd`` from the first sample.

    Raises:
        ValueError: ``|rho| >= 1`` (not stationary).
    """
    if not abs(rho) < 1.0:
        raise ValueError(f"AR(1) needs |rho| < 1, got {rho}")
    e = rng.standard_normal(n) * sd * np.sqrt(1.0 - rho**2)
    if n:
        e[0] *= 1.0 / np.sqrt(1.0 - rho**2)  # x_0 ~ N(0, sd²): the stationary start
    return lfilter([1.0], [1.0, -rho], e)


def random_walk(rng: np.random.Generator, n: int, h: float, sd_ref: float, t_ref: float = DRIFT_REF_S) -> np.ndarray:
    """A random walk sampled every ``h`` s starting at 0: Var(x(t)) = sd_ref² t / t_ref (linear in time).

    Args:
        h: sampling step, s.
        sd_ref: standard deviation after ``t_ref`` seconds.
    """
    return np.cumsum(sd_ref * np.sqrt(h / t_ref) * rng.standard_normal(n))


def quantise(x: np.ndarray, step: float) -> np.ndarray:
    """``x`` rounded to the nearest multiple of ``step`` (a grid through 0)."""
    return step * np.round(np.asarray(x, float) / step)


def lowpass(x: np.ndarray, h: float, tau: float) -> np.ndarray:
    """First-order sensor filter τ dy/dt = x − y of ``x`` sampled every ``h`` s, exact for an input linear between
    samples (so the steady lag behind a ramp is exactly ``tau``); starts settled (y_0 = x_0).

    Raises:
        ValueError: non-positive ``h`` or ``tau``.
    """
    if not (h > 0 and tau > 0):
        raise ValueError(f"lowpass needs h > 0 and tau > 0, got h={h}, tau={tau}")
    x = np.asarray(x, float)
    a = float(np.exp(-h / tau))
    b = tau * (1.0 - a) / h
    num, den = [1.0 - b, b - a], [1.0, -a]  # y_k = a y_{k-1} + (1 − b) x_k + (b − a) x_{k-1}
    if len(x) == 0:
        return x.copy()
    y, _ = lfilter(num, den, x, zi=lfilter_zi(num, den) * x[0])  # settled on x_0: y_0 = x_0
    return y


def channel_range(values: np.ndarray) -> float:
    """Range of a channel (peak to peak, its SI unit); floored for a constant channel (1e-3 of its magnitude, or
    1e-12) so that a noise "fraction of range" stays defined."""
    v = np.asarray(values, float)
    ptp = float(np.nanmax(v) - np.nanmin(v)) if v.size else 0.0
    return ptp if ptp > 0 else max(1e-3 * abs(float(np.nanmean(v))) if v.size else 0.0, 1e-12)


@dataclass
class Noisy:
    """Measured channels and what the noise did: ``sensor`` is the sensor's reading before additive noise (the truth,
    or the filtered truth for ``lowpass``), ``noise`` the rest (measured − sensor)."""

    measured: dict[str, np.ndarray]
    sensor: dict[str, np.ndarray]
    noise: dict[str, np.ndarray]


def apply_noise(spec: NoiseSpec, truth: Mapping[str, np.ndarray], h: float, control_dt: float,
                ranges: Mapping[str, float], sub_seed: int = 0, fine: Mapping[str, np.ndarray] | None = None,
                parts: int = 1) -> Noisy:
    """``truth`` (SI channels sampled every ``h`` s) as the sensors of ``spec`` would log it.

    Args:
        spec: the case's noise.
        truth: channel → true signal at the log's rate.
        h: log sampling step, s.
        control_dt: the twin's control step, s (the step at which ``spec.rho`` is the lag-one autocorrelation).
        ranges: channel → range in its SI unit (amplitudes are fractions of it).
        sub_seed: distinguishes the recordings of one case (analysed, held out).
        fine: the same channels at ``parts`` instants per log step, the last of each group at the log's sample
            (``LogData.fine``): a sensor filter acts on those, the signal between the samples.
    """
    measured, sensor, noise = {}, {}, {}
    for j, (name, x) in enumerate(sorted(truth.items())):
        rng = np.random.default_rng([spec.seed, sub_seed, j])
        x = np.asarray(x, float)
        n, rng_ = len(x), ranges.get(name) or channel_range(x)
        sd = spec.amplitude(name) * rng_
        s = x
        if spec.family == "white":
            y = x + white(rng, n, sd)
        elif spec.family == "ar1":
            y = x + ar1(rng, n, sd, spec.rho ** (h / control_dt))
        elif spec.family == "drift":
            y = x + random_walk(rng, n, h, sd) + white(rng, n, WHITE_SHARE * sd)
        elif spec.family == "quantised":
            y = quantise(x + white(rng, n, SMALL_WHITE * sd), rng_ / 2.0**spec.bits)
        elif spec.family == "lowpass":
            s = (lowpass(np.asarray(fine[name], float), h / parts, spec.tau(name))[parts - 1::parts]
                 if fine is not None and name in fine else lowpass(x, h, spec.tau(name)))
            y = s + white(rng, n, sd)
        else:
            raise ValueError(f"unknown noise family {spec.family!r}; known {FAMILIES}")
        measured[name], sensor[name], noise[name] = y, s, y - s
    return Noisy(measured, sensor, noise)
