"""Before comparing a log with its twin: the twin's start when the log has no seed, a common sensor filter, a
time offset between the log's signals and its commands.

:func:`align` takes the analysed episode and the nominal twin and returns both as they should be compared, plus
an :class:`Alignment` saying what was estimated (reported in the diagnosis). Each estimate is applied only when it
is worth it (``estimate_offset``'s and ``estimate_sensor_tau``'s own thresholds); an offset is applied only when
the lift and the tilt circuits agree on it (:data:`OFFSET_AGREEMENT`): a dead time in one actuator, which the
catalogue names, moves one circuit only.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from discrepancy.data.episode import EpisodeData
from discrepancy.data.fieldlog import (
    OffsetEstimate,
    estimate_channel_taus,
    estimate_offset,
    estimate_sensor_tau,
    first_order_filter,
    shift_signals,
)
from discrepancy.twin.plant import Plan
from discrepancy.twin.runner import Runner
from discrepancy.twin.spec import SimResult, TwinSpec
from discrepancy.twin.start import StartEstimate, estimate_start

LIFT = ("lift_extension", "boom_angle", "lift_speed")  # channels moved by the lift circuit
TILT = ("tilt_extension", "bucket_pitch", "tilt_speed")  # ... by the tilt circuit
OFFSET_AGREEMENT = 0.5  # the circuits' offsets may differ by this many control steps
REFINE_START = 2  # re-estimates of the start after the offset and sensor filter seen against the one before
TOLERANCE = 0.25  # control steps: an offset or filter time constant that moved less is settled


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
    return {k: first_order_filter(v, dt, tau) for k, v in result.signals.items()} if tau > 0 else result.signals


def _offset(ep: EpisodeData, twin: dict, notes: list[str]) -> tuple[OffsetEstimate, bool]:
    """The log's offset against ``twin`` and whether to undo it (both circuits agree; see the module)."""
    offset = estimate_offset(ep.signals, twin, ep.dt)
    if not offset.significant:
        return offset, False
    lift, tilt = estimate_offset(ep.signals, twin, ep.dt, LIFT), estimate_offset(ep.signals, twin, ep.dt, TILT)
    if lift.significant and tilt.significant and abs(lift.offset - tilt.offset) <= OFFSET_AGREEMENT * ep.dt:
        return offset, True
    notes.append(f"the kinematic channels lag the commands by {offset.offset:.3g} s, but the lift and tilt circuits "
                 "disagree: left to the diagnosis (an actuator dead time?)")
    return offset, False


def _head(signals: dict[str, np.ndarray], rows: int) -> dict[str, np.ndarray]:
    return {c: v[:rows] for c, v in signals.items()}


def _channel_taus(ep: EpisodeData, spec: TwinSpec, runner: Runner, nominal: SimResult,
                  shifted: bool, rows: int) -> tuple[tuple[str, float], ...]:
    """Each channel's own sensor time constant (s) against the twin over the first ``rows`` rows (the log ``ep``
    as compared, its offset undone when ``shifted``; ``nominal`` the unfiltered replay of the commands before
    that), where it differs from the common ``spec.sensor_tau`` by at least :data:`TOLERANCE` control steps
    (:func:`estimate_channel_taus`)."""
    if shifted:
        again = runner.with_twin(dataclasses.replace(spec, sensor_tau=0.0, sensor_taus=())).run_many(
            ep.commands, [Plan()])[0]
        nominal = nominal if again.error else again
    rows = min(rows, len(ep))
    taus = estimate_channel_taus(_head(ep.signals, rows), _head(nominal.signals, rows), ep.dt)
    return tuple(sorted((c, t) for c, t in taus.items() if abs(t - spec.sensor_tau) >= TOLERANCE * ep.dt))


def align(ep: EpisodeData, spec: TwinSpec, runner: Runner) -> tuple[EpisodeData, TwinSpec, Alignment]:
    """The episode and twin to compare, and what was estimated to get them (see the module).

    Order: an offset against the default start first (the kinematics before the bucket meets the pile do not depend
    on it), then the start on the log so aligned, then the sensor filter and what is left of the offset against
    the twin from that start; the offsets add up and the log is shifted once."""
    notes: list[str] = []
    start, total, applied, offset = None, 0.0, False, None
    if ep.seed is None:
        first = runner.with_twin(spec).run_many(ep.commands, [Plan()])[0]
        if not first.error:  # against the default start: a first guess, checked once the start is known
            guess = estimate_offset(ep.signals, first.signals, ep.dt)
            total = guess.offset if guess.significant else 0.0
        # a filter the twin does not declare is fitted jointly with the start (each replay through its best
        # filter, see estimate_start): a lag fitted afterwards absorbs a pile misplaced to make up for it
        profile = spec.sensor_tau == 0.0
        for k in range(REFINE_START + 1):  # the start on the log so aligned, then the offset against it
            held = int(np.ceil(max(-total, 0.0) / ep.dt - 1e-9))  # rows a negative offset leaves unlogged
            shifted = shift_signals(ep, total) if total else ep
            start = estimate_start(shifted, runner.with_twin(spec), held, profile_filter=profile)
            spec = dataclasses.replace(spec, start=start.options, start_draws=start.draws)
            again = runner.with_twin(spec).run_many(ep.commands, [Plan()])[0]
            if again.error or k == REFINE_START:
                break
            seen = _filtered(again, ep.dt, start.sensor_tau) if profile else again.signals
            refined, undo = _offset(ep, seen, [])
            new_total = refined.offset if undo else 0.0
            if abs(new_total - total) <= TOLERANCE * ep.dt:
                break
            total = new_total
        applied, offset = total != 0.0, (estimate_offset(ep.signals, again.signals, ep.dt) if total else None)
        assert start is not None
        notes.append(f"the log has no reset seed: start pose and pile estimated from it ({start.replays} replays; "
                     f"misfit {start.misfit_default:.3g} -> {start.misfit:.3g})")
        if start.unidentified:
            unseen = ", ".join(k.removeprefix("pile_").replace("_", " ") for k in start.unidentified)
            notes.append(f"the log does not show the pile's {unseen} (the bucket never reaches it): left at the "
                         "twin's nominal value")
    shifted = shift_signals(ep, total) if total else ep
    nominal = runner.with_twin(spec).run_many(shifted.commands, [Plan()])[0]
    if nominal.error:
        return ep, spec, Alignment(start, 0.0, offset, applied, tuple(notes))
    # where the start was estimated, the filter is fitted on the rows it was fitted on: later in the dig a twin
    # from a start the log cannot pin down differs by more than any filter (see estimate_start)
    trusted = start.rows if start is not None and start.rows else len(shifted)
    if start is not None and spec.sensor_tau == 0.0:  # fitted jointly with the start
        tau = start.sensor_tau
    else:
        tau = estimate_sensor_tau(_head(shifted.signals, trusted), _head(nominal.signals, trusted), ep.dt)
    rest, undo = _offset(shifted, _filtered(nominal, ep.dt, tau), notes)
    if undo:
        total, applied, offset = total + rest.offset, True, rest
    if applied:
        ep = shift_signals(ep, total)
        notes.append(f"time offset between the log's signals and its commands: {total:.3g} s, undone")
    if tau > 0:
        spec = dataclasses.replace(spec, sensor_tau=tau, sensor_taus=_channel_taus(ep, spec, runner, nominal,
                                                                                  applied, trusted))
        notes.append(f"the log's channels went through a first-order sensor filter: tau {tau:.3g} s estimated, "
                     "applied to the twin")
        if spec.sensor_taus:
            own = ", ".join(f"{c} {t:.3g}" for c, t in spec.sensor_taus)
            notes.append(f"each channel's own sensor filter, tau s (applied to the twin): {own}")
    if ep.input_report is not None:
        ep = dataclasses.replace(ep, input_report=dataclasses.replace(ep.input_report, sensor_tau=tau))
    if offset is not None and applied:
        offset = dataclasses.replace(offset, offset=total)
    return ep, spec, Alignment(start, tau, offset if offset is not None else rest, applied, tuple(notes))
