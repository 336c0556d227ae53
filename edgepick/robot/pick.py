"""The pick-and-place cycle (thesis 5.2): choose a target among the grasp records, plan
approach -> open -> descend -> grip -> lift -> place -> release -> home, check EVERY pose of
the plan and the straight path to it against the envelope before the first command, then
execute with a JSON-lines log.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

from edgepick.robot.base import RobotBase, RobotError
from edgepick.robot.envelope import Envelope, SafetyError
from edgepick.robot.motion import HOME_POSE


@dataclass
class PickConfig:
    classes: tuple[str, ...] = ()  # only these classes; empty = any
    choose: str = "largest"  # largest | closest (to the camera)
    approach_m: float = 0.08  # above the grasp point
    lift_m: float = 0.10
    grasp_offset_m: float = 0.0  # added to the grasp point's z (negative = deeper)
    place_pose: list[float] = field(default_factory=lambda: [-0.05, -0.32, 0.10, math.pi, 0.0, 0.0])
    home_pose: list[float] = field(default_factory=lambda: list(HOME_POSE))
    speed: float = 0.25
    acc: float = 1.2


@dataclass
class Step:
    command: str  # moveL | open | grip | release
    target: list[float] | None
    note: str


def _above(pose: list[float], dz: float) -> list[float]:
    return [pose[0], pose[1], pose[2] + dz, *pose[3:]]


def plan_pick(record: dict, cfg: PickConfig) -> list[Step]:
    """The cycle's steps for one grasp record with a robot pose."""
    grasp = list(record["pose_robot"])
    grasp[2] += cfg.grasp_offset_m
    place = list(cfg.place_pose)
    return [Step("moveL", _above(grasp, cfg.approach_m), "approach above the object"),
            Step("open", None, "open / magnet off"),
            Step("moveL", grasp, "descend to the grasp point"),
            Step("grip", None, "close / magnet on"),
            Step("moveL", _above(grasp, cfg.lift_m), "lift"),
            Step("moveL", _above(place, cfg.approach_m), "above the place pose"),
            Step("moveL", place, "place"),
            Step("release", None, "open / magnet off"),
            Step("moveL", _above(place, cfg.approach_m), "retreat"),
            Step("moveL", list(cfg.home_pose), "home")]


def plan_reason(plan: list[Step], envelope: Envelope, cfg: PickConfig, start: list[float] | None = None) -> str | None:
    """Why the plan is refused: the speed, the first target outside the envelope, or the first
    moveL whose straight path (from `start`, the arm's pose, then from each target) is not
    allowed. None when every step passes."""
    speed = envelope.speed_reason(cfg.speed, cfg.acc)
    if speed:
        return speed
    previous = list(start) if start is not None else None
    for step in plan:
        if step.target is not None:
            reason = envelope.pose_reason(step.target) or \
                (envelope.path_reason(previous, step.target) if previous is not None else None)
            if reason:
                return f"{step.note}: {reason}"
            previous = step.target
    return None


def choose_target(records: list[dict], envelope: Envelope, cfg: PickConfig,
                  start: list[float] | None = None) -> tuple[dict | None, list[Step], str]:
    """The preferred record whose whole plan, from the arm's pose `start` [default: the home
    pose], passes the envelope; its plan, and a note."""
    start = list(cfg.home_pose) if start is None else start
    candidates = [r for r in records if not cfg.classes or r["class"] in cfg.classes]
    if not candidates:
        return None, [], "no object of the requested classes"
    if cfg.choose == "closest":
        candidates.sort(key=lambda r: r["depth_m"] if r.get("depth_m") is not None else math.inf)
    else:
        candidates.sort(key=lambda r: -r["area_px"])
    reasons = []
    for r in candidates:
        if r.get("pose_robot") is None:
            reasons.append(f"{r['class']}: {r.get('reason', 'no robot pose (no calibration?)')}")
            continue
        plan = plan_pick(r, cfg)
        reason = plan_reason(plan, envelope, cfg, start)
        if reason is None:
            return r, plan, "ok"
        reasons.append(f"{r['class']}: {reason}")
    return None, [], "; ".join(reasons)


class CommandLog:
    """JSON lines: time, cycle, command, target, result. The file is created at the first entry,
    so a run that fails before it has anything to log leaves no empty log behind."""

    def __init__(self, path: str | Path | None):
        self.path = Path(path) if path else None
        self.file: IO[str] | None = None
        self.records: list[dict] = []

    def write(self, **entry) -> None:
        entry = {"t": round(time.time(), 4), **entry}
        self.records.append(entry)
        if self.path is not None:
            if self.file is None:
                self.file = open(self.path, "a")
            self.file.write(json.dumps(entry) + "\n")
            self.file.flush()

    def close(self) -> None:
        if self.file:
            self.file.close()
            self.file = None


def execute(plan: list[Step], robot: RobotBase, gripper, log: CommandLog, cycle: int, cfg: PickConfig) -> str | None:
    """Run the plan; returns None when every step was carried out, else the reason it stopped.
    Any robot error ends the cycle and leaves the arm stopped; a halt sends nothing more."""
    for step in plan:
        try:
            if step.command == "moveL":
                robot.move_l(step.target, cfg.speed, cfg.acc)
            else:
                getattr(gripper, step.command)()
        except (RobotError, SafetyError) as exc:
            log.write(cycle=cycle, command=step.command, target=step.target, note=step.note, result=f"error: {exc}")
            robot.stop()
            return str(exc)
        log.write(cycle=cycle, command=step.command, target=step.target, note=step.note, result="ok")
    return None
