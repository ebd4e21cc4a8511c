"""Field-log input: bring a data logger's recording to the twin's control steps, and measure what the logger did.

A field log is sampled at its own rate (50–1000 Hz typically, timestamps slightly jittered), has short dropouts
(NaN), may lack channels, may be offset in time from the commands and may have gone through a sensor's filter.
The twin (:mod:`scaletwin_envs.recording.schema`) has one row per control step of length ``dt``: row ``k`` holds
the command applied over the interval ``(t_k - dt, t_k]`` and the signals read at ``t_k``, the interval's END
(the env reads its signals after the physics of the step). :func:`prepare_log` matches that:

* signals: a zero-phase (centred, linear-phase) Kaiser FIR low-pass, flat up to the twin's Nyquist frequency
  ``f_N = 1/(2 dt)`` and :data:`STOP_DB` down from ``2 f_N``, then the filtered log is read at each control time
  ``t_k`` (cubic interpolation). The twin's signal at ``t_k`` is an instantaneous sample, not an average: its
  sequence carries everything in ``0..f_N`` (and its own fast dynamics folded onto it), so the filter must leave
  ``0..f_N`` untouched, or the twin would differ from the log where it is right (a filter flat only to 0.6 f_N
  changes an upsampled twin recording's accelerations by up to 0.25 of their spread; this one by < 1 %). From
  ``2 f_N`` on, where most of a fast logger's noise is, nothing folds back; in the transition ``f_N..2 f_N`` a
  tone is partly attenuated and folds onto ``0..f_N`` as it does in the twin's own samples. The filter is centred
  so it adds no delay: an average over the control interval would lag by ``dt/2`` and look like a sensor delay
  to the diagnosis.
  (``scipy.signal.resample_poly`` would be the same linear-phase FIR for an integer ratio on uniform timestamps;
  one path for every ratio and for jittered timestamps is used instead.)
* commands: the twin holds each command for one control step (zero-order hold), over ``(t_k - dt, t_k]``. A
  logger reads the command at its sampling instant, so every sample taken inside that interval reads the command
  of step ``k`` when the commands switch on the control grid: the command of interval ``k`` is the mean of the
  commands logged at times in ``(t_k - dt, t_k]``, which is then the command itself, whatever the logger's phase
  against the grid. For a command that changes in between, the mean of the instantaneous samples is the command
  of (nearly) equal integral (equal cylinder travel for a flow-proportional valve), known to within half a
  logger step of each change; the samples of one interval then disagree, and :attr:`InputReport.command_timing`
  says how far a change may be off (0 when every interval's samples agree). An interval without a sample (a
  jittered logger just above the control rate) takes the time-weighted mean of the logged commands, each held
  over the logger's interval ending at its timestamp. (Taking every sample as held over the logger's interval
  put a share of up to ``h / dt`` of each change into the wrong step: a 50 Hz log of a 0.038 s control step gave
  commands 0.06 RMS off, and a dig replayed from them with the true start left residuals 20 times its noise.)
* phases (strings): the logged phase nearest to ``t_k``.
* the control grid starts at the log's first timestamp: that sample is the end of the first control step, as the
  first row of our recordings and of a log at the control step is (the reset state is not a row), and rows are
  ``t_0 + k dt``, ``k = 0 .. floor((t_last - t_0)/dt)``; the first logged command is taken as held over the whole
  first interval ``(t_0 - dt, t_0]``. A log at the control step and the same log at a faster rate so give the same
  rows: when the grid started one step later, the replay lost the first command and ran one step behind the log
  (transients at the start and an offset in position that the start estimate half absorbed; every null case of a
  50-500 Hz benchmark log was located in its first windows).

A log slower than the control step is refused (:class:`RecordingError`): its signals would have to be invented
between samples; compare the twin at the log's times instead (every m-th twin row for an integer ratio m).

NaN gaps are bridged (signals linearly, commands by holding the last value) when the span without data is at most
:data:`MAX_GAP_STEPS` control steps, and refused otherwise. Everything done is recorded in an :class:`InputReport`.

:func:`estimate_offset`/:func:`delayed` find a time offset between the log and the twin's replay and read the twin
with it;
:func:`first_order_filter`/:func:`estimate_sensor_tau` model a sensor's first-order low-pass.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import optimize, signal, sparse
from scipy.interpolate import CubicSpline

from discrepancy.data.channels import COMPARED, RecordingError

#: A gap is bridged when the straight line (or the held command) spans at most this many control steps: 0.4 s at
#: ER12's 0.1 s, under half a locate window (10 steps), so a bridged gap can never fill a window by itself, and
#: short against the cylinders' motions (about one second per stroke segment) so a line follows them closely.
MAX_GAP_STEPS = 4
#: Relative mismatch of the log's median step and the control step still taken as the control rate; the same as
#: ``discrepancy.twin.spec.DT_TOLERANCE``, so what passes here passes the twin's compatibility check.
RATE_TOLERANCE = 0.02
#: A timestamp step this many times the median step is a logger dropout (reported, bridged like a NaN gap):
#: ordinary jitter of a data logger is a few per cent of its step.
DROPOUT_FACTOR = 1.5
#: Timestamps whose steps deviate less than this (relative) from the median are uniform: the log is used as is,
#: not interpolated onto a uniform grid (floating-point rounding of ``k * h`` stays far below it).
UNIFORM_TOLERANCE = 1e-6
#: Anti-alias filter: pass band up to this multiple of the twin's Nyquist frequency ``1/(2 dt)`` (all of what the
#: twin's samples carry, see the module docstring) ...
PASS_FRACTION = 1.0
#: ... and stop band from this multiple on, attenuated by STOP_DB: 60 dB (1e-3) puts a folded tone below a typical
#: sensor's noise (0.1 % of range).
STOP_FRACTION = 2.0
STOP_DB = 60.0
#: Kinematic channels used to estimate a time offset: positions and angles, which the twin gets right up to
#: smooth errors; forces jump at contact and relief and would make the cross-correlation follow the physics.
KINEMATIC = ("lift_extension", "tilt_extension", "boom_angle", "bucket_pitch", "x_b", "y_b")
#: An estimated offset is significant when it is at least this fraction of a control step (smaller shifts change a
#: sample by less than the interpolation error of the comparison) ...
MIN_OFFSET_STEPS = 0.25
#: ... and the aligned residual is at most half the residual without a shift: an offset of the whole log explains
#: nearly all of the kinematic residual it causes, while a physical discrepancy (a slower cylinder, friction) is
#: only partly imitated by a shift and must be left to the diagnosis.
MIN_OFFSET_GAIN = 0.5
#: The machine's independent circuits and the channels each one moves. A time offset of the whole log shifts every
#: circuit alike; an actuator's dead time shifts its own circuit only; so an offset is one of the log only when at
#: least two circuits each show it (:func:`circuits_agree`). The drive is the circuit that moves first in a dig
#: (the machine drives into the pile before the boom or the bucket moves much), so a log's first rows can show an
#: offset on it and on the tilt while the lift has not moved yet.
CIRCUITS: dict[str, tuple[str, ...]] = {"lift": ("lift_extension", "boom_angle", "lift_speed"),
                                         "tilt": ("tilt_extension", "bucket_pitch", "tilt_speed"),
                                         "drive": ("travel_speed",)}
#: Circuits agree on an offset when their own estimates lie within this many control steps of each other.
OFFSET_AGREEMENT = 0.5
#: Sensor time constants searched (s): 0 to 1 s covers load pins, pressure transducers and inclinometers.
TAU_MAX = 1.0
#: A sensor filter is reported (tau > 0) only when it removes at least half of the residual: a filter smooths the
#: twin's sharp steps and always gains a little against a noisy log or a physical discrepancy (friction smooths
#: the motion too), while a real sensor filter explains nearly all of the residual it causes.
MIN_TAU_GAIN = 0.5
#: A timestamp within this fraction of a control step after a grid time still belongs to the step ending there
#: (floating-point rounding of ``t_0 + k h`` against ``t_0 + k dt``; a logger's real jitter is far larger).
GRID_TOLERANCE = 1e-6
#: Logged commands within one control interval agree when they differ by at most this (normalised command units):
#: a logged value read back from a file keeps ten significant digits or more.
COMMAND_AGREEMENT = 1e-6


@dataclass(frozen=True)
class InputReport:
    """What was done to a log before the comparison.

    Attributes:
        original_rate_hz: the log's sampling rate (1 / median timestamp step), Hz.
        control_dt: the twin's control step the log was prepared for, s (None: taken as it is).
        resampled: whether the log was resampled to the control steps.
        filter: the anti-alias filter and the alignment rule, in words (None when not resampled).
        gaps: bridged gaps ``(channel, t_start, t_end)``: times (s, log clock) of the first and last missing
            sample; ``channel`` ``"time"`` for a logger dropout (missing rows).
        channels_missing: compared signals the log does not have (absent or never finite).
        time_offset: offset between the log's signals and the twin, s (positive: the log lags), once estimated.
        sensor_tau: a first-order sensor time constant, s, once declared or estimated.
        warnings: anything else a reader of the report should know.
        command_timing: how far a command change may lie from where the prepared commands put it, in control
            steps (0: not resampled, or every control interval's logged commands agree, so the commands switch on
            the twin's grid and are exact; see :func:`resample_commands`).
        span_s: the log's length, s (last timestamp less the first), which the resampling's ends depend on
            (:func:`resampling_operator`); None where not resampled.
    """

    original_rate_hz: float
    control_dt: float | None = None
    resampled: bool = False
    filter: str | None = None
    gaps: tuple[tuple[str, float, float], ...] = ()
    channels_missing: tuple[str, ...] = ()
    time_offset: float | None = None
    sensor_tau: float | None = None
    warnings: tuple[str, ...] = ()
    command_timing: float = 0.0
    span_s: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: numbers as floats, gaps as ``{"channel", "t_start", "t_end"}`` objects."""
        return {
            "original_rate_hz": float(self.original_rate_hz),
            "control_dt": None if self.control_dt is None else float(self.control_dt),
            "resampled": self.resampled,
            "filter": self.filter,
            "gaps": [{"channel": c, "t_start": float(a), "t_end": float(b)} for c, a, b in self.gaps],
            "channels_missing": list(self.channels_missing),
            "time_offset": None if self.time_offset is None else float(self.time_offset),
            "sensor_tau": None if self.sensor_tau is None else float(self.sensor_tau),
            "warnings": list(self.warnings),
            "command_timing": float(self.command_timing),
            "span_s": None if self.span_s is None else float(self.span_s),
        }


@dataclass(frozen=True)
class PreparedLog:
    """A log at the control steps: time (s), commands (steps, 3), SI signals, phases, and the report."""

    time: np.ndarray
    commands: np.ndarray
    signals: dict[str, np.ndarray]
    phases: np.ndarray
    report: InputReport


@dataclass(frozen=True)
class OffsetEstimate:
    """A time offset between a log and the twin's replay.

    Attributes:
        offset: s; positive when the log's signals lag the twin (``real(t) ≈ twin(t - offset)``).
        significant: whether the offset is worth undoing (:data:`MIN_OFFSET_STEPS`, :data:`MIN_OFFSET_GAIN`).
        cost_zero, cost: normalised mean squared residual without and with the shift (1 ≈ the twin's variance).
        channels: the channels used.
        standard_error: s, how far the offset is left open: the least-squares standard error from the cost's
            curvature at the optimum and the residual left there, over the residual's effective sample size (its
            rows are correlated: coloured noise, a start the log leaves open); NaN where not estimated.
    """

    offset: float
    significant: bool
    cost_zero: float
    cost: float
    channels: tuple[str, ...] = field(default_factory=tuple)
    standard_error: float = float("nan")

    def to_dict(self) -> dict[str, Any]:
        return {"offset": float(self.offset), "significant": self.significant, "cost_zero": float(self.cost_zero),
                "cost": float(self.cost), "channels": list(self.channels),
                "standard_error": float(self.standard_error)}


# -- preparing a log ---------------------------------------------------------------------------------------------

def prepare_log(time: np.ndarray, commands: np.ndarray, signals: Mapping[str, np.ndarray], phases: np.ndarray,
                control_dt: float | None, name: str = "log") -> PreparedLog:
    """Bridge short gaps, note missing channels and, for a log faster than ``control_dt``, resample it.

    Args:
        time: timestamps, s (finite, strictly increasing).
        commands: (rows, 3) normalised commands, NaN where the logger missed them.
        signals: SI signals by name (rows,), NaN where missing; never-finite ones count as absent.
        phases: dig phase per row (strings).
        control_dt: the twin's control step, s; None takes the log's own step as the control step (no resampling).
        name: used in messages.

    Raises:
        RecordingError: a gap too long to bridge (naming the channel, time and length), a log slower than the
            control step, no compared signal, too few rows, or a channel whose values overflow the resampling
            (naming it).
    """
    time = np.asarray(time, dtype=np.float64)
    steps = np.diff(time)
    if len(time) < 2 or np.any(steps <= 0):
        row = int(np.flatnonzero(steps <= 0)[0]) + 1 if len(time) >= 2 else 0
        raise RecordingError(f"{name}: time does not increase at row {row}")
    h = float(np.median(steps))
    dt = h if control_dt is None else float(control_dt)
    if not dt > 0:
        raise RecordingError(f"{name}: the control step must be positive, got {control_dt}")
    ratio = dt / h
    if ratio < 1.0 - RATE_TOLERANCE:
        raise RecordingError(
            f"{name}: sampled every {h:.4g} s ({1 / h:.4g} Hz), slower than the twin's control step {dt:.4g} s; "
            "the signals between samples would have to be invented. Log at the control rate or faster")
    resample = ratio > 1.0 + RATE_TOLERANCE
    max_span = MAX_GAP_STEPS * dt
    gaps: list[tuple[str, float, float]] = []
    warnings: list[str] = []
    if resample:  # a log kept at its own step is checked for uniform sampling by the caller
        gaps += _dropouts(time, h, max_span, name)
    present = {k: np.asarray(v, dtype=np.float64) for k, v in signals.items()}
    present = {k: v for k, v in present.items() if np.any(np.isfinite(v))}
    missing = tuple(s for s in COMPARED if s not in present)
    if not any(s in present for s in COMPARED):
        raise RecordingError(f"{name}: none of the compared signals {list(COMPARED)} is present and finite")
    bridged = {}
    for k, v in present.items():
        try:
            bridged[k], found = bridge_gaps(time, v, k, max_span, hold=False, name=name)
        except RecordingError as exc:
            if k in COMPARED:
                raise
            warnings.append(f"{k} dropped (not compared, only cross-checked): {exc}")
            continue
        gaps += found
    cmds = np.array(commands, dtype=np.float64, copy=True)
    for i, k in enumerate(("cmd_lift", "cmd_tilt", "cmd_drive")):
        if not np.any(np.isfinite(cmds[:, i])):
            raise RecordingError(f"{name}: {k} has no finite value; the twin replays the commands")
        cmds[:, i], found = bridge_gaps(time, cmds[:, i], k, max_span, hold=True, name=name)
        gaps += found
    phases = np.asarray(phases, dtype=object)
    if not resample:
        report = InputReport(1.0 / h, control_dt, False, None, tuple(gaps), missing, warnings=tuple(warnings))
        return PreparedLog(time, cmds, bridged, phases, report)
    grid = control_grid(time, dt)
    if len(grid) < 2:
        raise RecordingError(f"{name}: the log spans {time[-1] - time[0]:.3g} s, less than two control steps")
    taps, description = antialias_filter(h, dt)
    out = {k: _resampled(time, v, grid, dt, taps, k, name) for k, v in bridged.items()}
    if np.ptp(steps) > UNIFORM_TOLERANCE * h:
        warnings.append(f"timestamps jittered (steps {steps.min():.4g}..{steps.max():.4g} s): interpolated onto a "
                        f"uniform {h:.4g} s grid before filtering")
    on_grid, timing = resample_commands(time, cmds, grid, dt)
    report = InputReport(1.0 / h, dt, True, description, tuple(gaps), missing, warnings=tuple(warnings),
                         command_timing=timing, span_s=float(time[-1] - time[0]))
    return PreparedLog(grid, on_grid, out, resample_phases(time, phases, grid), report)


def _resampled(time: np.ndarray, x: np.ndarray, grid: np.ndarray, dt: float, taps: np.ndarray, channel: str,
               name: str) -> np.ndarray:
    """:func:`resample_signal`, refusing a channel whose values overflow it."""
    # values near the float64 limit (a logger's 1e306 N) overflow in the filter or the spline: without this check
    # the channel came back inf/NaN (a silent NaN) or scipy raised a ValueError naming neither file nor channel
    with np.errstate(over="ignore", invalid="ignore"):
        try:
            out = resample_signal(time, x, grid, dt, taps=taps)
        except ValueError:  # CubicSpline refuses the non-finite filter output
            out = np.full(len(grid), np.nan)
    if not np.all(np.isfinite(out)):
        raise RecordingError(f"{name}: {channel} cannot be resampled: its values (largest magnitude "
                             f"{np.max(np.abs(x)):.3g}, SI) overflow the anti-alias filter")
    return out


def control_grid(time: np.ndarray, dt: float) -> np.ndarray:
    """Control times ``t_0 + k dt`` (s), ``k = 0 .. floor((t_last - t_0)/dt)``; ``t_0`` = the first timestamp, the
    end of the first control step (see the module)."""
    n = math.floor((time[-1] - time[0]) / dt + 1e-9)  # tolerance: a log ending on the grid keeps its last step
    return time[0] + dt * np.arange(0, n + 1)


def antialias_filter(h: float, dt: float) -> tuple[np.ndarray, str]:
    """Taps of the linear-phase Kaiser FIR low-pass for a log step ``h`` (s) and control step ``dt`` (s), and a
    description of it for the report."""
    nyquist = 0.5 / dt
    f_pass, f_stop, fs = PASS_FRACTION * nyquist, STOP_FRACTION * nyquist, 1.0 / h
    numtaps, beta = signal.kaiserord(STOP_DB, (f_stop - f_pass) / (0.5 * fs))
    numtaps |= 1  # odd: the centre tap sits on a sample, so the filter delays nothing
    taps = signal.firwin(numtaps, 0.5 * (f_pass + f_stop), window=("kaiser", beta), fs=fs)
    text = (f"zero-phase Kaiser FIR low-pass ({numtaps} taps at {fs:.4g} Hz; pass to {f_pass:.3g} Hz, "
            f"-{STOP_DB:.0f} dB from {f_stop:.3g} Hz), signals read at the end of each {dt:.4g} s control step; "
            "commands: mean of those logged within each control interval; phases: nearest sample")
    return taps, text


def resample_signal(time: np.ndarray, x: np.ndarray, grid: np.ndarray, dt: float,
                    taps: np.ndarray | None = None) -> np.ndarray:
    """A finite signal sampled at ``time`` (s, increasing), low-passed and read at the control times ``grid``.

    The log is first put on a uniform grid at its median step (linear interpolation, only when the timestamps
    are jittered), filtered by :func:`antialias_filter` (centred; beyond the ends the log is reflected oddly through its
    end samples), then read at ``grid`` by cubic interpolation. Within half a filter length of the log's ends
    (about 0.35 s at a 0.1 s control step, whatever the log's rate), a smooth signal stays exact, but noise and a
    tone above the band are attenuated less than inside, down to not at all at the log's last sample (a centred
    filter has only one side of the data there; a one-sided one would delay). Logs of a dig cycle start and end
    at rest, where this matters least.
    """
    time = np.asarray(time, dtype=np.float64)
    h = float(np.median(np.diff(time)))
    fine_t, fine = _uniform(time, np.asarray(x, dtype=np.float64), h)
    if taps is None:
        taps, _ = antialias_filter(h, dt)
    return CubicSpline(fine_t, _antialiased(fine[:, None], h, dt, taps)[:, 0])(grid)


def _antialiased(fine: np.ndarray, h: float, dt: float, taps: np.ndarray) -> np.ndarray:
    """Columns of ``fine`` (samples every ``h`` s × signals) through the anti-alias FIR ``taps``, centred, each
    column reflected oddly through its end levels (:func:`resample_signal`)."""
    pad = min(len(taps) // 2, len(fine) - 1)
    # odd reflection through each end's level (scipy's filtfilt padding, but through a local fit rather than the end
    # sample): keeps the end's level and slope, so a smooth signal stays exact up to the ends, and the end rows do
    # not carry the full noise of one sample (6x the filtered noise at 500 Hz, which the noise model took for a
    # discrepancy in the first and last windows)
    span = min(pad, max(round(dt / h), 1))  # samples in one control step
    first, last = end_level(fine, span), end_level(fine[::-1], span)
    ext = np.concatenate((2 * first - fine[pad:0:-1], fine, 2 * last - fine[-2:-pad - 2:-1]))
    return signal.fftconvolve(ext, taps[:, None], mode="same", axes=0)[pad:pad + len(fine)]


#: Columns resampled at once while building :func:`resampling_operator` (memory: log samples × this × 8 bytes each).
OPERATOR_BATCH = 64


@functools.lru_cache(maxsize=64)
def resampling_operator(steps: int, parts: int, control_dt: float, log_step: float, span: float,
                        tau: float = 0.0) -> sparse.csr_matrix:
    """What a log's sensor filter and its resampling do to a signal known between its control steps, as a matrix.

    A log sampled every ``log_step`` s is low-passed and read at the control steps (:func:`resample_signal`); a
    twin's samples at those steps are not what that gives where a signal changes within a control step (a
    cylinder reaching relief, the bucket meeting the pile: a force jumps by most of its range within one, and the
    anti-alias filter spreads the jump over its neighbours). This is the same resampling applied to a signal read
    every ``control_dt / parts`` s (the sample at ``(j + 1) · control_dt / parts`` s, every ``parts``-th one at a
    control step; cubic between them), on the log's own grid (every ``log_step`` s over ``span`` s from the first
    control step), after a first-order sensor filter of time constant ``tau`` s on that grid where ``tau`` > 0
    (settled on the first sample; as a sensor filters the signal itself, not its readings: filtered between the
    readings instead, an acceleration read every 24 ms came out up to its whole range off a 0.16 s filter's):
    a sparse (``steps``, ``steps · parts``) matrix, each row the weights of one control step's value (within
    ~1e-12 of the filter and :func:`resample_signal`). Control steps past the log's end keep their own sample.

    Built by resampling combs of unit samples spaced wider than the filters reach (0.1–1 s, a filter's memory
    20 τ more), :data:`OPERATOR_BATCH` at a time, and kept for the log's next replays.
    """
    fine_dt = control_dt / parts
    n_fine = steps * parts
    t_fine = fine_dt * np.arange(1, n_fine + 1)
    log_t = control_dt + log_step * np.arange(math.floor(span / log_step + 1e-9) + 1)
    log_t = log_t[log_t <= t_fine[-1] + 1e-9 * fine_dt]
    grid = control_dt * np.arange(1, steps + 1)
    seen = int(np.count_nonzero(grid <= log_t[-1] + 1e-9 * control_dt)) if len(log_t) > 1 else 0
    taps, _ = antialias_filter(log_step, control_dt)
    # how far a unit sample reaches: the odd reflection at an end doubles the FIR's half-length; both cubic
    # interpolations decay by ~0.27 a knot (1e-12 after 20 knots); the sensor filter by 1e-9 after 20.7 τ
    reach = 2 * (len(taps) // 2) * log_step + 20 * (fine_dt + log_step) + 20.7 * max(tau, 0.0)
    comb = min(math.ceil(2 * reach / fine_dt) + 1, n_fine)
    rows, cols, vals = [], [], []
    if seen >= 2:
        centre = grid[:seen] / fine_dt - 1.0  # each control step's own fine sample
        for first in range(0, comb, OPERATOR_BATCH):
            offsets = np.arange(first, min(first + OPERATOR_BATCH, comb))
            y = np.zeros((n_fine, len(offsets)))
            for c, r in enumerate(offsets):
                y[r::comb, c] = 1.0
            x = CubicSpline(t_fine, y, axis=0)(log_t)
            if tau > 0.0:
                x = first_order_filter(x.T, log_step, tau).T
            out = CubicSpline(log_t, _antialiased(x, log_step, control_dt, taps), axis=0)(grid[:seen])
            for c, r in enumerate(offsets):
                tooth = r + comb * np.round((centre - r) / comb)
                ok = (tooth >= 0) & (tooth < n_fine) & (np.abs(out[:, c]) > 0.0)
                rows.append(np.flatnonzero(ok))
                cols.append(tooth[ok].astype(int))
                vals.append(out[ok, c])
    tail = np.arange(seen, steps)
    rows.append(tail)
    cols.append(tail * parts + parts - 1)
    vals.append(np.ones(len(tail)))
    return sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                             shape=(steps, n_fine))


#: Degree of the local least-squares polynomial that gives a log's level at its ends (:func:`end_level`), fitted over
#: one control step of samples: at 500 Hz it leaves 2.8x the filtered noise on the end rows (the end sample's own
#: noise was 6x it and read as a discrepancy in the first window) and is exact to 1e-3 on a 0.7 Hz tone; a longer
#: span straddles the steps a dig cycle's speeds take in its first control steps and biases the end row.
END_DEGREE = 2


def end_level(x: np.ndarray, span: int) -> float | np.ndarray:
    """The level of ``x`` (signal units; samples along the first axis, one signal per column) at its first sample
    from a least-squares polynomial of degree :data:`END_DEGREE` over its first ``span + 1`` samples (the sample
    itself when too few): a smooth signal's value, with the noise of one sample averaged down."""
    n = min(span + 1, len(x))
    if n < 2 * (END_DEGREE + 1):
        return float(x[0]) if x.ndim == 1 else x[0].copy()
    k = np.arange(n, dtype=np.float64) / n
    level = np.polynomial.polynomial.polyfit(k, x[:n], END_DEGREE)[0]
    return float(level) if x.ndim == 1 else level


def resample_commands(time: np.ndarray, commands: np.ndarray, grid: np.ndarray, dt: float
                      ) -> tuple[np.ndarray, float]:
    """Commands of the control intervals ``(t_k - dt, t_k]`` (``t_k`` in ``grid``, s) from a faster log, and how
    uncertain their switching times are.

    Returns:
        (steps, inputs): the mean of the commands logged at times within each interval (a logger reads the command
        at its sampling instant; see the module); an interval without a sample takes the time-weighted mean of the
        logged commands, each held over the logger's interval ending at its timestamp (the first held back over
        ``(grid[0] - dt, time[0]]``); and the timing uncertainty in control steps: 0 when the samples within every
        interval agree (the commands switch on the grid), else half a logger step (:func:`command_timing`).
    """
    time = np.asarray(time, dtype=np.float64)
    cmds = np.asarray(commands, dtype=np.float64).reshape(len(time), -1)
    # interval of each timestamp: k with t_k - dt < t <= t_k (a sample on a grid time ends that step's interval)
    k = np.ceil((time - grid[0]) / dt - GRID_TOLERANCE).astype(int)
    inside = (k >= 0) & (k < len(grid))
    k, x = k[inside], cmds[inside]
    counts = np.bincount(k, minlength=len(grid))
    sums = np.stack([np.bincount(k, weights=x[:, i], minlength=len(grid)) for i in range(x.shape[1])], axis=1)
    out = sums / np.maximum(counts, 1)[:, None]
    empty = counts == 0
    if empty.any():
        out[empty] = _held_means(time, cmds, grid, dt)[empty]
    spread = np.zeros((len(grid), x.shape[1]))
    for i in range(x.shape[1]):
        np.maximum.at(spread[:, i], k, np.abs(x[:, i] - out[k, i]))
    off_grid = bool(np.any(spread > COMMAND_AGREEMENT))
    h = float(np.median(np.diff(time))) if len(time) > 1 else dt
    timing = min(0.5, 0.5 * h / dt) if off_grid else 0.0
    return np.clip(out, -1.0, 1.0), timing  # clip: rounding only, the inputs are within [-1, 1]


def _held_means(time: np.ndarray, cmds: np.ndarray, grid: np.ndarray, dt: float) -> np.ndarray:
    """Time-weighted mean of the logged commands over each control interval, each held over the logger's interval
    ending at its timestamp; the first logged command held back over ``(grid[0] - dt, time[0]]``."""
    # running integral of the held command, exact (piecewise linear) for a piecewise-constant command; a point
    # one control step before the log's start carries the first command held back over that step
    before = min(time[0], grid[0]) - dt
    knots = np.concatenate(([before], time))
    integral = np.vstack((-cmds[:1] * (time[0] - before), np.zeros((1, cmds.shape[1])),
                          np.cumsum(cmds[1:] * np.diff(time)[:, None], axis=0)))
    at = np.stack([np.interp(np.concatenate(([grid[0] - dt], grid)), knots, integral[:, i])
                   for i in range(cmds.shape[1])], axis=1)
    return np.diff(at, axis=0) / dt


def command_timing(report: InputReport | None) -> float:
    """How uncertain the timing of a prepared log's commands is, in control steps
    (:attr:`InputReport.command_timing`): a logger samples a command every ``h`` s, so a change between two
    samples happened somewhere in that interval and the control step's mean command (:func:`resample_commands`)
    is known only to within ``h / 2`` of its switching time. 0 for a log taken as it is (its commands are the
    twin's own) and for one whose commands switch on the control grid."""
    if report is None or not report.resampled:
        return 0.0
    return float(report.command_timing)


def moved_commands(commands: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``commands`` (steps, inputs; each held over its control step) with the change into row ``k + 1`` moved by
    ``shift[k]`` control steps (|shift| ≤ 1): moved later (> 0), row ``k + 1`` keeps the old command over that
    share of its step; moved earlier (< 0), row ``k`` takes the new one over that share; within [-1, 1]."""
    out = np.array(commands, dtype=np.float64, copy=True)
    change = np.diff(out, axis=0)
    later, earlier = np.clip(shift, 0.0, None), np.clip(-np.asarray(shift), 0.0, None)
    out[1:] -= later[:, None] * change
    out[:-1] += earlier[:, None] * change
    return np.clip(out, -1.0, 1.0)


def jittered_commands(commands: np.ndarray, timing: float, rng: np.random.Generator) -> np.ndarray:
    """``commands`` with each change between control steps moved by a uniform draw within ±``timing`` control
    steps (:func:`command_timing`, :func:`moved_commands`)."""
    if timing <= 0 or len(commands) < 2:
        return np.array(commands, dtype=np.float64, copy=True)
    return moved_commands(commands, rng.uniform(-timing, timing, size=len(commands) - 1))


def resample_phases(time: np.ndarray, phases: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """The logged phase nearest in time to each control time."""
    idx = np.clip(np.searchsorted(time, grid), 1, len(time) - 1)
    nearest = np.where(grid - time[idx - 1] <= time[idx] - grid, idx - 1, idx)
    return np.asarray(phases, dtype=object)[nearest]


def bridge_gaps(time: np.ndarray, x: np.ndarray, channel: str, max_span: float, hold: bool = False,
                name: str = "log") -> tuple[np.ndarray, list[tuple[str, float, float]]]:
    """Fill NaN runs of ``x`` (linearly between the neighbours, or by holding the last value when ``hold``; at the
    ends by holding the nearest value) when the span without data is at most ``max_span`` s.

    Returns:
        the filled copy and the gaps ``(channel, t_first_missing, t_last_missing)``.

    Raises:
        RecordingError: a longer gap, naming the channel, its time and its length; or a line between values so
            large that it overflows (naming the channel).
    """
    x = np.array(x, dtype=np.float64, copy=True)
    bad = ~np.isfinite(x)
    if not bad.any():
        return x, []
    good = np.flatnonzero(~bad)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], bad.astype(np.int8), [0]))))
    gaps = []
    for start, stop in zip(edges[::2], edges[1::2], strict=True):  # missing rows start .. stop-1
        before = time[start - 1] if start > 0 else time[start]
        after = time[stop] if stop < len(x) else time[stop - 1]
        span = after - before
        if span > max_span + 1e-9 * max(abs(after), 1.0):
            raise RecordingError(
                f"{name}: {channel} is missing from t = {time[start]:.4g} s to {time[stop - 1]:.4g} s "
                f"({span:.3g} s without data); gaps up to {max_span:.3g} s ({MAX_GAP_STEPS} control steps) are "
                "bridged, a longer one cannot be compared")
        gaps.append((channel, float(time[start]), float(time[stop - 1])))
    if hold:  # the last logged value; before the first one, the first one
        filled = x[good][np.clip(np.searchsorted(good, np.arange(len(x))) - 1, 0, len(good) - 1)]
    else:
        filled = np.interp(time, time[good], x[good])
    x[bad] = filled[bad]
    if not np.all(np.isfinite(x)):  # a line between values near the float64 limit overflows: no silent NaN
        raise RecordingError(f"{name}: {channel} cannot be bridged: the line between its values around a gap "
                             f"(largest magnitude {np.max(np.abs(x[good])):.3g}, SI) overflows")
    return x, gaps


def _dropouts(time: np.ndarray, h: float, max_span: float, name: str) -> list[tuple[str, float, float]]:
    steps = np.diff(time)
    out = []
    for j in np.flatnonzero(steps > DROPOUT_FACTOR * h):
        if steps[j] > max_span:
            raise RecordingError(f"{name}: no rows from t = {time[j]:.4g} s to {time[j + 1]:.4g} s "
                                 f"({steps[j]:.3g} s); dropouts up to {max_span:.3g} s are bridged")
        out.append(("time", float(time[j] + h), float(time[j + 1] - h)))
    return out


def _uniform(time: np.ndarray, x: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    steps = np.diff(time)
    if np.ptp(steps) <= UNIFORM_TOLERANCE * h:
        return time, x
    n = math.floor((time[-1] - time[0]) / h + 1e-9) + 1
    fine_t = time[0] + h * np.arange(n)
    return fine_t, np.interp(fine_t, time, x)


# -- time offset -------------------------------------------------------------------------------------------------

def estimate_offset(real: Mapping[str, np.ndarray], twin: Mapping[str, np.ndarray], dt: float,
                    channels: Sequence[str] = KINEMATIC, max_shift: float = 1.0,
                    scale: Mapping[str, float] | None = None) -> OffsetEstimate:
    """The time offset (s) that best aligns a log's signals with the twin's replay of its commands.

    Least squares over fractional shifts: each channel is normalised by the twin's standard deviation, the twin is
    read at ``t - s`` by cubic interpolation, and the mean squared residual over the rows that every shift in
    ``[-max_shift, max_shift]`` keeps inside the record is minimised (a scan at whole steps, then a bounded
    refinement within a step of the best). Positive: the log lags the twin.

    Args:
        real, twin: SI signals (steps,) at the same control times, step ``dt`` (s).
        channels: channels to use where present and finite in both (default: the kinematic ones).
        max_shift: largest offset searched, s.
        scale: each channel's normaliser (default: the twin's standard deviation over the rows given; give the
            whole record's when estimating on its first rows, where a channel that barely moves yet would get a
            normaliser near zero and outweigh the rest).
    """
    names = tuple(c for c in channels if c in real and c in twin
                  and np.all(np.isfinite(real[c])) and np.all(np.isfinite(twin[c])) and np.std(twin[c]) > 0
                  and (scale is None or scale.get(c, 0.0) > 0))
    if not names:
        return OffsetEstimate(0.0, False, float("nan"), float("nan"), ())
    n = len(twin[names[0]])
    m = math.ceil(max_shift / dt)
    if n - 2 * m < 4:  # too short for the search range: shrink it to leave a few rows to compare
        m = max((n - 4) // 2, 0)
    t = dt * np.arange(n)
    keep = slice(m, n - m)
    norm = {c: float(scale[c]) if scale is not None else float(np.std(twin[c])) for c in names}
    splines = {c: CubicSpline(t, twin[c] / norm[c]) for c in names}
    target = {c: real[c][keep] / norm[c] for c in names}

    def cost(s: float) -> float:
        return float(np.mean([np.mean((target[c] - splines[c](t[keep] - s)) ** 2) for c in names]))

    shifts = dt * np.arange(-m, m + 1)
    costs = np.array([cost(s) for s in shifts])
    best = int(np.argmin(costs))
    lo, hi = shifts[max(best - 1, 0)], shifts[min(best + 1, len(shifts) - 1)]
    s_best, c_best = float(shifts[best]), float(costs[best])
    if hi > lo:
        res = optimize.minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4 * dt})
        if res.fun < c_best:
            s_best, c_best = float(res.x), float(res.fun)
    c_zero = cost(0.0)
    significant = (abs(s_best) >= MIN_OFFSET_STEPS * dt) and c_best <= (1.0 - MIN_OFFSET_GAIN) * c_zero
    residual = np.stack([target[c] - splines[c](t[keep] - s_best) for c in names])
    se = _offset_standard_error(cost, s_best, c_best, residual, dt)
    return OffsetEstimate(s_best, bool(significant), c_zero, c_best, names, se)


def _offset_standard_error(cost: Callable[[float], float], s: float, c: float, residual: np.ndarray,
                           dt: float) -> float:
    """Standard error (s) of the least-squares offset ``s`` of :func:`estimate_offset`: with ``cost`` the mean of
    the squared ``residual`` (channels, rows) over its ``N`` entries, ``var(s) = 2 c / (N_eff c'')``, the
    curvature ``c''`` by central differences (a twentieth of a step) and ``N_eff`` the entries over the lag-1
    autocorrelation's inflation ``(1 + ρ) / (1 − ρ)`` (pooled over channels, ρ clipped to [0, 0.95])."""
    h = 0.05 * dt
    curvature = (cost(s + h) - 2.0 * c + cost(s - h)) / h**2
    rows = residual.shape[1]
    if curvature <= 0.0 or rows < 3:
        return float("nan")
    r = residual - residual.mean(axis=1, keepdims=True)
    denom = float(np.sum(r * r))
    rho = float(np.clip(np.sum(r[:, 1:] * r[:, :-1]) / denom, 0.0, 0.95)) if denom > 0 else 0.0
    n_eff = residual.size * (1.0 - rho) / (1.0 + rho)
    return float(math.sqrt(2.0 * c / (n_eff * curvature)))


def circuit_offsets(real: Mapping[str, np.ndarray], twin: Mapping[str, np.ndarray], dt: float,
                    scale: Mapping[str, float] | None = None) -> dict[str, OffsetEstimate]:
    """Each circuit's own offset (:data:`CIRCUITS`; :func:`estimate_offset` on its channels)."""
    return {name: estimate_offset(real, twin, dt, channels, scale=scale) for name, channels in CIRCUITS.items()}


def circuits_agree(estimates: Mapping[str, OffsetEstimate], dt: float, offset: float | None = None) -> bool:
    """Whether an offset is one of the whole log: at least two circuits show a significant offset, all the
    significant ones within :data:`OFFSET_AGREEMENT` control steps of each other (and of ``offset``, s, if given).
    A circuit that did not move in the rows compared shows no offset and vetoes nothing."""
    seen = [e.offset for e in estimates.values() if e.significant]
    seen_all = [*seen, offset] if offset is not None else seen
    return len(seen) >= 2 and max(seen_all) - min(seen_all) <= OFFSET_AGREEMENT * dt


def delayed(x: np.ndarray, dt: float, offset: float) -> np.ndarray:
    """``x`` (sampled every ``dt`` s along its last axis) read ``offset`` s late, as a logger whose clock runs
    ``offset`` behind the commands' would log it: ``y(t) = x(t - offset)`` by cubic interpolation, the first and
    last samples held beyond the record."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[-1]
    if offset == 0.0 or n < 2 or not np.all(np.isfinite(x)):
        return x.copy()
    t = dt * np.arange(n)
    return CubicSpline(t, x, axis=-1)(np.clip(t - offset, 0.0, t[-1]))


# -- sensor low-pass ---------------------------------------------------------------------------------------------

def first_order_filter(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """``x`` (sampled every ``dt`` s along its last axis: one channel, or channels × samples) through a
    first-order lag ``tau dy/dt = x - y`` (``tau`` in s).

    Exact discretisation for an input linear between samples: with ``a = exp(-dt/tau)`` and
    ``c = tau (1 - a) / dt``, ``y_k = a y_{k-1} + (1 - c) x_k + (c - a) x_{k-1}``; the sensor starts settled
    (``y_0 = x_0``). ``tau <= 0`` returns a copy of ``x``.
    """
    x = np.asarray(x, dtype=np.float64)
    if tau <= 0 or x.shape[-1] == 0:
        return x.copy()
    a = math.exp(-dt / tau)
    c = tau * (1.0 - a) / dt
    # settled start: at a constant input x the filter's one state (transposed direct form II) is y - (1 - c) x = c x,
    # what signal.lfilter_zi returns through a companion-matrix solve on every call (equal to 2e-16)
    y, _ = signal.lfilter((1.0 - c, c - a), (1.0, -a), x, zi=c * x[..., :1])
    return y


def filter_sensitivity(y: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """∂y/∂τ (signal units per s) of a first-order filter's output ``y`` (sampled every ``dt`` s, time constant
    ``tau`` s): differentiating ``τ ẏ + y = x`` by τ gives ``(τ d/dt + 1) ∂y/∂τ = −ẏ``, i.e. the filter applied
    to −ẏ (:func:`first_order_filter`; ẏ by central differences). What a time constant slightly off leaves:
    ``δτ · ∂y/∂τ``."""
    if tau <= 0:
        return np.zeros_like(np.asarray(y, dtype=np.float64))
    return -first_order_filter(np.gradient(np.asarray(y, dtype=np.float64), dt), dt, tau)


def tau_standard_error(real: np.ndarray, twin: np.ndarray, dt: float, tau: float) -> float:
    """Standard error (s) of a channel's first-order filter time constant fitted at ``tau`` > 0 against ``twin``
    (both sampled every ``dt`` s): the residual's noise SD (robust, from its first differences, as if white) over
    the root of Σ (∂y/∂τ)² (:func:`filter_sensitivity`; the Gauss–Newton curvature). Infinite for a channel that
    does not move (nothing there tells one time constant from another)."""
    y = first_order_filter(np.asarray(twin, dtype=np.float64), dt, tau)
    info = float(np.sum(filter_sensitivity(y, dt, tau) ** 2))
    d = np.diff(np.asarray(real, dtype=np.float64) - y)
    if info <= 0.0 or len(d) < 2:
        return math.inf
    sd = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(2.0)
    return sd / math.sqrt(info)


def filtered_samples(x: np.ndarray, dt: float, tau: float, parts: int = 1) -> np.ndarray:
    """``x`` read ``parts`` times per sample step ``dt`` (s; the ``parts``-th of each group at the sample, the
    first ``dt / parts`` after the previous one) through a first-order filter of ``tau`` s, at the samples: a
    sensor filters the signal between the samples, not a line through them."""
    if parts == 1:
        return first_order_filter(x, dt, tau)
    return first_order_filter(x, dt / parts, tau)[..., parts - 1::parts]


def estimate_sensor_tau(real: Mapping[str, np.ndarray], twin: Mapping[str, np.ndarray], dt: float,
                        channels: Sequence[str] | None = None, parts: int = 1) -> float:
    """One first-order sensor time constant (s) common to ``channels`` (default: every compared channel present
    and finite in both): the ``tau`` in ``[0, TAU_MAX]`` minimising the mean squared residual of ``real`` against
    the twin passed through :func:`first_order_filter` (each channel normalised by the twin's spread), found by
    :func:`best_tau`; 0 when no filter lowers the residual by :data:`MIN_TAU_GAIN`. With ``parts`` > 1 the twin
    is read that many times per sample of ``real`` and filtered there (:func:`filtered_samples`).
    """
    names = _filterable(real, twin, channels)
    if not names:
        return 0.0
    scale = {c: float(np.std(twin[c][parts - 1::parts])) for c in names}

    def cost(tau: float) -> float:
        return float(np.mean([np.mean(((real[c] - filtered_samples(twin[c], dt, tau, parts)) / scale[c]) ** 2)
                              for c in names]))

    tau, c_tau, c_none = best_tau(cost, dt)
    return tau if c_tau <= (1.0 - MIN_TAU_GAIN) * c_none else 0.0


def estimate_channel_taus(real: Mapping[str, np.ndarray], twin: Mapping[str, np.ndarray], dt: float,
                          channels: Sequence[str] | None = None, parts: int = 1) -> dict[str, float]:
    """A first-order sensor time constant (s) per channel of ``channels`` (default: every compared channel present
    and finite in both): for each, the ``tau`` in ``[0, TAU_MAX]`` minimising that channel's mean squared residual
    of ``real`` against the twin through :func:`first_order_filter` (the search of :func:`estimate_sensor_tau` on
    one channel, without its gain threshold: a channel whose filter gains nothing gets the best ``tau`` all the
    same, 0 when none lowers its residual).

    Sensors of one logger need not share a filter (a load pin's amplifier, a pressure transducer's snubber, an
    inclinometer's averaging differ), and a common ``tau`` leaves each channel the lag by which its own differs,
    which reads as a discrepancy. Call it only where a common filter was found (:func:`estimate_sensor_tau` > 0):
    a lag on one channel of an unfiltered log is a sensor fault the diagnosis names (``sensor_delay``).
    ``parts``: as in :func:`estimate_sensor_tau`.
    """
    out = {}
    for c in _filterable(real, twin, channels):

        def cost(tau: float, c: str = c) -> float:
            return float(np.mean((real[c] - filtered_samples(twin[c], dt, tau, parts)) ** 2))

        out[c] = best_tau(cost, dt)[0]
    return out


def _filterable(real: Mapping[str, np.ndarray], twin: Mapping[str, np.ndarray],
                channels: Sequence[str] | None) -> list[str]:
    """The channels of ``channels`` (default: the compared ones) present and finite in both, the twin's not
    constant: those a sensor filter can be fitted on."""
    chosen = channels if channels is not None else COMPARED
    return [c for c in chosen if c in real and c in twin and np.all(np.isfinite(real[c]))
            and np.all(np.isfinite(twin[c])) and np.std(twin[c]) > 0]


def best_tau(cost: Callable[[float], float], dt: float) -> tuple[float, float, float]:
    """(tau, its cost, the cost without a filter) of the ``tau`` (s) in ``[0, TAU_MAX]`` minimising ``cost``: a
    scan on a geometric grid (24 points, ~30 % apart, from 1 % of the control step ``dt``), then a bounded scalar
    search around the best point; tau 0 when no grid point beats no filter."""
    grid = np.concatenate(([0.0], np.geomspace(0.01 * dt, TAU_MAX, 24)))
    costs = np.array([cost(v) for v in grid])
    best = int(np.argmin(costs))
    if best == 0:
        return 0.0, float(costs[0]), float(costs[0])
    lo, hi = grid[best - 1], grid[min(best + 1, len(grid) - 1)]
    res = optimize.minimize_scalar(cost, bounds=(lo, hi), method="bounded", options={"xatol": 1e-4})
    if res.fun < costs[best]:
        return float(res.x), float(res.fun), float(costs[0])
    return float(grid[best]), float(costs[best]), float(costs[0])


__all__ = [
    "KINEMATIC", "MAX_GAP_STEPS", "InputReport", "OffsetEstimate", "PreparedLog",
    "antialias_filter", "best_tau", "bridge_gaps", "command_timing", "control_grid", "delayed", "end_level",
    "estimate_channel_taus", "estimate_offset", "estimate_sensor_tau", "filter_sensitivity", "filtered_samples",
    "first_order_filter", "jittered_commands", "moved_commands", "prepare_log", "resample_commands",
    "resample_phases", "resample_signal", "tau_standard_error",
]
