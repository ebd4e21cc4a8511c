"""Dig-cycle phases, told from the machine's state (not from the policy), so any policy is labelled alike."""

from __future__ import annotations

import math
from enum import IntEnum

GRAVITY = 9.81


class DigPhase(IntEnum):
    APPROACH = 0  # driving towards the pile, bucket outside it
    PENETRATE = 1  # edge in the pile, bucket not curling
    CURL = 2  # edge in the pile, bucket curling back (crowding)
    LIFT = 3  # edge out of the pile with a load, not reversing
    PULL_BACK = 4  # reversing, edge out of the pile
    IDLE = 5  # outside the pile, empty, not moving forward


def classify(in_pile: bool, curl_rate: float, travel: float, loaded: bool, length: float) -> DigPhase:
    """Phase from: edge below the pile surface, bucket pitch rate (rad/s), travel speed (m/s), any load.

    Thresholds are in Froude units of the machine's length ``length`` (m), so labels agree at every size.
    """
    speed_scale = math.sqrt(GRAVITY * length)
    if in_pile:  # the pile may push the machine back while it curls: still digging
        return DigPhase.CURL if curl_rate * math.sqrt(length / GRAVITY) > 0.05 else DigPhase.PENETRATE
    if travel < -0.02 * speed_scale:
        return DigPhase.PULL_BACK
    if loaded:
        return DigPhase.LIFT
    return DigPhase.APPROACH if travel > 0.02 * speed_scale else DigPhase.IDLE
