"""The arm's home pose and the motion-time model of a moveL/moveJ (trapezoidal velocity profile).

URRobot sizes each command's timeout from motion_time; SimRobot (edgepick.sim.robot) uses it as
its simulated clock; the pick plan ends at HOME_POSE.
"""

from __future__ import annotations

import math

HOME_POSE = [0.25, -0.15, 0.30, math.pi, 0.0, 0.0]  # tool pointing down, above the +x side of the base


def motion_time(distance: float, speed: float, acc: float) -> float:
    """Trapezoidal profile duration (triangular when the distance is too short to reach speed)."""
    if distance <= 0:
        return 0.0
    ramp = speed * speed / acc
    if distance < ramp:
        return 2 * math.sqrt(distance / acc)
    return distance / speed + speed / acc
