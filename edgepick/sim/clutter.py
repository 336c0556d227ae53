"""Clutter-removal rounds in the synthetic cell (`pick --rounds N`, `bench --cell --rounds N`; the
`[sim]` extra): the grasping benchmarks' protocol (VGN, GIGA), where a scene is laid out once and
picked from until the table is empty.

A round lays out 4-10 parts in the pick area (piles allowed: a part rests on others where it
stays, data/stacking.py), lets them come to rest in MuJoCo, and then runs pick after pick on the
same table. After each cycle the part it took leaves the table, if the physics check carried it to
the place pose (with the geometric rule alone: if the rule passed the grasp); the rest, as the
check's hand left them (pushed, or fallen from the part taken), settle in MuJoCo, and the next
frame is drawn from where they came to rest, under the round's light condition, table and camera.
A round ends when the table is empty, after two failures in a row, or at its cycle cap. Each frame
is a fresh render of the parts' settled poses: the same poses and the same frame seed give the
same frame (`frame_rng`).

Ids: each part carries its id in the frame's truth ("id"), which the physics check reads back, so
a pick removes the part it really took.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from edgepick.data.render import Layout
from edgepick.data.shapes import ObjectModel, Placed
from edgepick.errors import ParameterError
from edgepick.frames import Frame
from edgepick.geometry import project
from edgepick.intervals import rounded, wilson
from edgepick.robot.clearance import jaw_opening_m
from edgepick.robot.cycle import CycleResult, verdicts
from edgepick.robot.pick import PickConfig
from edgepick.robot.recording import SceneChange
from edgepick.robot.verdict import Verdict, summarize
from edgepick.runtime.grasp_record import Grasp
from edgepick.sim.camera import SynthCamera
from edgepick.sim.physics import PhysicsConfig, PhysicsRun, physics_run, require_mujoco
from edgepick.sim.physics_scene import OVERLAP_M, Solid, scene_xml, settle

ROUND_ENDS = ("cleared", "two failures in a row", "cycle cap", "robot stopped")
STAYS_M, STAYS_DEG = 0.01, 10.0  # a laid-out part that settles farther or tips more did not stay where it was put
# a laid-out part lies this share of the frame's width or more inside every edge (a D415 has no depth in a band
# at its left edge, up to 3.5% of the width)
IN_VIEW_MARGIN = 0.04
TRAY_MARGIN_M = 0.05  # a part whose base centre ends farther than this outside the pick area has left the tray


@dataclass(frozen=True)
class RoundConfig:
    """How a clutter-removal round is laid out and when it ends, checked on creation."""

    objects: tuple[int, int] = (4, 10)  # how many parts a round lays out: drawn in this range
    max_cycles: int | None = None  # cycles per round at most; None: the failures' rule bounds it
    failures_in_row: int = 2  # the round ends after this many failed cycles in a row

    def __post_init__(self) -> None:
        object.__setattr__(self, "objects", tuple(self.objects))
        if not (len(self.objects) == 2 and all(isinstance(v, int) for v in self.objects)
                and 1 <= self.objects[0] <= self.objects[1] <= 20):
            raise ParameterError("{objects}: must be two whole numbers 1 <= low <= high <= 20", objects=self.objects)
        if self.max_cycles is not None and not (isinstance(self.max_cycles, int) and self.max_cycles >= 1):
            raise ParameterError("{max_cycles}: must be at least 1", max_cycles=self.max_cycles)
        if not (isinstance(self.failures_in_row, int) and self.failures_in_row >= 1):
            raise ParameterError("{failures_in_row}: must be at least 1", failures_in_row=self.failures_in_row)

    def cap(self, parts: int) -> int:
        """The cycles a round of PARTS may run: max_cycles, or the most the failures' rule allows
        (each part taken after failures_in_row - 1 failures, then failures_in_row more)."""
        return self.max_cycles or parts * self.failures_in_row + self.failures_in_row


@dataclass
class Part:
    """One part on a round's table, robot frame: its base centre and rotation (the columns its major
    axis, the axis across and up, as sim/physics_scene.py's Solid)."""

    key: int
    model: ObjectModel
    base: np.ndarray
    rotation: np.ndarray

    def rest(self, base: np.ndarray, rotation: np.ndarray) -> None:
        """Where the part came to rest. A part whose two ends are alike (all but a brake disk, whose hub
        stands on one side) and that landed upside down is the same solid the right way up: its frame
        turned over onto its other end, so that its top is the face that looks up, as the renderer,
        the grasp truth and the physics check take a top."""
        if rotation[2, 2] < 0 and self.model.cls != "disk":
            base = base + rotation[:, 2] * self.model.height
            rotation = rotation * np.array([1.0, -1.0, -1.0])  # x kept, y and up turned over: still a rotation
        self.base, self.rotation = base, rotation

    def solid(self) -> Solid:
        m = self.model
        dims = {"length": m.length, "width": m.width} if m.major_axis else dict(m.extra)
        top = self.base + self.rotation[:, 2] * m.height
        return Solid(m.cls, self.base, self.rotation, {"height": m.height, **dims}, top, self.key)

    def describe(self) -> dict:
        """As a recording holds it: id, class, pose [x, y, z, qx, qy, qz, qw] and size."""
        from edgepick.robot.messages import quaternion

        m = self.model
        size = {"length": m.length, "width": m.width} if m.major_axis else {"diameter": 2 * m.radius}
        return {"id": self.key, "class": m.cls, "pose": [round(float(v), 6) for v in (*self.base, *quaternion(self.rotation))],
                "size": {"height": round(m.height, 6), **{k: round(float(v), 6) for k, v in size.items()}}}


def frame_rng(seed: int, round_index: int, pick: int) -> np.random.Generator:
    """The sensor noise of a round's frame before pick PICK (0 = the first)."""
    return np.random.default_rng([seed, 19, round_index, pick])


class ClutterRound(SynthCamera):
    """One round as the cell's camera: `read` draws the table as it stands; `after` (run_cycles' hook)
    takes the picked part off and lets the rest settle; `physics_judge` is run_cycles' PHYSICS."""

    same_table = True

    def __init__(self, width: int = 640, height: int = 480, seed: int = 0, index: int = 0,
                 cfg: RoundConfig | None = None, mount_height_m: float = 0.7, physics: PhysicsConfig | None = None):
        super().__init__(width, height, seed=seed, mount_height_m=mount_height_m)
        self.mujoco = require_mujoco()
        # stiff contacts (three steps: stiffer ones fling a resting part now and then) so that parts rest on parts,
        # not in them; a magnet that holds steel alone, since every part's fate counts here
        physics = physics or PhysicsConfig()
        self.cfg, self.round = cfg or RoundConfig(), index
        self.physics_cfg = dataclasses.replace(physics, contact_s=3 * physics.timestep_s, magnet_steel_only=True)
        self.layout, self.parts = self._lay_out(np.random.default_rng([seed, 17, index]))
        self.laid_out, self.picks, self.failures = len(self.parts), 0, 0
        self.ended: str | None = None
        self.removed: list[int] = []  # the parts picks took off the table
        self.fell: list[int] = []  # the parts that left the tray otherwise (carried along, pushed off)
        self.cap = self.cfg.cap(self.laid_out)
        self._run: PhysicsRun | None = None  # the physics check of the cycle going on

    # -- the table --------------------------------------------------------------------------------
    def _lay_out(self, rng: np.random.Generator) -> tuple[Layout, list[Part]]:
        """The round's layout and its parts at rest: drawn until cfg.objects[0] or more stand, those
        placed into others (which no simulation can separate) left out, and again when a part does not
        stay where it was laid out (more than STAYS_M off, or tipped more than STAYS_DEG), as every
        scene of the cell stands as rendered (data/stacking.py)."""
        while True:
            layout = self.renderer.lay_out(rng, self.mount, self.in_pick_area, self.cfg.objects, tries=50)
            parts = [self._part(k, p, layout.n) for k, p in enumerate(layout.placed)]
            parts = [p for p in self._apart(parts) if self._in_view(p)]
            rested = settle(self.mujoco, [p.solid() for p in parts], self.physics_cfg)
            stays = rested is not None and all(
                np.linalg.norm(base - p.base) <= STAYS_M and rotation[:, 2] @ p.rotation[:, 2] >= np.cos(np.radians(STAYS_DEG))
                for p, (base, rotation) in zip(parts, rested))
            if rested is not None and stays and len(parts) >= self.cfg.objects[0]:
                for part, pose in zip(parts, rested):
                    part.rest(*pose)
                return layout, parts

    def _part(self, key: int, p: Placed, n: np.ndarray) -> Part:
        cal = self.calibration()
        up, axis = cal.R @ -n, cal.R @ p.a1
        return Part(key, p.model, cal.apply(p.ground - n * p.base_elev), np.stack([axis, np.cross(up, axis), up], axis=1))

    def _apart(self, parts: list[Part]) -> list[Part]:
        """PARTS less each one placed more than OVERLAP_M into one placed before it."""
        while len(parts) > 1:
            model = self.mujoco.MjModel.from_xml_string(scene_xml([p.solid() for p in parts], False, self.physics_cfg,
                                                                  hand=False))
            data = self.mujoco.MjData(model)
            self.mujoco.mj_forward(model, data)
            names = [model.body(model.geom_bodyid[g]).name for g in range(model.ngeom)]
            clash = [max(int(names[c.geom1][3:]), int(names[c.geom2][3:])) for c in data.contact[:data.ncon]
                     if c.dist < -OVERLAP_M and names[c.geom1] != names[c.geom2]
                     and names[c.geom1].startswith("obj") and names[c.geom2].startswith("obj")]
            if not clash:
                break
            parts = [p for i, p in enumerate(parts) if i != max(clash)]
        return parts

    def _in_view(self, part: Part) -> bool:
        """Whether PART lies wholly in the camera's view, IN_VIEW_MARGIN of the width inside every
        edge of the frame (the tray is in view: a part laid out half out of it could never be
        picked, its centroid not its own): its footprint's corners, or its rim, at its base and top."""
        m, cal, intr = part.model, self.calibration(), self.intrinsics
        if m.major_axis:
            footprint = [(sx * m.length / 2, sy * m.width / 2) for sx in (-1, 1) for sy in (-1, 1)]
        else:
            footprint = [(m.radius * np.cos(a), m.radius * np.sin(a)) for a in np.linspace(0, 2 * np.pi, 16, endpoint=False)]
        local = np.array([(x, y, z) for x, y in footprint for z in (0.0, m.height)])
        camera = (part.base + local @ part.rotation.T - cal.t) @ cal.R  # robot -> camera frame, one point a row
        if (camera[:, 2] <= 0).any():
            return False
        u, v = np.array([project(intr, point) for point in camera]).T
        margin = IN_VIEW_MARGIN * intr.width
        return bool((u >= margin).all() and (u <= intr.width - 1 - margin).all() and (v >= margin).all()
                    and (v <= intr.height - 1 - margin).all())

    def placed(self) -> list[Placed]:
        """The parts as the renderer places them (camera frame, each posed where it rests)."""
        cal = self.calibration()
        out = []
        for part in self.parts:
            a1 = cal.R.T @ part.rotation[:, 0]
            down = -(cal.R.T @ part.rotation[:, 2])
            out.append(Placed(part.model, cal.R.T @ (part.base - cal.t), 0.0, a1, np.cross(down, a1), down, part.key))
        return out

    def read(self) -> Frame:
        """The table as it stands now, before the next pick."""
        if self.ended is not None:
            raise StopIteration
        self._run = None
        layout = dataclasses.replace(self.layout, placed=self.placed())
        scene = self.renderer.draw(layout, frame_rng(self.seed, self.round, self.picks))
        info = {**scene.info, "round": self.round, "pick": self.picks + 1}
        name = f"synth-{self.seed}-round{self.round:03d}-{self.picks + 1:02d}"
        return Frame(scene.rgb, scene.depth, self.intrinsics, name, scene.grasps, scene.mask, info, scene.hidden)

    def describe(self) -> dict:
        """The round so far: its index, light condition, parts laid out and removed, picks, end."""
        return {"round": self.round, "seed": self.seed, "lighting": self.layout.lighting, "table": self.layout.table,
                "parts": self.laid_out, "removed": len(self.removed), "fell": len(self.fell), "picks": self.picks,
                "ended": self.ended}

    # -- the loop's hooks ---------------------------------------------------------------------------
    def physics_judge(self, pick: PickConfig):
        """run_cycles' PHYSICS: the chosen grasp carried out on the frame's truth (sim/physics.py), the
        poses the check left the parts in kept for `after`."""
        truth_cal = self.calibration()

        def judge(record: Grasp, frame: Frame, path: list[list[float]]) -> Verdict:
            self._run = physics_run(record, frame.truth or [], truth_cal, list(pick.place_pose), pick.grasp_offset_m,
                                    self.physics_cfg, hidden=frame.hidden or [], opening_m=jaw_opening_m(record, pick.hand),
                                    path=path)
            return self._run.verdict

        return judge

    def after(self, result: CycleResult, record: Grasp | None, frame: Frame) -> SceneChange:
        """run_cycles' AFTER: the picked part off the table when the cycle succeeded (the physics
        check's verdict where it ran, else the geometric rule's), the rest settled; says what changed
        and whether the round ends."""
        before = [p.describe() for p in self.parts]
        verdict = result.physics or result.verdict
        succeeded = verdict is not None and verdict.success
        run, self._run = self._run, None
        if run is not None and run.verdict.failure != "unstable":
            for part in self.parts:
                if part.key in run.poses:
                    part.base, part.rotation = run.poses[part.key]
        removed = None
        if succeeded and record is not None:
            removed = run.target if run is not None else self._nearest(record)
            self.parts = [p for p in self.parts if p.key != removed]
            self.removed += [] if removed is None else [removed]
        touched = removed is not None or run is not None  # else nothing came near the table: it stays as it was
        rested = settle(self.mujoco, [p.solid() for p in self.parts], self.physics_cfg) if touched else None
        if rested is not None:
            for part, pose in zip(self.parts, rested):
                part.rest(*pose)
        fell = [p.key for p in self.parts if not self._in_tray(p)]
        self.parts = [p for p in self.parts if p.key not in fell]
        self.fell += fell
        self.picks += 1
        self.failures = 0 if succeeded else self.failures + 1
        self.ended = "cleared" if not self.parts else "robot stopped" if result.outcome == "stopped" else \
            "two failures in a row" if self.failures >= self.cfg.failures_in_row else \
            "cycle cap" if self.picks >= self.cap else None
        return SceneChange(self.round, self.picks, before, [p.describe() for p in self.parts], removed,
                           time.time_ns(), self.ended, fell)

    def _in_tray(self, part: Part) -> bool:
        """Whether PART still lies in the tray: its base centre within TRAY_MARGIN_M of the pick area,
        on the table (not below it: the simulation lost it)."""
        (x0, x1), (y0, y1) = self.PICK_AREA_M
        x, y, z = part.base
        m = TRAY_MARGIN_M
        return x0 - m <= x <= x1 + m and y0 - m <= y <= y1 + m and z > -0.02

    def _nearest(self, record: Grasp) -> int | None:
        """The part of the record's class whose top lies nearest its commanded point (the part the
        geometric rule judged it against)."""
        same = [p for p in self.parts if p.model.cls == record.cls]
        point = np.asarray(record.chosen_pose()[:3], np.float64)
        best = min(same, key=lambda p: float(np.linalg.norm(p.solid().top - point)), default=None)
        return None if best is None else best.key


def round_summary(rounds: list[dict], results: list[CycleResult]) -> dict:
    """What a run of rounds reports, summed and per round and per light condition: grasp success
    (of the verdict that removed parts: the physics check's where it ran) with its 95% Wilson
    interval, clearance (parts removed over parts laid out) with its interval, picks per part
    removed, failures by kind, how the rounds ended and the time per pick (frame -> checked plan plus
    the arm's simulated motion)."""
    key = "physics" if any(r.physics is not None for r in results) else "verdict"
    by_round = {d["round"]: [r for r in results if r.round is not None and r.round["round"] == d["round"]]
                for d in rounds}
    per_round = [{**d, **_rates(by_round[d["round"]], [d], key)} for d in rounds]
    lights = list(dict.fromkeys(d["lighting"] for d in rounds))
    by_lighting = {light: _rates([r for d in rounds if d["lighting"] == light for r in by_round[d["round"]]],
                                 [d for d in rounds if d["lighting"] == light], key) for light in lights}
    ends = {end: sum(d["ended"] == end for d in rounds) for end in ROUND_ENDS}
    times = [r.plan_ms / 1000 + (r.motion_s or 0.0) for r in results if r.round is not None]
    plans = sorted(r.plan_ms for r in results if r.round is not None)
    return {"verdict": "physics" if key == "physics" else "geometric", **_rates(
        [r for d in rounds for r in by_round[d["round"]]], rounds, key),
            "ended": {k: v for k, v in ends.items() if v},
            "time_per_pick_s": round(sum(times) / len(times), 3) if times else None,
            "plan_ms_p50": plans[len(plans) // 2] if plans else None,
            "by_lighting": by_lighting, "per_round": per_round}


def _rates(results: list[CycleResult], rounds: list[dict], key: str) -> dict:
    judged = summarize(verdicts(results, key))
    picks, success = len(results), judged.get("success", 0)
    parts, removed = sum(d["parts"] for d in rounds), sum(d["removed"] for d in rounds)
    return {"rounds": len(rounds), "picks": picks, "success": success,
            "success_rate": round(success / picks, 4) if picks else None,
            "success_ci95": rounded(wilson(success, picks)), "parts": parts, "removed": removed,
            "fell": sum(d["fell"] for d in rounds),
            "clearance": round(removed / parts, 4) if parts else None, "clearance_ci95": rounded(wilson(removed, parts)),
            "picks_per_part": round(picks / removed, 3) if removed else None, "failures": judged.get("failures", {})}


def round_line(d: dict) -> str:
    """The line `pick` prints when a round ends."""
    fell = f", {d['fell']} left the tray otherwise" if d["fell"] else ""
    return (f"round {d['round']}: {d['removed']} of {d['parts']} parts removed in {d['picks']} picks{fell} "
            f"({d['lighting']}); {d['ended'] or 'stopped'}")



def run_rounds(pipeline, robot, gripper, *, rounds: int, pick: PickConfig, log, seed: int = 0,
               cfg: RoundConfig | None = None, physics: PhysicsConfig | None = None, judge: bool = False,
               echo=print, overlay_dir=None, recorder=None, done: list[CycleResult] | None = None,
               described: list[dict] | None = None, size: tuple[int, int] = (640, 480)) -> list[dict]:
    """ROUNDS clutter-removal rounds (numbered 1..ROUNDS, each laid out from SEED and its number) of
    robot/loop.py's run_cycles with PIPELINE, ROBOT and GRIPPER: each round runs until its table is
    empty, two failures in a row or its cap. JUDGE: each cycle also carried out in the physics check
    (PHYSICS), whose verdict then decides what leaves the table. RECORDER(round), when given, opens
    the round's recording (closed when the round ends). DONE gets each cycle's result and DESCRIBED
    each round's `describe()` as they finish (the caller's lists: still there after an interrupt);
    returns DESCRIBED."""
    from edgepick.robot.loop import Cell, run_cycles

    if rounds < 1:
        raise ParameterError("{rounds}: must be at least 1", rounds=rounds)
    done = [] if done is None else done
    described = [] if described is None else described
    for index in range(1, rounds + 1):
        cell = ClutterRound(*size, seed=seed, index=index, cfg=cfg, physics=physics)
        rec = recorder(cell) if recorder is not None else None
        try:
            picking = Cell(cell, pipeline, robot, gripper, log, cell.calibration(), rec,
                           cell.physics_judge(pick) if judge else None)
            run_cycles(picking, cfg=pick, cycles=cell.cap, overlay_dir=overlay_dir, echo=echo, done=done, after=cell.after,
                       first=len(done) + 1)
        finally:
            described.append(cell.describe())  # an interrupted round too: what it did so far
            if rec is not None:
                rec.close()
        echo(round_line(described[-1]))
        if robot is not None and robot.halted:
            break
    return described
