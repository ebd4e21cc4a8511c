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

Colour undecided
    A dig cycle is short (50–300 control steps), and on so few samples the differences often cannot tell moderate
    AR(1) noise from white (:data:`COLOUR_EVIDENCE` is not reached). Calling such a channel white with the variance
    its differences show under-states coloured noise (AR(1) ρ 0.74: the white fit of the differences is 0.6 of
    its SD) and the null then flags what is only noise. So an undecided channel is white with the largest marginal
    variance of the models the spectrum cannot rule out (:data:`PLAUSIBLE` log-likelihood of the best, ρ up to
    :data:`UNDECIDED_RHO_MAX`): honest if the noise is coloured, a few per cent wider if it is white. The drift
    tests see the channel's own fit; a drift found models the slow part instead of the widening.

Drift
    A 32-step spectral segment cannot see a slow random walk (a load pin's zero creeping, an inclinometer's
    temperature drift), yet over the record its level wanders far beyond the white noise and reads as a bias. So
    each channel also gets a random-walk part ``L_t = L_{t-1} + ε_t``, ``ε ~ N(0, drift²)``, zeroed before the
    record's first sample (an offset present from the start is a bias, a change after it is drift), estimated on
    the long time scales (:func:`estimate_drift`): the exact Gaussian likelihood of white + AR(1) + random walk
    over the whole record (every block length up to the record's), profiled over the drift rate, with the twin's
    own signal and its rate as free regressors (a restricted likelihood: a gain or delay is not drift, and the
    part of a walk that resembles the twin's slow signals still counts for its rate), with the
    residual's steps clipped first (a discrepancy's jumps are not drift), and kept only with clear evidence overall
    and none against it in either half of the record (a random walk's increments are stationary, a slow
    discrepancy's are not). The null's noise samples carry the drift, so a drifting channel's wandering level is
    part of what the null expects; the whitening does not predict it: a drift estimate is confounded with a slow
    physical discrepancy on the same channel (a payload's centre of mass moves x_b as slowly as a creeping zero),
    and whitening it away biased the fitted parameters of such effects (payload COM height 18 % short).

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

import dataclasses
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
#: Colour undecided: models whose (weighted) Whittle log-likelihood is within this of the best are not ruled out
#: (a one-parameter likelihood-ratio set of about 95 %: χ²₁(0.95) / 2 = 1.92) ...
PLAUSIBLE = 2.0
#: ... up to this ρ (beyond it an AR(1) part is drift on a dig cycle's length, which :func:`estimate_drift` fits).
UNDECIDED_RHO_MAX = 0.9
CONVERGED = 1e-9  # relative change of the Kalman gain below which the filter is in steady state
#: Drift rates searched, as random-walk increment variance per step relative to the short-scale noise variance:
#: from 1e-5 (a walk that wanders about one noise SD over 100 000 steps, far below what a record shows) to 0.3
#: (increments half the noise: the short-scale fit would call that coloured already). Spacing ×1.6.
DRIFT_GRID = np.logspace(-5.0, np.log10(0.3), 23)
#: Log-likelihood gain needed to call a channel drifting (twice it is the likelihood-ratio statistic: 12, whose
#: tail beyond the boundary's ½χ²₁ is 2.7e-4 per white channel) ...
DRIFT_EVIDENCE = 6.0
#: ... and neither half of the record may speak against that rate by more than this (log-likelihood): a random
#: walk's increments are stationary (its halves lost at most 0.6 in trials), a bump of discrepancy in one part of
#: the cycle makes the other half lose 2–5.
DRIFT_HALF_EVIDENCE = -1.0
#: ... and the robust short-scale spectrum may fit at most this much worse (log-likelihood) with the drift's flat
#: contribution to the differences added (the quiet-half evidence of the colour test, :data:`QUIET_EVIDENCE`).
DRIFT_SPECTRUM_TOLERANCE = QUIET_EVIDENCE
DIFFUSE = 1e6  # prior variance of the record's mean level, relative to the noise (the constant is not noise)
MIN_DRIFT_STEPS = 24  # shorter records say nothing about long time scales
#: A drift common to the recording's channels (:func:`common_drift`) needs at least this many channels ...
MIN_POOL = 3
#: ... and at least this share of them gaining by it.
POOL_SHARE = 0.5


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
    """Noise of one channel: white SD, AR(1) coefficient and marginal SD of the coloured part, and the random-walk
    increment SD per control step (``drift``; signal units)."""

    white: float
    rho: float = 0.0
    coloured: float = 0.0
    drift: float = 0.0
    #: colour undecided (:func:`short_scale`): the white SD the channel takes unless a drift explains its slow part
    #: (0: decided)
    undecided: float = 0.0

    def settled(self) -> ChannelNoise:
        """The channel as the null and the whitening use it: an undecided channel without drift is white with its
        ``undecided`` SD (see the module); a drift found models the slow part instead."""
        if self.undecided > self.white and self.drift == 0.0 and self.coloured == 0.0:
            return dataclasses.replace(self, white=self.undecided, undecided=0.0)
        return dataclasses.replace(self, undecided=0.0) if self.undecided else self

    @property
    def sd(self) -> float:
        """Marginal standard deviation of the short-scale noise (white and coloured; the drift has none)."""
        return float(np.hypot(self.white, self.coloured))

    def sample(self, rng: np.random.Generator, steps: int) -> np.ndarray:
        """A noise realisation of ``steps`` samples (white and coloured stationary from the first, the drift
        zeroed before it)."""
        out = self.white * rng.standard_normal(steps)
        if self.coloured > 0.0:
            eta = self.coloured * np.sqrt(1.0 - self.rho**2) * rng.standard_normal(steps)
            c0 = self.coloured * rng.standard_normal()
            c, _ = signal.lfilter([1.0], [1.0, -self.rho], eta, zi=[self.rho * c0])
            out += c
        if self.drift > 0.0:
            out += np.cumsum(self.drift * rng.standard_normal(steps))
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
    """(ρ, σ_c, σ_w, drift) of one channel: the short-scale fit (:func:`short_scale`), then the drift on the long
    time scales (:func:`estimate_drift`).

    Args:
        residual: (steps,) real minus twin, signal units.
        floor: smallest white SD accepted (signal units).
    """
    return _unsettled(residual, floor).settled()


def _unsettled(residual: np.ndarray, floor: float, raw: np.ndarray | None = None,
               twin: np.ndarray | None = None) -> ChannelNoise:
    """:func:`estimate_channel` before an undecided channel is settled (what the common-drift test sees): the short
    scale of ``residual``, the drift of ``raw`` (default ``residual``) with the twin's signal ``twin`` (steps,) as
    free regressors where given (:func:`estimate_drift`)."""
    short = short_scale(residual, floor)
    drift, _ = estimate_drift(residual if raw is None else raw, short, twin)
    return dataclasses.replace(short, drift=drift) if drift > 0.0 else short


def short_scale(residual: np.ndarray, floor: float) -> ChannelNoise:
    """(ρ, σ_c, σ_w) of one channel: a Whittle fit of AR(1) + white to the median-Welch spectrum of the residual's
    first differences, clipped at :data:`TRIM` robust deviations (see the module). The coloured part is kept only
    when it raises the likelihood beyond :data:`COLOUR_EVIDENCE` over white alone; otherwise the channel is white,
    its fit kept for the drift tests and the largest marginal SD the spectrum does not rule out recorded
    (``undecided``, :func:`_undecided_sd`; :meth:`ChannelNoise.settled` applies it).

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
    undecided = ChannelNoise(white, undecided=_undecided_sd(white, weight, float(white_ll[0]), loglik, w2, e2, floor))
    if weight * float(loglik[best] - white_ll[0]) < COLOUR_EVIDENCE or e2[best] <= 0.0:
        return undecided
    # stationary noise is coloured in the quiet segments too; a discrepancy that lasts through most of the record
    # (a load's offset) colours the median but not the segments before it acts
    quiet_white, _, _ = _whittle_fit(quiet, omega, np.array([0.0]))
    quiet_ll, _, _ = _whittle_fit(quiet, omega, RHO_GRID)
    if quiet_weight * float(np.max(quiet_ll) - quiet_white[0]) < QUIET_EVIDENCE:
        return undecided
    rho = float(RHO_GRID[best])
    coloured = float(np.sqrt(e2[best] / (1.0 - rho**2)))
    return ChannelNoise(max(float(np.sqrt(w2[best])), floor), rho, coloured)


def _undecided_sd(white: float, weight: float, white_ll: float, loglik: np.ndarray, w2: np.ndarray, e2: np.ndarray,
                  floor: float) -> float:
    """White SD of a channel whose colour is undecided (see the module): the largest marginal SD (white and AR(1)
    parts) of the models within :data:`PLAUSIBLE` of the best (ρ ≤ :data:`UNDECIDED_RHO_MAX`), at least ``white``
    (the all-white fit) and ``floor``."""
    top = max(float(np.max(loglik)), white_ll)
    plausible = (weight * (loglik - top) >= -PLAUSIBLE) & (RHO_GRID <= UNDECIDED_RHO_MAX)
    marginal = w2 + e2 / (1.0 - RHO_GRID**2)
    return max(white, floor, float(np.sqrt(np.max(marginal[plausible], initial=0.0))))


def level_loglik(x: np.ndarray, short: ChannelNoise, q: np.ndarray, zeroed: bool = False) -> np.ndarray:
    """Exact Gaussian log-likelihood of ``x`` (steps,) under ``short`` (white + AR(1)) plus a random walk of
    increment variance ``q`` (one value per entry of ``q``, signal units²), its level unknown at the start (diffuse
    prior: a free constant offset) or, ``zeroed``, zero before the first sample. Kalman filter of the state
    (AR(1) part, level), all ``q`` at once."""
    white2, rho, c2 = short.white**2, short.rho, short.coloured**2
    q = np.asarray(q, float)
    p00, p01 = np.full(len(q), c2), np.zeros(len(q))
    p11 = q.copy() if zeroed else np.full(len(q), DIFFUSE * max(white2 + c2, 1e-300))
    c, level, loglik = np.zeros(len(q)), np.zeros(len(q)), np.zeros(len(q))
    for value in x:
        s = np.maximum(p00 + 2.0 * p01 + p11 + white2, 1e-300)
        nu = value - c - level
        loglik -= 0.5 * (np.log(2.0 * np.pi * s) + nu * nu / s)
        k0, k1 = (p00 + p01) / s, (p01 + p11) / s
        c, level = rho * (c + k0 * nu), level + k1 * nu
        p00, p01, p11 = p00 - k0 * k0 * s, p01 - k0 * k1 * s, p11 - k1 * k1 * s
        p00, p01, p11 = rho**2 * p00 + c2 * (1.0 - rho**2), rho * p01, p11 + q
    return loglik


def regression_loglik(x: np.ndarray, short: ChannelNoise, q: np.ndarray, regressors: np.ndarray) -> np.ndarray:
    """:func:`level_loglik` (diffuse level) of ``x`` (steps,) with free coefficients on ``regressors`` (steps, k)
    beside the level: their priors diffuse too, so the likelihood is that of what the regressors cannot explain,
    a restricted likelihood (Harvey 1989, ch. 3.4; REML): a walk's rate estimated by it is not lowered by what the
    regressors absorb of the walk, and what they explain is not taken for a walk. Kalman filter of the state
    (AR(1) part, level, coefficients), all ``q`` (signal units², increment variance per step) at once."""
    white2, rho, c2 = short.white**2, short.rho, short.coloured**2
    q = np.asarray(q, float)
    k = regressors.shape[1]
    m = 2 + k
    var = max(white2 + c2, 1e-300)
    power = np.maximum(np.mean(regressors**2, axis=0), 1e-300)
    p = np.zeros((len(q), m, m))
    p[:, 0, 0] = c2
    p[:, 1, 1] = DIFFUSE * var
    for i in range(k):
        p[:, 2 + i, 2 + i] = DIFFUSE * var / power[i]
    a = np.zeros((len(q), m))
    decay = np.ones(m)
    decay[0] = rho
    loglik = np.zeros(len(q))
    for t, value in enumerate(x):
        z = np.concatenate([[1.0, 1.0], regressors[t]])
        pz = p @ z  # (B, m)
        f = np.maximum(pz @ z + white2, 1e-300)
        nu = value - a @ z
        loglik -= 0.5 * (np.log(2.0 * np.pi * f) + nu * nu / f)
        gain = pz / f[:, None]
        a = (a + gain * nu[:, None]) * decay
        p = (p - gain[:, :, None] * pz[:, None, :]) * decay[None, :, None] * decay[None, None, :]
        p[:, 0, 0] += c2 * (1.0 - rho**2)
        p[:, 1, 1] += q
    return loglik


def _spectral_misfit(d: np.ndarray, short: ChannelNoise, q: float) -> float:
    """How much worse (Whittle log-likelihood, weighted as in :func:`short_scale`) the median-Welch spectrum of the
    differences ``d`` fits when a random walk of increment variance ``q`` adds its flat spectrum ``q`` to the
    short-scale noise's: stationary drift shows in every segment, so the robust spectrum must accept it; a slow
    discrepancy that only some segments see (and the long-scale likelihood takes for drift) it rejects."""
    omega, spectrum, weight, _, _ = median_spectrum(robust_clip(d))
    a = 2.0 * (1.0 - np.cos(omega))
    b = a / (1.0 - 2.0 * short.rho * np.cos(omega) + short.rho**2)
    s0 = np.maximum(short.white**2 * a + short.coloured**2 * (1.0 - short.rho**2) * b, 1e-300)
    s1 = s0 + q
    return weight * float(np.sum(np.log(s1) + spectrum / s1 - np.log(s0) - spectrum / s0))


def estimate_drift(residual: np.ndarray, short: ChannelNoise, twin: np.ndarray | None = None
                   ) -> tuple[float, float]:
    """Random-walk increment SD per step (signal units; 0: no drift) of one channel beside its short-scale noise
    ``short``, and the log-likelihood gain it brings over no drift.

    The residual's first differences are clipped at :data:`TRIM` robust deviations and summed again (a
    discrepancy's steps are not drift; a random walk's increments are Gaussian and pass). The drift rate is the
    best of :data:`DRIFT_GRID` by :func:`level_loglik`; it is kept when it gains :data:`DRIFT_EVIDENCE` over none
    on the whole record, the robust short-scale spectrum accepts it (:func:`_spectral_misfit`) and neither half
    loses more than −:data:`DRIFT_HALF_EVIDENCE` by it (see the module).

    With ``twin`` (steps,; the twin's signal the residual is taken against), the twin's signal and its rate enter
    as free regressors (:func:`regression_loglik`): a gain or delay on the channel is a discrepancy, not a walk,
    and a walk that looks partly like the twin's slow signal keeps its full rate (a regression on a ramp took up
    to half a walk's excursion, so the null drew walks too tame for the record). The steps clipped are those of
    the residual less its least-squares fit on the twin (a gain on a signal with sharp steps is not clipped)."""
    if twin is None:
        d = np.diff(residual)
        if len(d) < MIN_DRIFT_STEPS or not np.all(np.isfinite(d)):
            return 0.0, 0.0
        x = np.concatenate([[0.0], np.cumsum(robust_clip(d))])
        regs = None
    else:
        if len(residual) - 1 < MIN_DRIFT_STEPS or not np.all(np.isfinite(residual)):
            return 0.0, 0.0
        design = _design(twin)
        coef, *_ = np.linalg.lstsq(design, residual, rcond=None)
        fit = design @ coef
        d = np.diff(residual - fit)
        x = fit - fit[0] + np.concatenate([[0.0], np.cumsum(robust_clip(d))])
        regs = design[:, 1:][:, np.ptp(design[:, 1:], axis=0) > 1e-9]  # a constant twin is the level already
    q = np.concatenate([[0.0], DRIFT_GRID * (short.white**2 + short.coloured**2)])

    def loglik(part: slice, rates: np.ndarray) -> np.ndarray:
        if regs is None:
            return level_loglik(x[part], short, rates)
        return regression_loglik(x[part], short, rates, regs[part])

    gain = loglik(slice(None), q)
    gain = gain[1:] - gain[0]
    best = int(np.argmax(gain))
    if gain[best] < DRIFT_EVIDENCE:
        return 0.0, float(max(gain[best], 0.0))
    if _spectral_misfit(d, short, float(q[best + 1])) > DRIFT_SPECTRUM_TOLERANCE:
        return 0.0, float(gain[best])
    half = len(x) // 2
    for part in (slice(0, half), slice(half, None)):
        ll = loglik(part, q[[0, best + 1]])
        if ll[1] - ll[0] < DRIFT_HALF_EVIDENCE:
            return 0.0, float(gain[best])
    return float(np.sqrt(q[best + 1])), float(gain[best])


def offset_or_drift(residual: np.ndarray, short: ChannelNoise) -> float:
    """Log-likelihood by which a constant offset (free level, no drift) explains ``residual`` (steps,) better than
    a random walk zeroed before the first sample (its rate the best of :data:`DRIFT_GRID`), both beside the
    short-scale noise ``short``. Negative: the level wanders rather than sits (drift, or a slow discrepancy), so
    the offset is no evidence of a sensor bias. Both models have one free parameter."""
    x = np.where(np.isfinite(residual), residual, 0.0)
    offset = float(level_loglik(x, short, np.array([0.0]))[0])
    q = DRIFT_GRID * (short.white**2 + short.coloured**2)
    walk = float(np.max(level_loglik(x, short, q, zeroed=True)))
    # the diffuse prior of the offset costs ½ log(prior variance / variance of the level's estimate) ≈ ½ log(DIFFUSE
    # × steps): given back, so the offset is a profiled free parameter like the walk's rate
    return offset + 0.5 * float(np.log(DIFFUSE * len(x))) - walk


def sensor_noise(residual: np.ndarray, spread: np.ndarray, twin: np.ndarray | None = None) -> list[ChannelNoise]:
    """The noise model of every column of ``residual`` (steps, signals); white SD floored by ``spread`` ×
    :data:`NOISE_FLOOR`.

    With ``twin`` (steps, signals, the twin's signals the residual is taken against), what the twin's own signal,
    its rate of change and a constant explain in each column is removed first: a gain, bias or delay on a channel
    is a discrepancy, not noise (left in, a gain on a pressure with sharp relief steps reads as drift, and the
    whitening would then hide the very gain). A random walk common to the channels is then looked for on the
    residual before that removal (:func:`common_drift`: the twin's slow signals absorb a slow walk)."""
    raw = residual
    if twin is None:
        channels = [_unsettled(residual[:, j], NOISE_FLOOR * float(spread[j])) for j in range(residual.shape[1])]
        return [c.settled() for c in common_drift(raw, channels)]
    residual = _unexplained_by(residual, twin)
    channels = [_unsettled(residual[:, j], NOISE_FLOOR * float(spread[j]), raw[:, j], np.nan_to_num(twin[:, j]))
                for j in range(residual.shape[1])]
    return [c.settled() for c in common_drift(raw, channels)]


def drift_gains(residual: np.ndarray, shorts: list[ChannelNoise]) -> np.ndarray:
    """Log-likelihood gain (over none) of a random walk beside each channel's short-scale noise ``shorts``, at
    every relative rate of :data:`DRIFT_GRID` (increment variance per step / the channel's ``sd``²): (channels,
    rates), on ``residual`` (steps, channels) with its steps clipped as in :func:`estimate_drift` and its level
    diffuse (:func:`level_loglik`, all channels and rates at once). Zero for a channel too short or not finite."""
    steps, n = residual.shape
    d = np.diff(residual, axis=0)
    ok = np.all(np.isfinite(d), axis=0) & (steps - 1 >= MIN_DRIFT_STEPS)
    if not np.any(ok):
        return np.zeros((n, len(DRIFT_GRID)))
    x = np.zeros((steps, n))
    x[1:, ok] = np.cumsum(np.stack([robust_clip(d[:, j]) for j in np.flatnonzero(ok)], axis=1), axis=0)
    white2 = np.array([c.white**2 for c in shorts])[:, None]
    rho = np.array([c.rho for c in shorts])[:, None]
    c2 = np.array([c.coloured**2 for c in shorts])[:, None]
    var = np.maximum(white2 + c2, 1e-300)
    q = np.concatenate([np.zeros((n, 1)), DRIFT_GRID[None, :] * var], axis=1)  # (channels, 1 + rates)
    p00, p01 = np.broadcast_to(c2, q.shape).copy(), np.zeros(q.shape)
    p11 = np.broadcast_to(DIFFUSE * var, q.shape).copy()
    c, level, loglik = np.zeros(q.shape), np.zeros(q.shape), np.zeros(q.shape)
    for value in x:  # the Kalman filter of level_loglik, one row of channels × rates per step
        s = np.maximum(p00 + 2.0 * p01 + p11 + white2, 1e-300)
        nu = value[:, None] - c - level
        loglik -= 0.5 * (np.log(2.0 * np.pi * s) + nu * nu / s)
        k0, k1 = (p00 + p01) / s, (p01 + p11) / s
        c, level = rho * (c + k0 * nu), level + k1 * nu
        p00, p01, p11 = p00 - k0 * k0 * s, p01 - k0 * k1 * s, p11 - k1 * k1 * s
        p00, p01, p11 = rho**2 * p00 + c2 * (1.0 - rho**2), rho * p01, p11 + q
    return np.where(ok[:, None], loglik[:, 1:] - loglik[:, :1], 0.0)


def common_drift(raw: np.ndarray, channels: list[ChannelNoise]) -> list[ChannelNoise]:
    """``channels`` with a random walk common to the recording's sensors where the record shows one.

    A record of a few seconds holds too little of a slow walk for one channel's test (:func:`estimate_drift`) to
    see it, and the twin's own slow signals, regressed out before the short-scale noise is estimated, absorb much
    of what it holds (the ramp of a curl in ``bucket_pitch`` took a walk of 3.5 noise SDs whole). Sensors of one
    machine and logger drift alike (temperature, supply), so the walk's rate relative to each channel's
    short-scale variance is tested on all channels of ``raw`` (steps, channels; the residual with only a constant
    removed, by the walk's diffuse level) together: the summed log-likelihood gain (:func:`drift_gains`) must
    reach :data:`DRIFT_EVIDENCE`, at least :data:`POOL_SHARE` of the channels must gain by it (a slow discrepancy
    moves some channels, a drifting logger all), and neither half of the record may lose by it, summed over the
    channels (a walk's increments are stationary, a discrepancy acts in some phases of the cycle). A channel
    without its own drift then gets the common rate unless its own gain at that rate is below
    :data:`DRIFT_HALF_EVIDENCE`. Fewer than :data:`MIN_POOL` channels: unchanged."""
    if len(channels) < MIN_POOL or len(raw) <= 2 * MIN_DRIFT_STEPS:
        return channels
    shorts = [dataclasses.replace(c, drift=0.0) for c in channels]
    gains = drift_gains(raw, shorts)
    total = gains.sum(axis=0)
    best = int(np.argmax(total))
    if total[best] < DRIFT_EVIDENCE or float(np.mean(gains[:, best] > 0.0)) < POOL_SHARE:
        return channels
    half = len(raw) // 2
    for part in (raw[:half], raw[half:]):
        if float(np.sum(drift_gains(part, shorts)[:, best])) < 0.0:
            return channels
    out = []
    for j, c in enumerate(channels):
        if c.drift == 0.0 and gains[j, best] >= DRIFT_HALF_EVIDENCE:
            c = dataclasses.replace(c, drift=float(np.sqrt(DRIFT_GRID[best]) * c.sd))
        out.append(c)
    return out


def _design(twin: np.ndarray) -> np.ndarray:
    """(1, twin, d twin / dstep) of one channel's twin signal (steps,), each column scaled to a peak of 1."""
    x = np.nan_to_num(twin)
    design = np.stack([np.ones(len(x)), x, np.gradient(x)], axis=1)
    return design / np.maximum(np.abs(design).max(axis=0), 1e-300)


def _unexplained_by(residual: np.ndarray, twin: np.ndarray) -> np.ndarray:
    """Per column, ``residual`` less its least-squares fit on (1, twin, d twin / dstep)."""
    out = residual.copy()
    for j in range(residual.shape[1]):
        design = _design(twin[:, j])
        coef, *_ = np.linalg.lstsq(design, residual[:, j], rcond=None)
        out[:, j] = residual[:, j] - design @ coef
    return out


@dataclass
class Whitener:
    """The one-step prediction-error filter of a set of channels (time-varying Kalman gain from the first sample) under
    their short-scale noise (white and AR(1); a channel's drift is left to the null, see the module docstring).

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


def drift_innovations(x: np.ndarray, channels: list[ChannelNoise]) -> tuple[np.ndarray, np.ndarray]:
    """One-step prediction errors of ``x`` (steps, channels; non-finite as 0) and their variances (same shape)
    under each channel's full model: white + AR(1) + its random walk, the walk's level diffuse at the start (a free
    constant). Kalman filter of (AR(1) part, level), all channels at once. Where a channel has no drift this is
    the :class:`Whitener`'s filter with a free constant."""
    x = np.where(np.isfinite(x), x, 0.0)
    white2 = np.array([c.white**2 for c in channels])
    rho = np.array([c.rho for c in channels])
    c2 = np.array([c.coloured**2 for c in channels])
    q = np.array([c.drift**2 for c in channels])
    p00, p01, p11 = c2.copy(), np.zeros(len(channels)), DIFFUSE * np.maximum(white2 + c2, 1e-300)
    c, level = np.zeros(len(channels)), np.zeros(len(channels))
    nu_out, s_out = np.empty_like(x, dtype=float), np.empty_like(x, dtype=float)
    for t, value in enumerate(x):
        s = np.maximum(p00 + 2.0 * p01 + p11 + white2, 1e-300)
        nu = value - c - level
        nu_out[t], s_out[t] = nu, s
        k0, k1 = (p00 + p01) / s, (p01 + p11) / s
        c, level = rho * (c + k0 * nu), level + k1 * nu
        p00, p01, p11 = p00 - k0 * k0 * s, p01 - k0 * k1 * s, p11 - k1 * k1 * s
        p00, p01, p11 = rho**2 * p00 + c2 * (1.0 - rho**2), rho * p01, p11 + q
    return nu_out, s_out


def linear_evidence(z: np.ndarray, zx: np.ndarray) -> np.ndarray:
    """Objective decrease (whitened units, the quadratic part of the Huber objective) of fitting ``a × x`` by
    generalised least squares, given the whitened residual ``z`` and whitened regressor ``zx`` (same shape;
    column-wise for 2-D): (Σ z zx)² / Σ zx². χ²₁ when the residual is noise as modelled."""
    return np.sum(z * zx, axis=0) ** 2 / np.maximum(np.sum(zx * zx, axis=0), 1e-300)


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
    #: per signal, the mean :func:`linear_evidence` of a constant offset in the null runs (drift alone; set by
    #: :func:`~discrepancy.stats.null.calibrate`; None: not calibrated)
    bias_null: np.ndarray | None = None
    #: per signal, the mean :func:`linear_evidence` of a gain (a multiple of the twin's signal) in the null runs
    #: (set by :func:`~discrepancy.stats.null.calibrate`; None: not calibrated)
    gain_null: np.ndarray | None = None
    #: signal → why a sensor fault on it was not tried (filled by the searches)
    withheld: dict[str, str] = field(default_factory=dict)

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

    @property
    def drifting(self) -> tuple[str, ...]:
        """Signals whose noise has a random-walk part."""
        return tuple(n for n, c in zip(self.names, self.channels, strict=True) if c.drift > 0.0)

    def bias_evidence(self, residual: np.ndarray) -> np.ndarray:
        """Per signal, :func:`linear_evidence` of a constant offset in ``residual`` (steps, signals)."""
        ones = self.whiten(np.ones_like(residual))
        return linear_evidence(np.nan_to_num(self.whiten(residual)), ones)

    def whiten_drift(self, residual: np.ndarray) -> np.ndarray:
        """Residual (steps, signals) as prediction errors under the full model, drift included
        (:func:`drift_innovations`; a free constant), in units of their SD with the twin spread; NaN where it is
        NaN. What is left is what neither the sensors' noise nor their drift explains."""
        nu, s = drift_innovations(residual, self.channels)
        z = nu / np.sqrt(s + self.twin**2)
        return np.where(np.isfinite(residual), z, np.nan)

    def gain_evidence(self, residual: np.ndarray, twin: np.ndarray) -> np.ndarray:
        """Per signal, :func:`linear_evidence` of a multiple of ``twin`` (steps, signals; a gain error) in
        ``residual`` (steps, signals)."""
        return linear_evidence(np.nan_to_num(self.whiten(residual)), np.nan_to_num(self.whiten(twin)))

    def sample(self, rng: np.random.Generator) -> np.ndarray:
        """A sensor-noise realisation (steps, signals) from the model (with its drift)."""
        return np.stack([c.sample(rng, self.whitener.steps) for c in self.channels], axis=1)
