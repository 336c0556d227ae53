"""The physics check's scene (sim/physics.py): the scene's objects as MuJoCo solids on the table,
the hand at the TCP (a two-finger jaw or a magnet's pole face), and the objects a scene placed into
each other taken out so that the rest can be simulated. Built from primitives only."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from edgepick.errors import ConfigError, ParameterError
from edgepick.runtime.calibration import Calibration

# effective density (kg/m^3) of the solid and its friction on the table
MATERIALS = {"box": (150.0, 0.5), "adapter": (700.0, 0.4), "bearing": (7850.0, 0.3), "disk": (7200.0, 0.3)}
FINGER_DAMPING = 300.0  # N s/m: at 40 N an RG2-like finger moves at about 0.13 m/s


@dataclass(frozen=True)
class PhysicsConfig:
    """The simulated grippers and the moves of a check, checked on creation."""

    jaw_force_n: float = 40.0  # RG2: 3-40 N per grip
    jaw_stroke_m: float = 0.110  # RG2: 0-110 mm between the fingers
    finger_depth_m: float = 0.015  # the fingertips below the commanded TCP: the jaw grips the top 15 mm of a side
    pad_friction: float = 0.9  # rubber pads; a contact takes the larger friction of its two geoms
    pole_radius_m: float = 0.05  # a 100 mm electro-holding magnet
    magnet_force_n: float = 1000.0  # its pull with the whole pole face on steel
    magnet_gap_m: float = 0.001  # an air gap this wide quarters its pull: force / (1 + gap / this)^2
    magnet_reach_m: float = 0.01  # it pulls nothing farther than this
    magnet_travel_m: float = 0.01  # its spring mount: it may come down this far below the commanded point
    lift_m: float = 0.10
    hold_s: float = 1.0
    speed_m_s: float = 0.10  # approach, descent and lift
    carry_speed_m_s: float = 0.25  # the envelope's cap on moveL speed
    acc_m_s2: float = 1.2  # every move speeds up and slows down at this (the envelope's cap)
    timestep_s: float = 0.004
    # the time constant of the contacts between the objects and with the table (MuJoCo's default, which scales a
    # contact's stiffness by the lighter body's mass: a heavy disk on a light adapter sinks it millimetres into the
    # table); a clutter-removal round (sim/clutter.py) takes two steps, the stiffest MuJoCo allows
    contact_s: float = 0.02
    # MuJoCo's adhesion holds whatever touches the pole face, steel or not (a plastic adapter under its rim goes
    # along): the verdict of a single scene only asks what the target did; a clutter-removal round, which goes on
    # from where every part ended, has the switched-on face touch the steel parts alone
    magnet_steel_only: bool = False

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if isinstance(value, bool):
                continue
            if not (math.isfinite(value) and value > 0):
                raise ParameterError(f"{{{name}}}: must be a positive number", **{name: value})


@dataclass
class Solid:
    """One object of the scene in the robot frame."""

    cls: str
    base: np.ndarray  # centre of its base
    rotation: np.ndarray  # 3x3: columns = its major axis, the axis across, up
    dims: dict  # solid truth's dimensions
    top: np.ndarray  # its grasp point (top centre)
    key: int | None = None  # the object's id in the truth, when it has one (a clutter-removal round)


def solids(truth: list[dict], cal: Calibration) -> list[Solid]:
    """The scene's objects (frame truth with their "solid" entries) in the robot frame."""
    out = []
    for t in truth:
        s = t.get("solid")
        if s is None:
            raise ConfigError("the scene's truth has no solids (made before the physics check existed); render it again")
        up = cal.R @ np.asarray(s["up_camera"], np.float64)
        axis = cal.R @ np.asarray(s["axis_camera"], np.float64)
        axis = axis - up * (axis @ up)
        axis /= np.linalg.norm(axis)
        rotation = np.stack([axis, np.cross(up, axis), up], axis=1)
        base = cal.apply(np.asarray(s["base_camera_m"], np.float64))
        dims = {k: v for k, v in s.items() if k not in ("base_camera_m", "up_camera", "axis_camera")}
        out.append(Solid(t["class"], base, rotation, dims, cal.apply(np.asarray(t["point_camera_m"], np.float64)),
                         t.get("id")))
    return out


def _quat(rotation: np.ndarray) -> str:
    from edgepick.robot.messages import quaternion

    x, y, z, w = quaternion(rotation)
    return f"{w:.9f} {x:.9f} {y:.9f} {z:.9f}"


def _cylinder(radius: float, z0: float, z1: float, attrs: str, density: float) -> str:
    """A vertical cylinder between heights z0 and z1 of its body."""
    return (f'<geom type="cylinder" size="{radius:.6f} {(z1 - z0) / 2:.6f}" pos="0 0 {(z0 + z1) / 2:.6f}" '
            f'{attrs} density="{density:.1f}"/>')


def _ring_density(r_in: float, r_out: float, density: float) -> float:
    """The density that gives a solid cylinder of radius R_OUT the mass of the annulus R_IN..R_OUT."""
    return density * (1 - (r_in / r_out) ** 2)


def _solid_xml(k: int, s: Solid) -> str:
    density, friction = MATERIALS[s.cls]
    attrs = f'friction="{friction} 0.005 0.0001"'
    d = s.dims
    if s.cls in ("box", "adapter"):
        geoms = [f'<geom type="box" size="{d["length"] / 2:.6f} {d["width"] / 2:.6f} {d["height"] / 2:.6f}" '
                 f'pos="0 0 {d["height"] / 2:.6f}" {attrs} density="{density}"/>']
    elif s.cls == "bearing":  # collides as a solid cylinder: the pole face is wider than the bore
        geoms = [_cylinder(d["r_out"], 0.0, d["height"], attrs, _ring_density(d["r_in"], d["r_out"], density))]
    else:  # the friction ring and the hub as two cylinders, each with the mass of its annulus
        geoms = [_cylinder(d["r_out"], 0.0, d["ring_h"], attrs, _ring_density(d["r_ring_in"], d["r_out"], density)),
                 _cylinder(d["r_hat"], d["ring_h"], d["hat_h"], attrs,
                           _ring_density(d["r_bore"], d["r_hat"], density))]
    base = " ".join(f"{v:.6f}" for v in s.base + np.array([0, 0, 0.0005]))
    return f'<body name="obj{k}" pos="{base}" quat="{_quat(s.rotation)}"><freejoint/>{"".join(geoms)}</body>'


def _hand_xml(magnet: bool, cfg: PhysicsConfig) -> str:
    """The hand at the TCP, z up: the pole face at its origin, or two fingers closing along its x
    whose tips are cfg.finger_depth_m below it. A free body welded to a kinematic target (MuJoCo's
    mocap), so that it moves with a velocity and its contacts carry friction."""
    palm = '<geom name="palm" type="box" size="0.04 0.03 0.02" pos="0 0 {z}" mass="0.5"/>'
    target = '<body name="target" mocap="true"/>'
    if magnet:  # the pole face: a disc
        return (f'{target}<body name="hand"><freejoint/>'
                f'<geom name="pole" type="cylinder" size="{cfg.pole_radius_m:.4f} 0.01" pos="0 0 0.01" mass="0.5"/>'
                f'{palm.format(z=0.04)}</body>')
    pad_h = 0.02
    z = -cfg.finger_depth_m + pad_h
    stiff = 2 * cfg.timestep_s  # the stiffest contacts and joint limits a step allows: the pads must not sink in
    fingers = []
    for side, sign in (("r", 1), ("l", -1)):
        fingers.append(f'<body name="finger_{side}"><joint name="j{side}" type="slide" axis="{sign} 0 0" range="0 '
                       f'{cfg.jaw_stroke_m / 2:.4f}" damping="{FINGER_DAMPING}" solreflimit="{stiff} 1" solimplimit="0.99 0.999 '
                       f'0.001"/><geom name="pad_{side}" type="box" size="0.005 0.012 {pad_h}" pos="{sign * 0.005} 0 '
                       f'{z:.4f}" mass="0.2" friction="{cfg.pad_friction} 0.02 0.001" solref="{stiff} 1" '
                       'solimp="0.99 0.99 0.001"/></body>')
    return f'{target}<body name="hand"><freejoint/>{"".join(fingers)}{palm.format(z=z + pad_h + 0.03)}</body>'


def scene_xml(world: list[Solid], magnet: bool, cfg: PhysicsConfig, hand: bool = True) -> str:
    """The MuJoCo model of WORLD on the table with the hand (a magnet or a jaw); HAND False: the objects alone."""
    if not hand:
        return (f'<mujoco><option timestep="{cfg.timestep_s}" cone="elliptic" impratio="10" noslip_iterations="3"/>'
                f'<default><geom condim="4" solref="{cfg.contact_s} 1"/></default><worldbody>'
                '<geom name="table" type="plane" size="2 2 0.01" friction="0.5 0.005 0.0001"/>'
                f'{"".join(_solid_xml(k, s) for k, s in enumerate(world))}</worldbody></mujoco>')
    # the jaw: a force on each finger (the RG2 closes until it holds its set force), the magnet: adhesion
    actuators = f'<adhesion body="hand" ctrlrange="0 1" gain="{cfg.magnet_force_n}"/>' if magnet else \
        f'<motor joint="jr" ctrlrange="-1 1" gear="{2 * cfg.jaw_force_n}"/>'
    # the RG2's fingers are linked: they move together, so the grip stays centred on the hand
    coupled = "" if magnet else '<joint joint1="jr" joint2="jl"/>'
    return (f'<mujoco><option timestep="{cfg.timestep_s}" cone="elliptic" impratio="10" noslip_iterations="3"/>'
            f'<default><geom condim="4" solref="{cfg.contact_s} 1"/></default><worldbody>'
            '<geom name="table" type="plane" size="2 2 0.01" friction="0.5 0.005 0.0001"/>'
            f'{"".join(_solid_xml(k, s) for k, s in enumerate(world))}{_hand_xml(magnet, cfg)}</worldbody>'
            f'<equality><weld body1="target" body2="hand" solref="0.01 1"/>{coupled}</equality>'
            f'<actuator>{actuators}</actuator></mujoco>')


OVERLAP_M = 0.003  # solids that the scene placed this far into each other cannot both be simulated
TOUCH_M = 0.005  # solids this close touch: one rests on or leans against the other


def without_overlaps(mujoco, world: list[Solid], magnet: bool, cfg: PhysicsConfig):
    """The model and data of WORLD less the objects the scene placed inside others (a scene from
    elsewhere may, and the simulated shapes fill in what the renderer's leave open, such as a box's
    rounded corners; pushed apart, they would explode). Of each such pair the one left
    out is the one farther from the target (index 0) along the chain of objects touching it (what
    the target rests on, and what that rests on, stay), then in space. Returns the left out
    indices too."""
    left_out: set[int] = set()
    hops: list[float] | None = None
    while True:
        kept = [i for i in range(len(world)) if i not in left_out]
        model = mujoco.MjModel.from_xml_string(scene_xml([world[i] for i in kept], magnet, cfg))
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        names = [model.body(model.geom_bodyid[g]).name for g in range(model.ngeom)]
        clash = None
        for c in data.contact[:data.ncon]:
            a, b = names[c.geom1], names[c.geom2]
            if c.dist < -OVERLAP_M and a.startswith("obj") and b.startswith("obj") and a != b:
                if hops is None:  # at the first clash, on the whole scene
                    hops = _touch_hops(mujoco, model, data, names, len(world))
                pair = (kept[int(a[3:])], kept[int(b[3:])])
                clash = max(pair, key=lambda i: (i != 0, hops[i], float(np.linalg.norm(world[i].base - world[0].base))))
                break
        if clash is None:
            return model, data, left_out
        left_out.add(clash)


def _touch_hops(mujoco, model, data, names: list[str], count: int) -> list[float]:
    """For each of COUNT objects (bodies obj0, obj1, ...), how many objects touching one another
    (within TOUCH_M) lie between it and obj0, the target: 0 for the target, 1 for what it rests on
    or leans against, inf for an object not linked to it."""
    touching = _touching(mujoco, model, data, names, count)
    hops, front = [math.inf] * count, [0]
    hops[0] = 0
    while front:
        nearer = []
        for i in front:
            for j in touching[i]:
                if hops[j] == math.inf:
                    hops[j] = hops[i] + 1
                    nearer.append(j)
        front = nearer
    return hops


def _touching(mujoco, model, data, names: list[str], count: int) -> dict[int, set[int]]:
    """For each of COUNT objects (bodies obj0, obj1, ...), the objects within TOUCH_M of it."""
    geoms: dict[int, list[int]] = {}
    for g, name in enumerate(names):
        if name.startswith("obj"):
            geoms.setdefault(int(name[3:]), []).append(g)
    touching: dict[int, set[int]] = {k: set() for k in range(count)}
    for a in range(count):
        for b in range(a + 1, count):
            if any(mujoco.mj_geomDistance(model, data, ga, gb, TOUCH_M, None) < TOUCH_M
                   for ga in geoms.get(a, []) for gb in geoms.get(b, [])):
                touching[a].add(b)
                touching[b].add(a)
    return touching


def with_what_they_touch(mujoco, world: list[Solid], chosen: list[int], cfg: PhysicsConfig) -> list[int]:
    """CHOSEN (indices into WORLD, in order) and, after them, every other object of WORLD linked to
    one of them by objects touching one another (within TOUCH_M): what a chosen object rests on,
    and what rests on it. A check that leaves out what a part lies on drops that part onto the
    table, into the place where the left-out object stands."""
    if len(chosen) == len(world):
        return list(chosen)
    model = mujoco.MjModel.from_xml_string(scene_xml(world, False, cfg, hand=False))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    names = [model.body(model.geom_bodyid[g]).name for g in range(model.ngeom)]
    touching = _touching(mujoco, model, data, names, len(world))
    kept, front = list(chosen), list(chosen)
    while front:
        linked = sorted({j for i in front for j in touching[i]} - set(kept))
        kept += linked
        front = linked
    return kept


REST_M_S = 0.003  # an object moving slower than this (and turning slower than REST_RAD_S) is at rest
REST_RAD_S = 0.05


def settle(mujoco, world: list[Solid], cfg: PhysicsConfig, max_s: float = 3.0
           ) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """WORLD's objects (robot frame, the table at z = 0) left alone until they rest: each one's base
    centre and rotation once every object moves slower than REST_M_S and turns slower than
    REST_RAD_S (looked at every 0.1 s, from 0.2 s on), or after MAX_S. None when the simulation
    diverged (MuJoCo reset a state): the poses would mean nothing."""
    if not world:
        return []
    model = mujoco.MjModel.from_xml_string(scene_xml(world, False, cfg, hand=False))
    data = mujoco.MjData(model)
    bodies = [model.body(f"obj{k}").id for k in range(len(world))]
    speeds = np.array([model.jnt_dofadr[model.body_jntadr[b]] for b in bodies])
    per_look = max(1, round(0.1 / cfg.timestep_s))
    for look in range(max(1, math.ceil(max_s / 0.1))):
        mujoco.mj_step(model, data, nstep=per_look)
        if data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number:
            return None
        linear = np.linalg.norm(np.stack([data.qvel[a:a + 3] for a in speeds]), axis=1)
        angular = np.linalg.norm(np.stack([data.qvel[a + 3:a + 6] for a in speeds]), axis=1)
        if look >= 1 and linear.max() < REST_M_S and angular.max() < REST_RAD_S:
            break
    return [(data.xpos[b].copy(), data.xmat[b].reshape(3, 3).copy()) for b in bodies]
