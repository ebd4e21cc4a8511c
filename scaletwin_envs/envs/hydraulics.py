"""From a normalised operator command to cylinder and drive speeds: flow limits, end cushions and valve hold."""

from __future__ import annotations

from dataclasses import dataclass

from scaletwin_envs.specs.loader import CylinderSpec

HOLD_BAND = 0.02  # |command| below this closes the valve (holds position)
CUSHION = 0.03  # fraction of the stroke over which the cylinder slows down at each end


@dataclass
class CylinderValve:
    """A proportional valve on one cylinder circuit.

    ``command`` in [-1, 1] asks for a fraction of the flow-limited speed (extend faster at the rod end is
    not possible: extension is piston-area limited, retraction annulus-limited). A closed valve holds the
    cylinder where it stopped, correcting the servo's droop under load with time constant ``hold_time`` (s).
    """

    cylinder: CylinderSpec
    lower: float  # slide joint range, m
    upper: float
    hold_time: float
    hold_at: float | None = None

    def __post_init__(self) -> None:
        # the spec's flow-limited speeds (m/s), read at every control step: its properties recompute them
        self._extend, self._retract = self.cylinder.extend_speed, self.cylinder.retract_speed

    def speed(self, command: float, position: float) -> float:
        """Slide speed setpoint, m/s."""
        if abs(command) < HOLD_BAND:
            if self.hold_at is None:
                self.hold_at = position
            correction = (self.hold_at - position) / self.hold_time
            limit = 0.1 * self._extend
            return max(-limit, min(limit, correction))
        self.hold_at = None
        stroke = self.upper - self.lower
        if command > 0:
            room = (self.upper - position) / (CUSHION * stroke)
            return command * self._extend * max(0.0, min(1.0, room))
        room = (position - self.lower) / (CUSHION * stroke)
        return command * self._retract * max(0.0, min(1.0, room))

    def reset(self) -> None:
        self.hold_at = None
