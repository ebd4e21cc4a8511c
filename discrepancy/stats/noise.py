"""What residual the twin would leave if it were right: sensor noise (white or coloured) plus the twin's own spread.

Sensor noise
    Real transducers are filtered, drift and are quantised, so their noise is coloured. Each channel's noise is
    modelled as a white part (electronics, quantisation) plus an AR(1) part (filtered noise; drift is its ρ → 1
    limit), ``n = w + c``, ``c_t = ρ c_{t-1} + η_t``. The three numbers (ρ, σ_c, σ_w) are estimated per channel
    from the variances of the 1st–4th differences of the real-minus-twin residual (:func:`estimate_channel`):
    differences remove slow discrepancies (what the analysis looks for), and their variances are trimmed of
    outliers (steps of a discrepancy, fragile samples). Differences of order d of a white process have variance
    C(2d, d)·σ_w², those of the AR(1) part ``σ_c² f_d(ρ)``; white and random-walk-like noise differ in the ratios
    of these variances (3 and 2 for the 2nd over the 1st).

Whitening
    The residual of each channel is replaced by its one-step prediction errors under that noise model (the Kalman
    filter of the state-space model above, time-varying from the first sample), divided by their standard
    deviation: white noise passes unchanged, coloured noise comes out white, and a discrepancy comes out as what
    the noise model cannot predict. That is the price of honesty under coloured noise: a slow discrepancy on a
    channel with strongly drifting noise is seen only through its changes.

Twin spread
    Repeated twin runs with small seeded perturbations (:class:`NullSpec`: tiny friction in every joint, payload
    mass, start pose and pile): some moments of a dig cycle (relief valves opening, the bucket stalling, the
    reversal jerk) react strongly to anything, and residuals there mean little. The runs' deviations pass through
    the same whitening filter; their RMS (widened by ±1 step) adds to the innovation variance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from discrepancy.effects import JOINTS, Scales, pi_unit
from discrepancy.twin.env import PhysicsParams
from discrepancy.twin.plant import Plan

MAD_TO_SD = 1.4826
NOISE_FLOOR = 1e-4  # sensor noise is at least this fraction of the signal's spread (a noiseless channel)
TRIM = 3.5  # differences beyond this many robust deviations are discrepancy steps or fragile samples, not noise
#: ρ searched on this grid: dense near 1, where drift lives (1 − ρ from 0.7 down to 1e-3).
RHO_GRID = np.concatenate([np.linspace(0.0, 0.3, 7)[1:], 1.0 - np.logspace(np.log10(0.7), -3.0, 40)])
QUIET_EVIDENCE = 3.0  # ... and at least this much in the quieter half of the record (fewer segments)
SEGMENT = 32  # control steps per spectral segment (3.2 s at ER12: several per dig phase)
TAPER = 0.2  # fraction of the record in the cosine tapers at its ends
COLOUR_EVIDENCE = 10.0  # log-likelihood gain needed to call a channel coloured (white noise exceeds it 1 in 20 000)
CONVERGED = 1e-9  # relative change of the Kalman gain below which the filter is in steady state


@dataclass(frozen=True)
class NullSpec:
    """Repeated perturbed twin runs: how many, how large (relative), seed."""

    runs: int = 8
    size: float = 3e-4
    seed: int = 0

    def plans(self, scales: Scales) -> list[Plan]:
        """One perturbed twin per run (no structure change)."""
        out = []
        for k in range(self.runs):
            rng = np.random.default_rng([self.seed, k])
            friction = {j: abs(rng.normal()) * self.size * pi_unit("coulomb_friction", "friction", j, scales)
                        for j in JOINTS}
            physics = PhysicsParams(frictionloss=friction, payload_mass_factor=1.0 + self.size * rng.normal(),
                                    jitter=0.1 * self.size, jitter_seed=int(rng.integers(2**31)))
            out.append(Plan(physics=physics))
        return out


@dataclass(frozen=True)
class ChannelNoise:
    """Noise of one channel: white SD, AR(1) coefficient and marginal SD of the coloured part (signal units)."""

    white: float
    rho: float = 0.0
    coloured: float = 0.0

    @property
    def sd(self) -> float:
        """Marginal standard deviation of the noise."""
        return float(np.hypot(self.white, self.coloured))

    def sample(self, rng: np.random.Generator, steps: int) -> np.ndarray:
        """A noise realisation of ``steps`` samples (stationary from the first)."""
        out = self.white * rng.standard_normal(steps)
        if self.coloured > 0.0:
            eta = self.coloured * np.sqrt(1.0 - self.rho**2) * rng.standard_normal(steps)
            c0 = self.coloured * rng.standard_normal()
            c, _ = signal.lfilter([1.0], [1.0, -self.rho], eta, zi=[self.rho * c0])
            out += c
        return out


def robust_clip(x: np.ndarray) -> np.ndarray:
    """``x`` (1-D) with values beyond :data:`TRIM` robust deviations of its median clipped to that bound."""
    center = float(np.median(x))
    robust = MAD_TO_SD * float(np.median(np.abs(x - center)))
    bound = TRIM * max(robust, 1e-300)
    return np.clip(x, center - bound, center + bound)


def _whittle_fit(periodogram: np.ndarray, omega: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, ...]:
    """Whittle fit of the differenced AR(1) + white spectrum at every ``rho``: (loglik, σ_w², σ_η²) per ρ.

    Given ρ the spectrum is linear in (σ_w², σ_η²): S = σ_w² a + σ_η² b, a = 2(1 − cos ω),
    b = a / (1 − 2ρ cos ω + ρ²); the Whittle likelihood is maximised by iteratively reweighted least squares
    (weights 1/S², non-negative parameters).
    """
    a = 2.0 * (1.0 - np.cos(omega))[None, :]
    b = a / (1.0 - 2.0 * rho[:, None] * np.cos(omega)[None, :] + rho[:, None] ** 2)
    i = periodogram[None, :]
    w2 = np.full(len(rho), float(np.mean(periodogram / a[0])))
    e2 = np.zeros(len(rho))
    for _ in range(6):
        s = np.maximum(w2[:, None] * a + e2[:, None] * b, 1e-300)
        wt = 1.0 / s**2
        saa, sbb, sab = np.sum(wt * a * a, 1), np.sum(wt * b * b, 1), np.sum(wt * a * b, 1)
        sai, sbi = np.sum(wt * a * i, 1), np.sum(wt * b * i, 1)
        det = saa * sbb - sab * sab
        w_new = np.where(det > 0, (sbb * sai - sab * sbi) / np.maximum(det, 1e-300), sai / saa)
        e_new = np.where(det > 0, (saa * sbi - sab * sai) / np.maximum(det, 1e-300), 0.0)
        only_w = (w_new < 0) | (e_new < 0)  # one of them at zero: fit the other alone
        w_alone, e_alone = sai / saa, sbi / sbb
        s_w = np.sum(np.log(np.maximum(w_alone[:, None] * a, 1e-300)) + i / np.maximum(w_alone[:, None] * a, 1e-300), 1)
        s_e = np.sum(np.log(np.maximum(e_alone[:, None] * b, 1e-300)) + i / np.maximum(e_alone[:, None] * b, 1e-300), 1)
        w2 = np.where(only_w, np.where(s_w <= s_e, w_alone, 0.0), w_new)
        e2 = np.where(only_w, np.where(s_w <= s_e, 0.0, e_alone), e_new)
    s = np.maximum(w2[:, None] * a + e2[:, None] * b, 1e-300)
    return -np.sum(np.log(s) + i / s, axis=1), w2, e2


def median_spectrum(d: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, np.ndarray, float]:
    """Median over overlapping tapered segments of the periodogram of ``d`` (median-Welch): (ω, spectrum, weight).

    Sensor noise is stationary, a discrepancy is not (it shows where the physics it stands for acts): the median
    over segments follows the noise and ignores the few segments a discrepancy dominates. The median of an
    exponential periodogram ordinate is ln 2 of its mean, hence the correction. ``weight``: the number of
    independent ordinates each value stands for (the median of K segments is worth about 0.64 K means; half-
    overlapping segments about 0.7 of an independent one), which scales the log-likelihood. Then the mean spectrum
    of the quieter half of the segments and its weight: the shape of the noise where no discrepancy acts."""
    n = len(d)
    length = min(SEGMENT, n)
    starts = range(0, n - length + 1, max(length // 2, 1))
    taper = signal.windows.tukey(length, TAPER)
    norm = float(np.sum(taper**2))
    segments = np.stack([np.abs(np.fft.rfft((d[i:i + length] - d[i:i + length].mean()) * taper)) ** 2 / norm
                         for i in starts])
    k = np.arange(1, (length + 1) // 2)  # without 0 and Nyquist
    spectrum = np.median(segments[:, k], axis=0) / (np.log(2.0) if len(segments) > 2 else 1.0)
    weight = max(1.0, 0.64 * 0.7 * len(segments)) if len(segments) > 2 else float(len(segments))
    quiet = np.argsort(segments[:, k].sum(axis=1))[: max(1, len(segments) // 2)]  # the quieter half
    return 2.0 * np.pi * k / length, spectrum, weight, segments[quiet][:, k].mean(axis=0), 0.7 * len(quiet)


def estimate_channel(residual: np.ndarray, floor: float) -> ChannelNoise:
    """(ρ, σ_c, σ_w) of one channel: a Whittle fit of AR(1) + white to the median-Welch spectrum of the residual's
    first differences, clipped at :data:`TRIM` robust deviations (see the module). The coloured part is kept only
    when it raises the likelihood beyond :data:`COLOUR_EVIDENCE` over white alone.

    Args:
        residual: (steps,) real minus twin, signal units.
        floor: smallest white SD accepted (signal units).
    """
    d = np.diff(residual)
    if len(d) < 8 or not np.all(np.isfinite(d)):
        return ChannelNoise(floor)
    omega, spectrum, weight, quiet, quiet_weight = median_spectrum(robust_clip(d))
    if len(omega) < 4 or not np.any(spectrum > 0):
        return ChannelNoise(floor)
    white_ll, white_w2, white_e2 = _whittle_fit(spectrum, omega, np.array([0.0]))  # ρ = 0: all white
    white = max(float(np.sqrt(white_w2[0] + white_e2[0])), floor)
    loglik, w2, e2 = _whittle_fit(spectrum, omega, RHO_GRID)
    best = int(np.argmax(loglik))
    if weight * float(loglik[best] - white_ll[0]) < COLOUR_EVIDENCE or e2[best] <= 0.0:
        return ChannelNoise(white)
    # stationary noise is coloured in the quiet segments too; a discrepancy that lasts through most of the record
    # (a load's offset) colours the median but not the segments before it acts
    quiet_white, _, _ = _whittle_fit(quiet, omega, np.array([0.0]))
    quiet_ll, _, _ = _whittle_fit(quiet, omega, RHO_GRID)
    if quiet_weight * float(np.max(quiet_ll) - quiet_white[0]) < QUIET_EVIDENCE:
        return ChannelNoise(white)
    rho = float(RHO_GRID[best])
    coloured = float(np.sqrt(e2[best] / (1.0 - rho**2)))
    return ChannelNoise(max(float(np.sqrt(w2[best])), floor), rho, coloured)


def sensor_noise(residual: np.ndarray, spread: np.ndarray, twin: np.ndarray | None = None) -> list[ChannelNoise]:
    """The noise model of every column of ``residual`` (steps, signals); white SD floored by ``spread`` ×
    :data:`NOISE_FLOOR`.

    With ``twin`` (steps, signals, the twin's signals the residual is taken against), what the twin's own signal,
    its rate of change and a constant explain in each column is removed first: a gain, bias or delay on a channel
    is a discrepancy, not noise (left in, a gain on a pressure with sharp relief steps reads as drift, and the
    whitening would then hide the very gain)."""
    if twin is not None:
        residual = _unexplained_by(residual, twin)
    return [estimate_channel(residual[:, j], NOISE_FLOOR * float(spread[j])) for j in range(residual.shape[1])]


def _unexplained_by(residual: np.ndarray, twin: np.ndarray) -> np.ndarray:
    """Per column, ``residual`` less its least-squares fit on (1, twin, d twin / dstep)."""
    out = residual.copy()
    for j in range(residual.shape[1]):
        x = np.nan_to_num(twin[:, j])
        design = np.stack([np.ones(len(x)), x, np.gradient(x)], axis=1)
        scale = np.maximum(np.abs(design).max(axis=0), 1e-300)
        coef, *_ = np.linalg.lstsq(design / scale, residual[:, j], rcond=None)
        out[:, j] = residual[:, j] - (design / scale) @ coef
    return out


@dataclass
class Whitener:
    """The one-step prediction-error filter of a set of channels (time-varying Kalman gain from the first sample).

    ``apply(x)`` maps a (steps, channels) residual to its prediction errors (same units); their variance under the
    noise model is ``variance`` (steps, channels).
    """

    channels: list[ChannelNoise]
    steps: int
    gain: np.ndarray = field(init=False)  # (steps, channels)
    variance: np.ndarray = field(init=False)  # (steps, channels), innovation variance
    settled: int = field(init=False)  # first step from which the gain is constant
    _rho: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        rho = np.array([c.rho for c in self.channels])
        c2 = np.array([c.coloured**2 for c in self.channels])
        w2 = np.array([c.white**2 for c in self.channels])
        q = c2 * (1.0 - rho**2)
        gain, var = np.zeros((self.steps, len(rho))), np.zeros((self.steps, len(rho)))
        prior = c2.copy()  # the coloured part is stationary from the start
        self.settled = self.steps
        for t in range(self.steps):
            s = prior + w2
            k = np.where(s > 0.0, prior / np.maximum(s, 1e-300), 0.0)
            gain[t], var[t] = k, s
            if t and np.all(np.abs(k - gain[t - 1]) <= CONVERGED * np.maximum(k, 1e-300)):
                gain[t:], var[t:] = k, s
                self.settled = t
                break
            prior = rho**2 * (1.0 - k) * prior + q
        self.gain, self.variance = gain, var
        self._rho = rho

    def apply(self, x: np.ndarray, columns: list[int] | None = None) -> np.ndarray:
        """Prediction errors of ``x`` (steps, channels), or of ``x`` holding only ``columns`` of the channels;
        non-finite inputs count as 0 (the caller masks them)."""
        cols = list(range(len(self.channels))) if columns is None else columns
        x = np.where(np.isfinite(x), x, 0.0)
        steps = len(x)
        out = np.empty_like(x, dtype=float)
        state = np.zeros(x.shape[1])
        rho, gain = self._rho[cols], self.gain[:, cols]
        head = min(self.settled, steps)
        for t in range(head):
            pred = rho * state
            out[t] = x[t] - pred
            state = pred + gain[t] * out[t]
        if head < steps:  # steady state: ν = (1 − ρ z⁻¹)/(1 − (1 − K)ρ z⁻¹) x, started from the filter's state
            k = gain[min(head, self.steps - 1)]
            for j in range(x.shape[1]):
                if rho[j] == 0.0:
                    out[head:, j] = x[head:, j]
                    continue
                a = (1.0 - k[j]) * rho[j]
                # state recursion s_t = a s_{t-1} + K x_t (lfilter's zi is a·s_{t-1}); ν_t = x_t − ρ s_{t-1}
                s, _ = signal.lfilter([k[j]], [1.0, -a], x[head:, j], zi=[a * state[j]])
                prev = np.concatenate([[state[j]], s[:-1]])
                out[head:, j] = x[head:, j] - rho[j] * prev
        return out


def twin_spread(deviations: np.ndarray) -> np.ndarray:
    """RMS deviation of perturbed runs from the nominal twin, (steps, signals), widened by ±1 step.

    Args:
        deviations: (runs, steps, signals), perturbed minus nominal (already whitened when the model is).
    """
    rms = np.sqrt(np.mean(deviations**2, axis=0))
    padded = np.pad(rms, ((1, 1), (0, 0)), mode="edge")
    return np.maximum(np.maximum(padded[:-2], padded[1:-1]), padded[2:])


@dataclass
class NoiseModel:
    """Per-sample scale of an unexplained residual after whitening: sqrt(innovation variance + whitened twin
    spread²) (steps × signals), and the per-channel sensor noise it comes from."""

    names: tuple[str, ...]
    channels: list[ChannelNoise]
    whitener: Whitener
    twin: np.ndarray  # whitened twin spread, (steps, signals)

    @classmethod
    def build(cls, names: tuple[str, ...], channels: list[ChannelNoise], deviations: np.ndarray) -> NoiseModel:
        """The model of ``channels`` with the twin spread of ``deviations`` (runs, steps, signals)."""
        whitener = Whitener(channels, deviations.shape[1])
        spread = twin_spread(np.stack([whitener.apply(d) for d in deviations])) if len(deviations) else \
            np.zeros((whitener.steps, len(channels)))
        return cls(names, channels, whitener, spread)

    @property
    def sensor(self) -> np.ndarray:
        """Marginal sensor-noise SD per signal (signal units)."""
        return np.array([c.sd for c in self.channels])

    @property
    def total(self) -> np.ndarray:
        """Scale of a whitened residual, (steps, signals)."""
        return np.sqrt(self.whitener.variance + self.twin**2)

    def whiten(self, residual: np.ndarray) -> np.ndarray:
        """Residual (steps, signals) as prediction errors in units of the total scale; NaN where it is NaN."""
        z = self.whitener.apply(residual) / self.total
        return np.where(np.isfinite(residual), z, np.nan)

    def whiten_channel(self, residual: np.ndarray, j: int) -> np.ndarray:
        """One column of :meth:`whiten` (``residual`` (steps,) of signal ``j``)."""
        z = self.whitener.apply(residual[:, None], [j])[:, 0] / self.total[:, j]
        return np.where(np.isfinite(residual), z, np.nan)

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """A sensor-noise realisation (steps, signals) from the model."""
        return np.stack([c.sample(rng, self.whitener.steps) for c in self.channels], axis=1)
