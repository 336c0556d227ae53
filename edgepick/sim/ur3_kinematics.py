"""UR3 forward kinematics (Universal Robots' published DH parameters) and its reach, for the
loopback controller."""

from __future__ import annotations

import math

# UR3 DH parameters (Universal Robots' published values)
DH_D = (0.1519, 0.0, 0.0, 0.11235, 0.08535, 0.0819)
DH_A = (0.0, -0.24365, -0.21325, 0.0, 0.0, 0.0)
DH_ALPHA = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
REACH_M = 0.5


def forward_kinematics(q: list[float]) -> list[float]:
    """UR3 TCP pose [x, y, z, rx, ry, rz] of joint angles (standard DH)."""
    T = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    for th, d, a, al in zip(q, DH_D, DH_A, DH_ALPHA):
        ct, st, ca, sa = math.cos(th), math.sin(th), math.cos(al), math.sin(al)
        A = [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]]
        T = [[sum(T[i][k] * A[k][j] for k in range(4)) for j in range(4)] for i in range(4)]
    return [T[0][3], T[1][3], T[2][3], *rotvec(T)]


def rotvec(T) -> list[float]:
    c = max(-1.0, min(1.0, (T[0][0] + T[1][1] + T[2][2] - 1) / 2))
    angle = math.acos(c)
    if angle < 1e-9:
        return [0.0, 0.0, 0.0]
    if math.pi - angle < 1e-6:  # half turn: axis from the diagonal
        axis = [math.sqrt(max(0.0, (T[i][i] + 1) / 2)) for i in range(3)]
        if T[0][1] < 0:
            axis[1] = -axis[1]
        if T[0][2] < 0:
            axis[2] = -axis[2]
        return [angle * a for a in axis]
    s = 2 * math.sin(angle)
    return [angle * (T[2][1] - T[1][2]) / s, angle * (T[0][2] - T[2][0]) / s, angle * (T[1][0] - T[0][1]) / s]


def reachable(pose: list[float]) -> bool:
    x, y, z = pose[:3]
    return math.sqrt(x * x + y * y + (z - DH_D[0]) ** 2) <= REACH_M
