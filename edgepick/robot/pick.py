"""The pick-and-place cycle (thesis 5.2): choose a target among the grasp records, plan
approach -> open -> descend -> grip -> lift -> place -> release -> home, check EVERY pose of
the plan and the straight path to it against the envelope (and, with an arm connected, every
pose against the controller's own safety limits) before the first command, then execute with a
JSON-lines log.
"""

from __future__ import annotations

import enum
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO

from edgepick.errors import ParameterError
from edgepick.robot.base import RobotBase, RobotError
from edgepick.robot.clearance import HandShape, jaw_opening_m
from edgepick.robot.envelope import Envelope, SafetyError
from edgepick.robot.motion import HOME_POSE
from edgepick.robot.verdict import GRIPPER, closing_yaw_deg
from edgepick.runtime.grasp_record import Grasp
from edgepick.schema import member

OCCLUDED = 0.02  # share of an object's rim under other objects above which it is picked last
BURIED = 0.2  # ... and above which it is not picked at all: lifting it would drag what lies on it


class Choose(enum.StrEnum):
    """Which reachable object a cycle picks first."""

    LARGEST = "largest"
    CLOSEST = "closest"  # to the camera


@dataclass(frozen=True)
class PickConfig:
    """What a pick cycle does, checked on creation (the envelope's caps are checked per plan)."""

    classes: tuple[str, ...] = ()  # only these classes; empty = any
    choose: Choose = Choose.LARGEST
    approach_m: float = 0.08  # above the grasp point
    lift_m: float = 0.10  # above the grasp point at least; higher where the table holds taller parts (plan_pick)
    transit_clearance_m: float = 0.02  # what the hand carries passes this far above the tallest part in view
    grasp_offset_m: float = 0.0  # added to the grasp point's z (negative = deeper)
    place_pose: tuple[float, ...] = (-0.05, -0.32, 0.10, math.pi, 0.0, 0.0)
    home_pose: tuple[float, ...] = tuple(HOME_POSE)
    speed: float = 0.25  # moveL, m/s
    acc: float = 1.2  # moveL, m/s^2
    transit_radius_m: float = 0.18  # lift -> place passes the base no closer than this (via points on this circle)
    hand: HandShape | None = HandShape()  # the footprint checked on the frame's depth (robot/clearance.py); None: not checked
    # on one table picked from in turn: a part still seen this close to where an earlier pick went is tried after
    # the others (that pick failed there, and the same plan would fail again); 0: no memory
    retry_elsewhere_m: float = 0.03

    def __post_init__(self) -> None:
        object.__setattr__(self, "choose", member(Choose, "choose", self.choose))
        if isinstance(self.hand, dict):  # as a recording's metadata holds it
            object.__setattr__(self, "hand", HandShape(**self.hand))
        for name in ("classes", "place_pose", "home_pose"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        for name in ("speed", "acc"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ParameterError(f"{{{name}}}: must be a positive number", **{name: getattr(self, name)})
        for name in ("lift_m", "transit_clearance_m"):
            if not (math.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ParameterError(f"{{{name}}}: must be 0 or more metres", **{name: getattr(self, name)})
        if not (math.isfinite(self.retry_elsewhere_m) and self.retry_elsewhere_m >= 0):
            raise ParameterError("{retry_elsewhere_m}: must be 0 or more metres", retry_elsewhere_m=self.retry_elsewhere_m)


@dataclass
class Step:
    command: str  # moveL | open | grip | release
    target: list[float] | None
    note: str
    clears_view: bool = False  # once done, the arm and what it holds have left the pick area: the next frame may be taken
    width_m: float | None = None  # open: how far a jaw opens (robot/clearance.py jaw_opening_m); a magnet ignores it


def _above(pose: list[float], dz: float) -> list[float]:
    return [pose[0], pose[1], pose[2] + dz, *pose[3:]]


def _around_the_base(a: list[float], b: list[float], cfg: PickConfig) -> list[list[float]]:
    """Via points when the straight line A -> B would pass the base axis closer than
    cfg.transit_radius_m (the envelope keeps the TCP out of a cylinder around it): points on that
    circle, at most 60 degrees apart, at the higher of the two heights. None when the line is clear."""
    ax, ay, bx, by = a[0], a[1], b[0], b[1]
    dx, dy = bx - ax, by - ay
    t = max(0.0, min(1.0, -(ax * dx + ay * dy) / (dx * dx + dy * dy))) if dx or dy else 0.0
    if math.hypot(ax + t * dx, ay + t * dy) >= cfg.transit_radius_m:
        return []
    start, end = math.atan2(ay, ax), math.atan2(by, bx)
    turn = (end - start + math.pi) % (2 * math.pi) - math.pi  # the shorter way round
    n = max(1, math.ceil(abs(turn) / math.radians(60)))
    z, r = max(a[2], b[2]), cfg.transit_radius_m
    return [[r * math.cos(start + turn * k / (n + 1)), r * math.sin(start + turn * k / (n + 1)), z, *a[3:]]
            for k in range(1, n + 1)]


def plan_pick(record: Grasp, cfg: PickConfig, tallest_z_m: float | None = None, table_z_m: float = 0.0) -> list[Step]:
    """The cycle's steps for one grasp with a robot pose: a jaw opens to the part's width and room
    for its fingers (jaw_opening_m), and all the way when it lets go. The lift (lift_height_m)
    carries the part over the tallest top in view (TALLEST_Z_M, robot frame; None: lift_m alone)."""
    grasp = list(record.chosen_pose())
    grasp[2] += cfg.grasp_offset_m
    place = list(cfg.place_pose)
    lifted = _above(grasp, lift_height_m(cfg, tallest_z_m, table_z_m))
    return [Step("moveL", _above(grasp, cfg.approach_m), "approach above the object"),
            Step("open", None, "open / magnet off", width_m=jaw_opening_m(record, cfg.hand)),
            Step("moveL", grasp, "descend to the grasp point"),
            Step("grip", None, "close / magnet on"),
            Step("moveL", lifted, "lift"),
            *[Step("moveL", via, "around the base") for via in _around_the_base(lifted, _above(place, cfg.approach_m), cfg)],
            Step("moveL", _above(place, cfg.approach_m), "above the place pose", clears_view=True),
            Step("moveL", place, "place"),
            Step("release", None, "open / magnet off"),
            Step("moveL", _above(place, cfg.approach_m), "retreat"),
            Step("moveL", list(cfg.home_pose), "home")]


def lift_height_m(cfg: PickConfig, tallest_z_m: float | None = None, table_z_m: float = 0.0) -> float:
    """How far the hand rises from the grasp point before it carries the part off: cfg.lift_m, or
    as high as the tallest top in view (TALLEST_Z_M) stands above the table (TABLE_Z_M) plus
    cfg.transit_clearance_m, if that is more. The part rises with the hand from where it stood (on
    the table or higher), so its underside then passes over every part in view: a part carried
    low drags the parts it meets on its way to the place pose off the table."""
    if tallest_z_m is None:
        return cfg.lift_m
    return round(max(cfg.lift_m, tallest_z_m - table_z_m + cfg.transit_clearance_m), 4)


def carry_path(plan: Sequence[Step]) -> list[list[float]]:
    """The TCP positions (x, y, z) a plan moves through while it holds the part: the lift, then
    on to above the place pose (the physics check's hand follows them, sim/physics.py)."""
    path: list[list[float]] = []
    holding = False
    for step in plan:
        holding = holding or step.command == "grip"
        if holding and step.command == "moveL" and step.target is not None:
            path.append(list(step.target[:3]))
            if step.clears_view:
                break
    return path


def plan_reason(plan: list[Step], envelope: Envelope, cfg: PickConfig, start: list[float] | None = None,
                limits: Callable[[list[float]], str | None] | None = None) -> str | None:
    """Why the plan is refused: the speed, the first target outside the envelope, the first
    moveL whose straight path (from `start`, the arm's pose, then from each target) is not
    allowed, or the first target that LIMITS (the controller's safety limits, asked once the
    envelope passes) refuses. None when every step passes."""
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
    if limits is not None:
        for step in plan:
            reason = limits(step.target) if step.target is not None else None
            if reason:
                return f"{step.note}: {reason}"
    return None


def _tried_here(record: Grasp, tried: Sequence[Sequence[float]], radius_m: float) -> bool:
    """Whether RECORD's grasp point lies within RADIUS_M of a point in TRIED (robot frame)."""
    if record.pose_robot is None or radius_m <= 0:
        return False
    return any(math.dist(record.pose_robot[:3], point[:3]) <= radius_m for point in tried)


def choose_target(records: list[Grasp], envelope: Envelope, cfg: PickConfig, start: list[float] | None = None,
                  limits: Callable[[list[float]], str | None] | None = None,
                  clear: Callable[[Grasp], str | None] | None = None,
                  tried: Sequence[Sequence[float]] = ()) -> tuple[Grasp | None, list[Step], str]:
    """The preferred record whose whole plan, from the arm's pose `start` [default: the home
    pose], passes the envelope and LIMITS (see plan_reason); its plan, and a note. An object cut
    by the image border is not chosen (its centroid is that of the part in view, not of the
    object), nor one with BURIED or more of its rim under other objects, nor one where CLEAR
    (robot/clearance.py: the hand's footprint on the frame's depth) says the hand cannot come down,
    across the part or, for a jaw, along it (along_its_length). TRIED: the robot points earlier picks
    on the same table went to; a record within cfg.retry_elsewhere_m of one comes after the rest."""
    start = list(cfg.home_pose) if start is None else start
    candidates = [r for r in records if not cfg.classes or r.cls in cfg.classes]
    if not candidates:
        return None, [], "no object of the requested classes"
    if cfg.choose == Choose.CLOSEST:
        candidates.sort(key=lambda r: r.depth_m if r.depth_m is not None else math.inf)
    else:
        candidates.sort(key=lambda r: -r.area_px)
    # objects with nothing on top first: a partly hidden object's centroid is that of its visible part; of the
    # others, the least covered first: the top of a pile before what it lies on, which would carry it off
    candidates.sort(key=lambda r: (r.occluded > OCCLUDED, r.occluded if r.occluded > OCCLUDED else 0.0))
    candidates.sort(key=lambda r: _tried_here(r, tried, cfg.retry_elsewhere_m))
    reasons = []
    tops = [r.chosen_pose()[2] for r in records if r.pose_robot is not None]  # every part in view: what a carry passes over
    tallest = max(tops) if tops else None
    for r in candidates:
        if r.partial:
            reasons.append(f"{r.cls}: cut by the image border")
            continue
        if r.occluded >= BURIED:
            reasons.append(f"{r.cls}: under other objects ({100 * r.occluded:.0f}% of its rim)")
            continue
        if r.pose_robot is None:
            reasons.append(f"{r.cls}: {r.reason or 'no robot pose (no calibration?)'}")
            continue
        blocked = clear(r) if clear is not None else None
        if blocked and clear is not None and GRIPPER.get(r.cls) == "two-finger" and r.orientation_defined:
            turned = along_its_length(r)  # its sides are crowded: try its ends
            if clear(turned) is None:
                r, blocked = turned, None
        if blocked:
            reasons.append(f"{r.cls}: {blocked}")
            continue
        plan = plan_pick(r, cfg, tallest, envelope.table_z_m)
        reason = plan_reason(plan, envelope, cfg, start, limits)
        if reason is None:
            return r, plan, "ok"
        reasons.append(f"{r.cls}: {reason}")
    return None, [], "; ".join(reasons)


def along_its_length(record: Grasp) -> Grasp:
    """RECORD's grasp turned a quarter turn about the vertical, the jaw opened all the way: it closes
    on the part's ends instead of its sides. For a part short enough for the stroke whose sides are
    crowded (two adapters side by side); choose_target tries it where the hand cannot come down
    across the part, and the clearance check refuses it for a part longer than the stroke."""
    yaw = math.radians(closing_yaw_deg(record.chosen_pose()) + 90.0)
    yaw = (yaw + math.pi / 2) % math.pi - math.pi / 2
    pose = (*record.chosen_pose()[:3], math.pi * math.cos(yaw / 2), math.pi * math.sin(yaw / 2), 0.0)
    return replace(record, pose_robot=tuple(round(float(v), 6) for v in pose), width_m=None)


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
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self.file = open(self.path, "a")
            self.file.write(json.dumps(entry) + "\n")
            self.file.flush()

    def close(self) -> None:
        if self.file:
            self.file.close()
            self.file = None


def execute(plan: list[Step], robot: RobotBase, gripper, log: CommandLog, cycle: int, cfg: PickConfig,
            on_clear: Callable[[], object] | None = None,
            on_step: Callable[[Step, str], object] | None = None) -> str | None:
    """Run the plan; returns None when every step was carried out, else the reason it stopped.
    Any robot error ends the cycle and leaves the arm stopped; a halt sends nothing more. A
    gripper that fails halts the robot too: what it holds, or not, is unknown. ON_CLEAR is
    called once the step that takes the arm out of the pick area (Step.clears_view) is done;
    ON_STEP after each step carried out or failed, with its result as the log writes it."""
    for step in plan:
        try:
            if step.target is not None:  # a moveL
                robot.move_l(step.target, cfg.speed, cfg.acc)
            elif step.command == "open":
                gripper.open(step.width_m)
            else:
                getattr(gripper, step.command)()
        except (RobotError, SafetyError) as exc:
            log.write(cycle=cycle, command=step.command, target=step.target, note=step.note, result=f"error: {exc}")
            robot.stop()
            if step.command != "moveL":
                robot.halt(str(exc))
            if on_step is not None:
                on_step(step, f"error: {exc}")
            return str(exc)
        log.write(cycle=cycle, command=step.command, target=step.target, note=step.note, result="ok")
        if on_step is not None:
            on_step(step, "ok")
        if step.clears_view and on_clear is not None:
            on_clear()
    return None
