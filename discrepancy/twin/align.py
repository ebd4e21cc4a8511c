"""Before comparing a log with its twin: the twin's start when the log has no seed, a common sensor filter, a
time offset between the log's signals and its commands.

:func:`align` takes the analysed episode and the nominal twin and returns both as they should be compared, plus
an :class:`Alignment` saying what was estimated (reported in the diagnosis). Each estimate is applied only when it
is worth it (``estimate_offset``'s and ``estimate_sensor_tau``'s own thresholds; for a log without seed, the
joint fit's, see ``estimate_start``); an offset found against the twin is applied only when two of the machine's
circuits (lift, tilt, drive) show it alike (:func:`~discrepancy.data.fieldlog.circuits_agree`): a dead time in one
actuator, which the catalogue names, moves one circuit only. An offset applied is known to within its standard
error, which the null carries (``TwinSpec.offset_spread``); a log whose signals lead its commands is compared only
on the rows whose commands it holds (:func:`_compared_rows`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from discrepancy.data.channels import RecordingError
from discrepancy.data.episode import EpisodeData, signal_spread
from discrepancy.data.fieldlog import (
    MIN_OFFSET_STEPS,
    TAU_MAX,
    OffsetEstimate,
    circuit_offsets,
    circuits_agree,
    estimate_channel_taus,
    estimate_offset,
    estimate_sensor_tau,
    filtered_samples,
    tau_standard_error,
)
from discrepancy.twin.plant import Plan
from discrepancy.twin.runner import Runner
from discrepancy.twin.spec import SimResult, TwinSpec
from discrepancy.twin.start import StartEstimate, estimate_start

TOLERANCE = 0.25  # control steps: a channel's own filter time constant this close to the common one is the common one
#: ... and one within this many of its standard errors (``tau_standard_error``) of the common one is not told apart
#: from it: a channel that barely moves on the rows it is fitted on gets any time constant (benchmark seed 24 case
#: 0, a low-passed null: ``tilt_extension`` 1 s, the search's limit, for a true 0.08 s, and 5 windows located)
SIGNIFICANT = 3.0
#: Fewest rows a log must keep with known commands (a dig's approach at the control step is about 10).
MIN_COMPARED = 10


@dataclass(frozen=True)
class Alignment:
    """What :func:`align` estimated: the start (None when the log has a seed), the sensor filter time constant (s,
    0: none), the offset (None when not estimated) and whether it was applied, and notes for the report."""

    start: StartEstimate | None
    sensor_tau: float
    offset: OffsetEstimate | None
    offset_applied: bool
    notes: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        return {"start": self.start.to_dict() if self.start else None, "sensor_tau_s": self.sensor_tau,
                "offset": self.offset.to_dict() if self.offset else None, "offset_applied": self.offset_applied,
                "notes": list(self.notes)}


def _filtered(result: SimResult, dt: float, tau: float) -> dict:
    """``result``'s signals through a sensor filter of ``tau`` s: filtered between the control steps where the
    replay was read there (a sensor filters the signal, not a line through its samples)."""
    if tau <= 0:
        return result.signals
    read, parts = _read(result, dt, len(result.phases))
    return {k: filtered_samples(v, dt, tau, parts) for k, v in read.items()}


def _read(result: SimResult, dt: float, rows: int) -> tuple[dict[str, np.ndarray], int]:
    """``result``'s signals over its first ``rows`` control steps as a sensor filter meets them: read between the
    steps where the replay was (with the readings per step), else the control samples (1)."""
    if result.between is None:
        return _head(result.signals, rows), 1
    parts = round(dt / result.between.dt)
    return _head(result.between.signals, rows * parts), parts


def _offset(ep: EpisodeData, twin: dict, notes: list[str], scale: dict[str, float] | None = None
            ) -> tuple[OffsetEstimate, bool]:
    """The log's offset against ``twin`` and whether to undo it (two circuits agree; see the module); ``scale``:
    the channels' normalisers (see ``estimate_offset``)."""
    offset = estimate_offset(ep.signals, twin, ep.dt, scale=scale)
    if not offset.significant:
        return offset, False
    per = circuit_offsets(ep.signals, twin, ep.dt, scale)
    if circuits_agree(per, ep.dt, offset.offset):
        return offset, True
    notes.append(f"the kinematic channels lag the commands by {offset.offset:.3g} s, but the machine's circuits "
                 "disagree: left to the diagnosis (an actuator dead time?)")
    return offset, False


def _resampled_alike(ep: EpisodeData, spec: TwinSpec, notes: list[str]) -> TwinSpec:
    """``spec`` reading its signals as ``ep``'s log was resampled (``TwinSpec.log_step``, ``log_span``) where it was
    sampled faster than the control step: the anti-alias filter spreads a change within a control step (a force
    jumping by most of its range as a cylinder reaches relief) over its neighbours, which the twin's samples alone
    do not (a perfect twin was up to 20–50 % of a force's range off at such rows once read between its samples,
    where the noise of a 200–500 Hz log low-passed is a fraction of a percent)."""
    report = ep.input_report
    if report is None or not report.resampled or not report.span_s or not report.original_rate_hz > 0:
        return spec
    notes.append(f"the log was resampled from {report.original_rate_hz:.4g} Hz to the control step: the twin is "
                 "read between its control steps too and resampled alike")
    return dataclasses.replace(spec, log_step=1.0 / report.original_rate_hz, log_span=float(report.span_s))


def _compared_rows(ep: EpisodeData, spec: TwinSpec, notes: list[str]) -> tuple[EpisodeData, TwinSpec]:
    """A log whose signals lead its commands (``spec.time_offset`` < 0) reads, on its last rows, the machine under
    commands logged after them: those rows are not compared (their commands become the twin's
    ``command_tail``); any other log is returned as it is.

    Raises:
        RecordingError: the offset leaves fewer than :data:`MIN_COMPARED` rows.
    """
    lead = spec.lead_steps(ep.dt)
    if lead == 0:
        return ep, spec
    keep = len(ep) - lead
    if keep < MIN_COMPARED:
        raise RecordingError(f"{ep.name}: its signals lead its commands by {-spec.time_offset:.3g} s, which leaves "
                             f"{max(keep, 0)} of its {len(ep)} rows with known commands (at least {MIN_COMPARED} "
                             "needed)")
    notes.append(f"the last {lead} rows read the machine under commands logged after them (the signals lead by "
                 f"{-spec.time_offset:.3g} s): not compared")
    tail = tuple((float(a), float(b), float(c)) for a, b, c in ep.commands[keep:])
    return ep.head(keep), dataclasses.replace(spec, command_tail=tail)


def _head(signals: dict[str, np.ndarray], rows: int) -> dict[str, np.ndarray]:
    return {c: v[:rows] for c, v in signals.items()}


def _channel_taus(ep: EpisodeData, spec: TwinSpec, runner: Runner, rows: int, common: float,
                  plain: SimResult | None = None) -> tuple[tuple[str, float], ...]:
    """Each channel's own sensor time constant (s) against the twin ``spec`` without its filters (``plain``, that
    replay where the caller has it; else one replay) over the first ``rows`` rows, where it differs from the common
    time constant ``common`` (s, the one applied to every other channel) by at least :data:`TOLERANCE` control steps
    and :data:`SIGNIFICANT` standard errors (:func:`estimate_channel_taus`), and lies inside the search: one at its
    bound (``TAU_MAX``) is a residual that keeps falling however much the channel is smoothed, which a misfit of
    the start does and a sensor filter does not (benchmark seed 86 case 39: ``F21_z`` and ``F31_z`` at 1 s for a
    true 0.21 and 0.26 s, ``F21_z`` then located in the penetration of a null)."""
    nominal = plain or runner.with_twin(dataclasses.replace(spec, sensor_tau=0.0, sensor_taus=())).run_many(
        ep.commands, [Plan()], between=spec.log_step <= 0.0)[0]
    if nominal.error:
        return ()
    rows = min(rows, len(ep))
    real, twin = _head(ep.signals, rows), _head(nominal.signals, rows)
    fine, parts = _read(nominal, ep.dt, rows)
    taus = estimate_channel_taus(real, fine, ep.dt, parts=parts)
    return tuple(sorted((c, t) for c, t in taus.items() if abs(t - common) >= TOLERANCE * ep.dt and t < TAU_MAX
                        and (t <= 0.0 or abs(t - common) >= SIGNIFICANT * tau_standard_error(real[c], twin[c],
                                                                                             ep.dt, t))))


def align(ep: EpisodeData, spec: TwinSpec, runner: Runner) -> tuple[EpisodeData, TwinSpec, Alignment]:
    """The episode and twin to compare, and what was estimated to get them (see the module).

    A log without seed: its start, a common sensor filter and a time offset fitted together on its first rows
    (:func:`estimate_start`); then each channel's own filter and what is left of the offset against the twin from
    that start, on the same rows; the offsets add up and the twin is read at the log's times
    (``TwinSpec.time_offset``). A log with a seed: the filter and the offset against the twin from its seed.
    A log resampled to the control step is compared with the twin resampled alike (``TwinSpec.log_step``) from
    the start."""
    notes: list[str] = []
    spec = _resampled_alike(ep, spec, notes)
    fine = spec.log_step <= 0.0  # a log at the control step: filters and offsets act between the twin's steps
    start, total, applied, offset = None, 0.0, False, None
    if ep.seed is None:
        # the start, a filter the twin does not declare and the time offset are fitted together (see
        # estimate_start): one after the other, a lag reads as a pile met later, a pile misplaced as a lag
        profile = spec.sensor_tau == 0.0
        start = estimate_start(ep, runner.with_twin(spec), profile_filter=profile, fit_offset=True)
        spec = dataclasses.replace(spec, start=start.options, start_draws=start.draws)
        total = start.offset
        applied = total != 0.0
        if applied:
            again = runner.with_twin(spec).run_many(ep.commands, [Plan()], between=fine)[0]
            seen = _filtered(again, ep.dt, start.sensor_tau) if profile else again.signals
            offset = estimate_offset(_head(ep.signals, start.rows), _head(seen, start.rows), ep.dt,
                                     scale=signal_spread(seen))
        assert start is not None
        notes.append(f"the log has no reset seed: start pose and pile estimated from it ({start.replays} replays; "
                     f"misfit {start.misfit_default:.3g} -> {start.misfit:.3g})")
        if start.unidentified:
            unseen = ", ".join(k.removeprefix("pile_").replace("_", " ") for k in start.unidentified)
            notes.append(f"the log does not show the pile's {unseen} (the bucket never reaches it): left at the "
                         "twin's nominal value")
    spec = dataclasses.replace(spec, time_offset=total)
    nominal = runner.with_twin(spec).run_many(ep.commands, [Plan()], between=fine)[0]
    if nominal.error:
        return ep, spec, Alignment(start, 0.0, offset, applied, tuple(notes))
    # where the start was estimated, the filter is fitted on the rows it was fitted on: later in the dig a twin
    # from a start the log cannot pin down differs by more than any filter (see estimate_start)
    trusted = start.rows if start is not None and start.rows else len(ep)
    if start is not None and spec.sensor_tau == 0.0:  # fitted jointly with the start
        tau = start.sensor_tau
    else:
        twin, parts = _read(nominal, ep.dt, trusted)
        tau = estimate_sensor_tau(_head(ep.signals, trusted), twin, ep.dt, parts=parts)
    seen = _filtered(nominal, ep.dt, tau)
    rest, undo = _offset(ep.head(trusted), _head(seen, trusted), notes, signal_spread(seen))
    # the replay above is the twin without filters at the offset kept, unless the spec declares a filter or the
    # offset moved: then each channel's filter needs a replay of its own
    plain = nominal if not undo and spec.sensor_tau == 0.0 and not spec.sensor_taus else None
    if undo:
        total, applied, offset = total + rest.offset, True, rest
        spec = dataclasses.replace(spec, time_offset=total)
    elif ep.seed is None and abs(rest.offset) >= MIN_OFFSET_STEPS * ep.dt:
        # a field log's clock is its logger's (a log with its reset seed is the twin's own run): an offset it
        # suggests (a quarter step or more) and does not confirm is not undone, but it is not known to be zero
        # either, and the null carries one that size (log 27:19 of the benchmark, 0.09 s off: the lift speed's
        # samples at its valve's switches, replayed 0.06 s off the log, read as a discrepancy)
        spec = dataclasses.replace(spec, offset_spread=abs(rest.offset))
    if applied:
        se = offset.standard_error if offset is not None else float("nan")
        if math.isfinite(se):  # the offset applied is known to within its standard error, which the null carries
            spec = dataclasses.replace(spec, offset_spread=se)
        notes.append(f"time offset between the log's signals and its commands: {total:.3g} s (standard error "
                     f"{se:.2g} s), applied to the twin (read at the log's times)")
    if tau > 0:
        spec = dataclasses.replace(spec, sensor_tau=tau,
                                   sensor_taus=_channel_taus(ep, spec, runner, trusted, tau, plain))
        notes.append(f"the log's channels went through a first-order sensor filter: tau {tau:.3g} s estimated, "
                     "applied to the twin")
        if spec.sensor_taus:
            own = ", ".join(f"{c} {t:.3g}" for c, t in spec.sensor_taus)
            notes.append(f"each channel's own sensor filter, tau s (applied to the twin): {own}")
    if ep.input_report is not None:
        ep = dataclasses.replace(ep, input_report=dataclasses.replace(
            ep.input_report, sensor_tau=tau, time_offset=float(total) if applied else ep.input_report.time_offset))
    if offset is not None and applied:
        offset = dataclasses.replace(offset, offset=total)
    ep, spec = _compared_rows(ep, spec, notes)
    return ep, spec, Alignment(start, tau, offset if offset is not None else rest, applied, tuple(notes))
