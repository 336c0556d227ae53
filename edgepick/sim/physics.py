"""A pick judged by physics (the `[sim]` extra, MuJoCo): the scene's objects as solids on the table,
the gripper the class uses, and the commanded grasp carried out: approach, descend, close the jaw or
switch the magnet on, lift, hold, carry to the place pose. Success: the object arrives, still held.

The thesis's criterion has two halves: the grasp point within 1 cm, and for the adapter and the
box "without letting them fall" (5.1.5). The geometric verdict (robot/verdict.py) checks the
first; this module checks the second, and with it the tolerance each gripper really has: a
parallel jaw centres an object across its closing axis, a magnet holds wherever its pole face
covers enough steel.

Everything is built from primitives (docs/contracts.md#data-set-layout, "solid"): a box or
adapter is one box; a bearing, and a brake disk's ring and hub, are cylinders with the masses of
their annuli (the pole face is wider than any bore, so it rests on the rim either way), and the
magnet's pull counts only the steel under the face: the annulus, not the bore. The arm is not
simulated (reach and paths are checked kinematically): the hand follows the plan's moves (a free
body welded to a kinematic target, speeding up and slowing down as a moveL does) with two linked
fingers pressed by a set force (an OnRobot RG2: 40 N, 110 mm stroke), or a pole face whose pull
on a steel part is its rated force times the share of the face over the part's top (MuJoCo's
adhesion). Friction is solved without slip (MuJoCo's noslip pass): a grip holds or fails, it
does not creep. Deterministic: the same inputs give the same verdict. The scene itself is built
in sim/physics_scene.py.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from edgepick.errors import ConfigError, ParameterError
from edgepick.frames import Frame
from edgepick.robot.clearance import jaw_opening_m
from edgepick.robot.pick import PickConfig
from edgepick.robot.verdict import Verdict
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp_record import Grasp
from edgepick.sim.physics_scene import FINGER_DAMPING, PhysicsConfig, Solid, solids, with_what_they_touch, without_overlaps

__all__ = ["PHYSICS_FAILURES", "PhysicsConfig", "PhysicsRun", "Solid", "physics_judge", "physics_run", "physics_verdict",
           "require_mujoco", "solids", "steel_share"]

SIM_EXTRA = "the physics verdict needs the sim extra: pip install 'edgepick[sim]'"
MAGNETIC = ("bearing", "disk")  # steel and cast iron; the box (cardboard) and adapter (plastic) are not
CONTACT_M = 0.0005  # a pole face this close to the part's top touches it
NEAR_M = 0.3  # objects farther than this from the target are left out of its check, unless they touch one in it
PHYSICS_FAILURES = ("false detection", "blocked", "too wide", "missed", "dropped", "unsettled", "unstable")
SETTLED_M = 0.005  # a target that moves farther than this before the hand reaches it was not at rest in the scene


def trapezoid(distance: float, speed: float, acc: float, dt: float) -> list[float]:
    """The share of DISTANCE covered at each DT of a move that speeds up at ACC to SPEED (or as far
    as half the way allows) and slows down again."""
    if distance <= 0:
        return [1.0]
    ramp = min(speed / acc, math.sqrt(distance / acc))  # time to top speed
    top = acc * ramp
    total = 2 * ramp + (distance - acc * ramp ** 2) / top
    out = []
    for k in range(1, math.ceil(total / dt) + 1):
        t = min(k * dt, total)
        if t < ramp:
            s = acc * t * t / 2
        elif t > total - ramp:
            s = distance - acc * (total - t) ** 2 / 2
        else:
            s = acc * ramp ** 2 / 2 + top * (t - ramp)
        out.append(min(1.0, s / distance))
    return out


def _overlap(r1: float, r2: float, d: float) -> float:
    """The area two circles of radii R1 and R2 whose centres lie D apart have in common."""
    if d >= r1 + r2:
        return 0.0
    if d <= abs(r1 - r2):
        return math.pi * min(r1, r2) ** 2
    a1 = r1 * r1 * math.acos(min(1.0, max(-1.0, (d * d + r1 * r1 - r2 * r2) / (2 * d * r1))))  # rounding
    a2 = r2 * r2 * math.acos(min(1.0, max(-1.0, (d * d + r2 * r2 - r1 * r1) / (2 * d * r2))))  # near tangency
    return a1 + a2 - 0.5 * math.sqrt(max(0.0, (-d + r1 + r2) * (d + r1 - r2) * (d - r1 + r2) * (d + r1 + r2)))


def steel_share(solid: Solid, centre: np.ndarray, radius: float, body_pos: np.ndarray, body_rot: np.ndarray) -> float:
    """The share of a round pole face centred at CENTRE (robot frame) over the solid's top face (a
    bearing's annulus, a disk's hub): exact, from the areas the face has in common with its circles."""
    local = body_rot.T @ (centre - body_pos)
    d = math.hypot(float(local[0]), float(local[1]))
    dims = solid.dims
    inner, outer = (dims["r_in"], dims["r_out"]) if solid.cls == "bearing" else (dims["r_bore"], dims["r_hat"])
    return (_overlap(radius, outer, d) - _overlap(radius, inner, d)) / (math.pi * radius * radius)


def _target(record: Grasp, world: list[Solid]) -> int | None:
    same = [k for k, s in enumerate(world) if s.cls == record.cls]
    if not same:
        return None
    commanded = np.asarray(record.chosen_pose()[:3], np.float64)
    return min(same, key=lambda k: float(np.linalg.norm(world[k].top - commanded)))


def require_mujoco():
    """MuJoCo (the [sim] extra), or a ConfigError that says how to install it."""
    try:
        import mujoco
    except ModuleNotFoundError:
        raise ConfigError(SIM_EXTRA) from None
    return mujoco


def physics_judge(truth_cal: Calibration, pick: PickConfig, cfg: PhysicsConfig | None = None
                  ) -> Callable[[Grasp, Frame, list[list[float]]], Verdict]:
    """run_cycles' PHYSICS for the synthetic cell: each chosen record's grasp carried out on the
    frame's truth, with the pick's place pose and grasp offset, and carried along the plan's path
    (robot/pick.py carry_path). Needs the [sim] extra (checked now)."""
    require_mujoco()
    cfg = cfg or PhysicsConfig()

    def judge(record: Grasp, frame: Frame, path: list[list[float]]) -> Verdict:
        return physics_verdict(record, frame.truth or [], truth_cal, list(pick.place_pose), pick.grasp_offset_m, cfg,
                               hidden=frame.hidden or [], opening_m=jaw_opening_m(record, pick.hand), path=path)

    return judge


def physics_verdict(record: Grasp, truth: list[dict], cal: Calibration, place_pose: list[float],
                    grasp_offset_m: float = 0.0, cfg: PhysicsConfig | None = None, hidden: Sequence[dict] = (),
                    opening_m: float | None = None, path: Sequence[Sequence[float]] = ()) -> Verdict:
    """Carry out RECORD's grasp (its pose_robot, the chosen object) on the scene TRUTH (the true
    calibration CAL puts it in the robot frame): its success, failure (PHYSICS_FAILURES),
    lifted_m and ms. The gripper is the class's (robot/verdict.py GRIPPER); a jaw opens to
    OPENING_M (the plan's, robot/clearance.py jaw_opening_m; None: its whole stroke). HIDDEN: the
    truth of objects the camera does not see, in the scene too (what rests on them) but never the target.
    PATH: the TCP positions the plan carries the part through (robot/pick.py carry_path: the lift,
    then on to above the place pose), followed from where the hand gripped; empty: up cfg.lift_m,
    then straight at that height to above the place pose."""
    return physics_run(record, truth, cal, place_pose, grasp_offset_m, cfg, hidden, opening_m, path).verdict


@dataclass
class PhysicsRun:
    """A check's verdict, and where it left the objects it simulated: by their truth's "id" (those
    without one are not listed), each one's base centre and rotation (robot frame, the columns its
    major axis, the axis across and up); `target`, the id of the object the hand went for."""

    verdict: Verdict
    poses: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    target: int | None = None


def physics_run(record: Grasp, truth: list[dict], cal: Calibration, place_pose: list[float],
                grasp_offset_m: float = 0.0, cfg: PhysicsConfig | None = None, hidden: Sequence[dict] = (),
                opening_m: float | None = None, path: Sequence[Sequence[float]] = ()) -> PhysicsRun:
    """physics_verdict, with the poses the check left its objects in: what a clutter-removal round
    (sim/clutter.py) goes on from. The poses are read once the check ends (the part carried, or the
    hand where it stopped)."""
    mujoco = require_mujoco()
    from edgepick.robot.verdict import GRIPPER, closing_yaw_deg

    start = time.perf_counter()
    cfg = cfg or PhysicsConfig()
    opening = cfg.jaw_stroke_m if opening_m is None else opening_m
    if not 0 < opening <= cfg.jaw_stroke_m:
        raise ParameterError(f"{{opening_m}}: must be in (0, {cfg.jaw_stroke_m}], the jaw's stroke", opening_m=opening_m)
    world = solids(truth, cal)
    k = _target(record, world)
    if k is None:
        return PhysicsRun(Verdict(False, "false detection", lifted_m=0.0, ms=0.0))
    world += solids(list(hidden), cal)
    # what the hand can meet on its way down, up and off: objects within NEAR_M of the target, and what those
    # rest on or hold up
    target = world[k]
    near = [k] + [i for i, s in enumerate(world) if i != k and np.linalg.norm((s.base - target.base)[:2]) < NEAR_M]
    world = [world[i] for i in with_what_they_touch(mujoco, world, near, cfg)]
    k = 0
    magnet = GRIPPER.get(record.cls) == "electromagnet"
    model, data, left_out = without_overlaps(mujoco, world, magnet, cfg)
    world = [s for i, s in enumerate(world) if i not in left_out]
    sim = _Sim(mujoco, model, data, world, k, magnet, cfg)
    yaw = math.radians(closing_yaw_deg(record.chosen_pose()))
    grasp = np.asarray(record.chosen_pose()[:3], np.float64) + [0, 0, grasp_offset_m]
    place = np.asarray(place_pose[:3], np.float64)
    lifted = grasp + [0, 0, cfg.lift_m]
    carry = [np.asarray(p[:3], np.float64) for p in path] or [lifted, np.array([*place[:2], max(place[2], lifted[2])])]
    verdict = sim.run(grasp, yaw, carry, opening)
    if not verdict.success and sim.settled_m > SETTLED_M:  # the scene, not the grasp, failed
        verdict = replace(verdict, failure="unsettled", note=f"the scene does not stand as rendered: the "
                          f"{target.cls} moved {1000 * sim.settled_m:.0f} mm before the hand reached it")
    if data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number:  # MuJoCo reset a diverging state
        verdict = Verdict(False, "unstable", lifted_m=0.0, note="the simulation diverged; this check says nothing")
    if left_out:
        verdict = replace(verdict, left_out=len(left_out))
    poses = {s.key: (data.xpos[model.body(f"obj{i}").id].copy(), data.xmat[model.body(f"obj{i}").id].reshape(3, 3).copy())
             for i, s in enumerate(world) if s.key is not None}
    return PhysicsRun(replace(verdict, ms=round(1000 * (time.perf_counter() - start), 1)), poses, target.key)


class _Sim:
    """One check: the hand's moves, the magnet's pull, and what the target does."""

    def __init__(self, mujoco, model, data, world: list[Solid], target: int, magnet: bool, cfg: PhysicsConfig):
        self.mj, self.model, self.data, self.world, self.magnet, self.cfg = mujoco, model, data, world, magnet, cfg
        self.solid = world[target]
        self.body = model.body(f"obj{target}").id
        self.hand_geoms = {model.geom(n).id for n in (["pole", "palm"] if magnet else ["pad_r", "pad_l", "palm"])}
        self.hand_array = np.array(sorted(self.hand_geoms))
        self.target_geoms = {g for g in range(model.ngeom) if model.geom_bodyid[g] == self.body}
        self.hand = model.body("hand").id
        self.magnet_on = False
        self.settled_m = 0.0  # how far the target moved while the scene settled, before the hand came down

    def step(self, hand: np.ndarray, seconds: float, ctrl: float | None = None) -> None:
        """Hold the hand at HAND for SECONDS (fingers driven to CTRL), 5 steps per update."""
        self.data.mocap_pos[0] = hand
        if ctrl is not None:
            self.data.ctrl[:] = ctrl
        for _ in range(max(1, round(seconds / (5 * self.cfg.timestep_s)))):
            self._pull()
            self.mj.mj_step(self.model, self.data, nstep=5)

    def move(self, a: np.ndarray, b: np.ndarray, speed: float, guarded: bool = False) -> tuple[np.ndarray, str | None]:
        """The hand from A to B at SPEED, speeding up and slowing down at cfg.acc_m_s2 as a moveL
        does; GUARDED (a descent) stops where the hand first rests on something: returns where it
        stopped and what it landed on (None: it reached B)."""
        dt = 5 * self.cfg.timestep_s
        for s in trapezoid(float(np.linalg.norm(b - a)), speed, self.cfg.acc_m_s2, dt):
            p = a + (b - a) * s
            self.step(p, dt)
            landed = self._landed() if guarded else None
            if landed is not None:
                return p, landed
        return b, None

    def _landed(self) -> str | None:
        """What a hand geom touches from above (a contact normal within 45 degrees of vertical)."""
        n = self.data.ncon
        if not n:
            return None
        contact = self.data.contact
        first, second = contact.geom1[:n], contact.geom2[:n]
        mine = np.isin(first, self.hand_array)
        hits = np.flatnonzero((mine | np.isin(second, self.hand_array)) & (np.abs(contact.frame[:n, 2]) > 0.7))
        if not len(hits):
            return None
        i = hits[0]
        body = self.model.geom_bodyid[second[i] if mine[i] else first[i]]
        return "table" if body == 0 else self.world[int(self.model.body(body).name[3:])].cls

    def _touching(self) -> set[int]:
        """The hand geoms in contact with the target."""
        out = set()
        for c in self.data.contact[:self.data.ncon]:
            for mine, other in ((c.geom1, c.geom2), (c.geom2, c.geom1)):
                if mine in self.hand_geoms and other in self.target_geoms:
                    out.add(mine)
        return out

    def _pull(self) -> None:
        """The magnet's pull: its rated force times the share of the pole face over the target's
        steel top face; through an air gap (up to cfg.magnet_reach_m) divided by (1 + gap /
        cfg.magnet_gap_m)^2 and applied to the part, in contact as MuJoCo's adhesion on the pole's
        contacts (a force through the contact solver: stable where a pull on a touching part is not)."""
        self.data.xfrc_applied[self.body] = 0.0
        if not (self.magnet and self.magnet_on):
            return
        self.data.ctrl[0] = 0.0
        if self.solid.cls not in MAGNETIC:
            return
        pos, rot = self.data.xpos[self.body], self.data.xmat[self.body].reshape(3, 3)
        face = self.data.xpos[self.hand]
        gap = self._gap()
        share = steel_share(self.solid, face, self.cfg.pole_radius_m, pos, rot)
        if gap <= CONTACT_M:
            self.data.ctrl[0] = share
        elif gap < self.cfg.magnet_reach_m:
            self.data.xfrc_applied[self.body, 2] = self.cfg.magnet_force_n * share / (1 + gap / self.cfg.magnet_gap_m) ** 2

    def _gap(self) -> float:
        """The height of the hand (the magnet's face) above the target's top face."""
        pos, rot = self.data.xpos[self.body], self.data.xmat[self.body].reshape(3, 3)
        return float(self.data.xpos[self.hand][2] - (pos + rot @ [0, 0, self.solid.dims["height"]])[2])

    def run(self, grasp: np.ndarray, yaw: float, carry: list[np.ndarray], opening: float) -> Verdict:
        """The moves from above GRASP down, the grip, and the carry: up to CARRY's first point and
        through the rest, each shifted by where the hand stopped against GRASP."""
        cfg = self.cfg
        self.data.mocap_quat[0] = [math.cos(yaw / 2), 0, 0, math.sin(yaw / 2)]
        above = grasp + [0, 0, 0.08]
        hand_q = self.model.jnt_qposadr[self.model.body_jntadr[self.hand]]
        self.data.qpos[hand_q:hand_q + 7] = [*above, *self.data.mocap_quat[0]]  # start at the approach pose
        self.data.mocap_pos[0] = above
        # the objects settle and the jaw opens to OPENING, as an RG2 told a width (each finger's travel
        # ends there: its joint's limit), at the speed its fingers' damping allows (FINGER_DAMPING)
        if not self.magnet:
            for finger in ("jr", "jl"):
                self.model.jnt_range[self.model.joint(finger).id, 1] = opening / 2
        seconds = 0.1 + opening / 2 * FINGER_DAMPING / cfg.jaw_force_n
        self.step(above, 0.3, None) if self.magnet else self.step(above, seconds, 1.0)
        start_z = float(self.data.xpos[self.body][2])
        self.settled_m = float(np.linalg.norm(self.data.xpos[self.body] - self.solid.base))
        # a magnet on its spring mount comes down until its face touches, at most its travel below the
        # commanded point; a jaw goes where it is sent
        bottom = grasp - [0, 0, cfg.magnet_travel_m] if self.magnet else grasp
        reached, landed = self.move(above, bottom, cfg.speed_m_s, guarded=True)
        # a finger that lands on anything but the target is blocked; the magnet's spring mount stops
        # its face on whatever it meets first, and the pull reaches the part across the gap left
        if landed is not None and not (self.magnet and (landed == self.solid.cls or
                                                        (landed != "table" and 0.0 <= self._gap() < cfg.magnet_reach_m))):
            what = "the table" if landed == "table" else f"a {landed}"
            return Verdict(False, "blocked", note=f"the hand lands on {what}", lifted_m=0.0)
        if self.magnet:
            self.magnet_on = True
            if cfg.magnet_steel_only:
                self._steel_only()
            self.step(reached, 0.2)
        else:
            self.step(reached, 0.5, -1.0)  # close
            if self._touching() != {self.model.geom("pad_r").id, self.model.geom("pad_l").id}:
                wide = self._across() > opening
                return Verdict(False, "too wide" if wide else "missed", lifted_m=0.0,
                               note="the object is wider than the opening" if wide else "the fingers closed on nothing")
        shift = reached - grasp  # a magnet's spring mount may stop it off the commanded point
        lifted = carry[0] + shift
        self.move(reached, lifted, cfg.speed_m_s)
        self.step(lifted, cfg.hold_s)
        rise = float(self.data.xpos[self.body][2]) - start_z
        if rise < lifted[2] - reached[2] - 0.03 or not self._touching():
            return Verdict(False, "missed" if rise < 0.01 else "dropped", lifted_m=round(rise, 4))
        hangs = float(self.data.xpos[self.hand][2] - self.data.xpos[self.body][2])  # how far below the hand
        at = lifted
        for point in carry[1:]:
            at, _ = self.move(at, point + shift, cfg.carry_speed_m_s)
        self.step(at, 0.3)
        rise = float(self.data.xpos[self.body][2]) - start_z
        slipped = float(self.data.xpos[self.hand][2] - self.data.xpos[self.body][2]) - hangs
        held = bool(self._touching()) and slipped < 0.03
        return Verdict(held, None if held else "dropped", lifted_m=round(rise, 4))

    def _steel_only(self) -> None:
        """From now on the hand (its pole face and palm) touches only the steel parts (cfg.magnet_steel_only):
        MuJoCo's adhesion, which pulls at every contact of the hand, then pulls no plastic or cardboard."""
        model, steel = self.model, 2  # a collision bit the hand shares with steel alone
        for g in self.hand_geoms:
            model.geom_contype[g] = model.geom_conaffinity[g] = steel
        for g in range(model.ngeom):
            name = model.body(model.geom_bodyid[g]).name
            if name.startswith("obj") and self.world[int(name[3:])].cls in MAGNETIC:
                model.geom_contype[g] |= steel
                model.geom_conaffinity[g] |= steel

    def _across(self) -> float:
        """The target's extent along the jaw's closing axis."""
        closing = self.data.xmat[self.hand].reshape(3, 3)[:, 0]
        d, rot = self.solid.dims, self.solid.rotation
        if self.solid.cls in ("box", "adapter"):
            return float(abs(closing @ rot[:, 0]) * d["length"] + abs(closing @ rot[:, 1]) * d["width"])
        return 2 * d["r_out"]
