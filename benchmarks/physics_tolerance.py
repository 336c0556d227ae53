"""How far off can a grasp be and still carry the object? The physics check (sim/physics.py) on one
object of each class, alone on the table, with the commanded grasp moved away from the true one
along one direction at a time: across the jaw (the fingers' closing axis), along it, in yaw, and in
depth (above the true top); for the magnet, sideways and in depth.

    python benchmarks/physics_tolerance.py [--stroke 0.110] [--out FILE.md | --save]

Each row gives the largest error tried that still succeeds before the first failure, beside the
geometric rule's (docs/contracts.md#grasp-success: 10 mm, 15 degrees), and the sizes tried.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

from edgepick.robot.verdict import Verdict  # noqa: E402
from edgepick.runtime.calibration import Calibration  # noqa: E402
from edgepick.runtime.grasp_record import Grasp  # noqa: E402
from edgepick.sim.physics import PhysicsConfig, physics_verdict  # noqa: E402

IDENTITY = Calibration(np.eye(3), np.zeros(3), 0.0, 0)  # the solids are given in the robot frame
PLACE = [-0.05, -0.32, 0.10, math.pi, 0.0, 0.0]
X, Y = 0.26, 0.0
# the middle of each class's size range in the synthetic scenes (data/shapes.py); the box at the
# widths an RG2 takes and at the middle of the scenes' range
SOLIDS = {
    "adapter": {"length": 0.0625, "width": 0.043, "height": 0.0375},
    "box (95 mm wide)": {"length": 0.17, "width": 0.095, "height": 0.08},
    "box (115 mm wide)": {"length": 0.17, "width": 0.115, "height": 0.08},
    "bearing": {"r_out": 0.038, "r_in": 0.02, "height": 0.035},
    "disk": {"r_out": 0.1325, "r_ring_in": 0.058, "ring_h": 0.024, "r_hat": 0.068, "r_bore": 0.031, "height": 0.05,
             "hat_h": 0.05},
}
YAW = math.radians(20)  # the object's major axis in the robot frame


def truth(name: str) -> list[dict]:
    dims = SOLIDS[name]
    cls = name.split()[0]
    solid = {"base_camera_m": [X, Y, 0.0], "up_camera": [0, 0, 1], "axis_camera": [math.cos(YAW), math.sin(YAW), 0],
             **dims}
    return [{"class": cls, "point_camera_m": [X, Y, dims["height"]], "solid": solid}]


def attempt(name: str, across: float = 0.0, along: float = 0.0, yaw_deg: float = 0.0, above: float = 0.0,
            cfg: PhysicsConfig | None = None) -> Verdict:
    """The grasp moved ACROSS the jaw's closing axis... (metres, degrees) from the true one."""
    cls, height = name.split()[0], SOLIDS[name]["height"]
    closing = YAW + math.pi / 2 + math.radians(yaw_deg)  # the fingers close across the major axis
    c, a = np.array([math.cos(YAW + math.pi / 2), math.sin(YAW + math.pi / 2)]), np.array([math.cos(YAW), math.sin(YAW)])
    x, y = np.array([X, Y]) + across * c + along * a
    pose = [float(x), float(y), height + above, math.pi * math.cos(closing / 2), math.pi * math.sin(closing / 2), 0.0]
    grasp = Grasp(cls, (0.0, 0.0), 0.0, True, 0, height, (X, Y, height), pose)  # the check reads its class and pose
    return physics_verdict(grasp, truth(name), IDENTITY, PLACE, cfg=cfg)


def tolerance(name: str, key: str, values: list[float], cfg: PhysicsConfig) -> tuple[float | None, str, list[float]]:
    """The largest value before the first failure, that failure's kind, and the check times."""
    best, times = None, []
    for v in values:
        verdict = attempt(name, cfg=cfg, **{key: v})
        times.append(verdict.ms)
        if not verdict.success:
            return best, f"{verdict.failure} at {v:g}", times
        best = v
    return best, "none in range", times


SWEEPS = {  # key, values, unit factor for the table
    "jaw": [("across", [i * 0.005 for i in range(0, 11)], "mm", 1000), ("along", [i * 0.005 for i in range(0, 11)], "mm", 1000),
            ("yaw_deg", [i * 5.0 for i in range(0, 10)], "deg", 1), ("above", [i * 0.0025 for i in range(-4, 11)], "mm", 1000)],
    "magnet": [("across", [i * 0.005 for i in range(0, 19)], "mm", 1000),
               ("above", [i * 0.002 for i in range(-2, 13)], "mm", 1000)],
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stroke", type=float, default=PhysicsConfig().jaw_stroke_m, help="the jaw's stroke, metres")
    add_output(ap)
    args = ap.parse_args()
    cfg = PhysicsConfig(jaw_stroke_m=args.stroke)
    start = time.perf_counter()
    rows, all_times = [], []
    for name in SOLIDS:
        gripper = "magnet" if name.split()[0] in ("bearing", "disk") else "jaw"
        for key, values, unit, factor in SWEEPS[gripper]:
            best, first, times = tolerance(name, key, values, cfg)
            all_times += times
            shown = "fails at 0" if best is None else f"{best * factor:g} {unit}"
            rows.append(f"| {name} | {gripper} | {key.replace('_deg', '')} | {shown} | {first} | "
                        f"{values[0] * factor:g} to {values[-1] * factor:g} {unit} |")
    lines = [f"# What a grasp tolerates under physics: one object alone, the jaw's stroke {1000 * args.stroke:.0f} mm", "",
             f"Command: `python benchmarks/physics_tolerance.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; {PhysicsConfig.__doc__.splitlines()[0].rstrip('.')}: jaw {cfg.jaw_force_n:g} N, "
             f"fingertips {1000 * cfg.finger_depth_m:g} mm below the TCP, magnet {cfg.magnet_force_n:g} N over a "
             f"{2000 * cfg.pole_radius_m:g} mm face. Object major axis at {math.degrees(YAW):g} degrees; the fingers "
             f"close across it. Checks: {len(all_times)}, median {np.median(all_times):.0f} ms, p95 "
             f"{np.percentile(all_times, 95):.0f} ms per check, {time.perf_counter() - start:.0f} s in all.", "",
             "| object | gripper | error | largest that still carries it | first failure | tried |",
             "|---|---|---|---|---|---|", *rows, "",
             "across: along the fingers' closing axis (for the magnet: any direction sideways); along: across it, "
             "along the object's major axis; yaw: the closing axis turned from the object's minor axis; above: the "
             "commanded grasp point above the true top face (negative: below). The geometric rule allows 10 mm in "
             "position (any direction) and, for the jaw, 15 degrees."]
    emit("\n".join(lines) + "\n", args)


if __name__ == "__main__":
    main()
