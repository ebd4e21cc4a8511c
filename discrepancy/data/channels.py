"""The input stage's vocabulary: which signals are compared with the twin, and the error for unusable logs."""

from __future__ import annotations

from scaletwin_envs.signal_units import SIGNAL_UNITS

#: Signals compared between real and twin (route-2 and residual columns are the linkage-redundancy check's).
COMPARED = tuple(s for s in SIGNAL_UNITS if not s.endswith("_route2") and not s.startswith("residual_"))
ROUTE2 = tuple(s for s in SIGNAL_UNITS if s.endswith("_route2"))


class RecordingError(ValueError):
    """A recording that cannot be compared with the twin (corrupted, incomplete or mismatched)."""
