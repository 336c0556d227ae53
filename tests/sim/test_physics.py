"""The physics verdict (MuJoCo): a centred grasp carries each class; what a parallel jaw and a magnet
really tolerate decides the rest; the same inputs give the same verdict."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("mujoco")

from edgepick.errors import ParameterError  # noqa: E402
from edgepick.robot.verdict import Verdict  # noqa: E402
from edgepick.runtime.calibration import Calibration  # noqa: E402
from edgepick.runtime.grasp_record import Grasp  # noqa: E402
from edgepick.sim.physics import PhysicsConfig, physics_verdict, solids, steel_share  # noqa: E402
from tests.conftest import make_grasp  # noqa: E402

IDENTITY = Calibration(np.eye(3), np.zeros(3), 0.0, 0)  # the tests' "camera" frame is the robot frame
PLACE = [-0.05, -0.32, 0.10, math.pi, 0.0, 0.0]


def block(cls: str, x: float, y: float, yaw: float, length: float, width: float, height: float) -> dict:
    return {"class": cls, "point_camera_m": [x, y, height],
            "solid": {"base_camera_m": [x, y, 0.0], "up_camera": [0, 0, 1], "axis_camera": [math.cos(yaw), math.sin(yaw), 0],
                      "height": height, "length": length, "width": width}}


def bearing(x: float, y: float, r_out: float = 0.038, r_in: float = 0.02, height: float = 0.035) -> dict:
    return {"class": "bearing", "point_camera_m": [x, y, height],
            "solid": {"base_camera_m": [x, y, 0.0], "up_camera": [0, 0, 1], "axis_camera": [1, 0, 0], "height": height,
                      "r_out": r_out, "r_in": r_in}}


def disk(x: float, y: float) -> dict:
    return {"class": "disk", "point_camera_m": [x, y, 0.055],
            "solid": {"base_camera_m": [x, y, 0.0], "up_camera": [0, 0, 1], "axis_camera": [1, 0, 0], "height": 0.055,
                      "r_out": 0.13, "r_ring_in": 0.058, "ring_h": 0.025, "r_hat": 0.068, "r_bore": 0.032,
                      "hat_h": 0.055}}


def grasp(cls: str, x: float, y: float, z: float, closing_yaw: float = 0.0) -> Grasp:
    """A chosen grasp: the TCP at (x, y, z), tool down, the fingers closing along CLOSING_YAW."""
    return make_grasp(cls, [x, y, z, math.pi * math.cos(closing_yaw / 2), math.pi * math.sin(closing_yaw / 2), 0.0])


def verdict(record: Grasp, scene: list[dict], **cfg) -> Verdict:
    return physics_verdict(record, scene, IDENTITY, PLACE, cfg=PhysicsConfig(**cfg) if cfg else None)


@pytest.mark.parametrize("scene, record", [
    ([block("adapter", 0.25, 0.0, 0.0, 0.062, 0.044, 0.036)], grasp("adapter", 0.25, 0.0, 0.036, math.pi / 2)),
    ([block("box", 0.25, 0.05, 0.4, 0.16, 0.09, 0.08)], grasp("box", 0.25, 0.05, 0.08, 0.4 + math.pi / 2)),
    ([bearing(0.25, 0.0)], grasp("bearing", 0.25, 0.0, 0.035)),
    ([disk(0.25, 0.0)], grasp("disk", 0.25, 0.0, 0.055)),
], ids=["adapter", "box", "bearing", "disk"])
def test_a_centred_grasp_carries_each_class_to_the_place_pose(scene, record):
    v = verdict(record, scene)
    assert v.success and v.failure is None, v
    assert v.lifted_m > 0.07 and v.ms > 0


def test_a_jaw_centres_the_object_across_its_fingers_but_not_along_them():
    scene = [block("adapter", 0.25, 0.0, 0.0, 0.062, 0.044, 0.036)]  # the jaw closes along y, across its 44 mm
    assert verdict(grasp("adapter", 0.25, 0.015, 0.036, math.pi / 2), scene).success  # 15 mm across: pushed centre
    off_along = verdict(grasp("adapter", 0.25 + 0.045, 0.0, 0.036, math.pi / 2), scene)
    assert not off_along.success and off_along.failure == "missed"  # 45 mm along: the pads miss its end


def test_a_jaw_needs_the_object_to_fit_its_stroke():
    wide = [block("box", 0.25, 0.0, 0.0, 0.20, 0.13, 0.08)]  # 130 mm across: over the RG2's 110 mm
    v = verdict(grasp("box", 0.25, 0.0, 0.08, math.pi / 2), wide)
    assert not v.success and v.failure in ("blocked", "too wide")
    assert verdict(grasp("box", 0.25, 0.0, 0.08, math.pi / 2), wide, jaw_stroke_m=0.16).success  # an RG6's stroke


def test_a_jaw_opened_to_the_parts_width_grips_it_beside_a_twin_the_whole_stroke_lands_on():
    # two adapters side by side, 33 mm apart across their 44 mm: the jaw closing across them
    scene = [block("adapter", 0.25, 0.0, 0.0, 0.062, 0.044, 0.036), block("adapter", 0.25, 0.077, 0.0, 0.062, 0.044, 0.036)]
    record = grasp("adapter", 0.25, 0.0, 0.036, math.pi / 2)
    whole = physics_verdict(record, scene, IDENTITY, PLACE)  # opened to its 110 mm: a pad comes down on the twin
    assert not whole.success and whole.failure == "blocked" and "adapter" in whole.note, whole
    fitted = physics_verdict(record, scene, IDENTITY, PLACE, opening_m=0.044 + 2 * 0.015)
    assert fitted.success, fitted
    narrow = physics_verdict(record, scene, IDENTITY, PLACE, opening_m=0.040)  # narrower than the part
    assert not narrow.success and narrow.failure in ("blocked", "too wide"), narrow
    with pytest.raises(ParameterError, match="opening_m"):
        physics_verdict(record, scene, IDENTITY, PLACE, opening_m=0.2)


def test_a_jaw_grips_only_when_its_fingers_reach_down_the_sides():
    scene = [block("adapter", 0.25, 0.0, 0.0, 0.062, 0.044, 0.036)]
    high = verdict(grasp("adapter", 0.25, 0.0, 0.036 + 0.02, math.pi / 2), scene)  # 20 mm above: tips above the top
    assert not high.success and high.failure == "missed"


def test_a_magnet_holds_wherever_its_face_covers_enough_steel():
    assert verdict(grasp("bearing", 0.25 + 0.02, 0.0, 0.035), [bearing(0.25, 0.0)]).success  # 20 mm off
    assert not verdict(grasp("bearing", 0.25 + 0.09, 0.0, 0.035), [bearing(0.25, 0.0)]).success  # off the part
    weak = verdict(grasp("bearing", 0.25, 0.0, 0.035), [bearing(0.25, 0.0)], magnet_force_n=2.0)
    assert not weak.success  # 2 N at full cover: less than the bearing's weight


def test_a_magnet_comes_down_its_spring_travel_until_it_touches():
    scene = [bearing(0.25, 0.0)]
    assert verdict(grasp("bearing", 0.25, 0.0, 0.035 + 0.008), scene).success  # 8 mm high: within the 10 mm
    high = verdict(grasp("bearing", 0.25, 0.0, 0.035 + 0.025), scene)  # 25 mm high: its face stops 15 mm above
    assert not high.success and high.failure == "missed"
    assert verdict(grasp("bearing", 0.25, 0.0, 0.035 + 0.015), scene, magnet_travel_m=0.002).failure == "missed"


def test_a_magnet_that_lands_on_a_slightly_taller_neighbour_pulls_the_part_across_the_gap():
    # the face comes down on an adapter 4 mm higher than the bearing and overlapping its rim; its spring
    # mount stops there, and the pull across 4 mm lifts the bearing to the face
    scene = [bearing(0.25, 0.0), block("adapter", 0.25, 0.06, 0.0, 0.062, 0.044, 0.039)]
    v = verdict(grasp("bearing", 0.25, 0.0, 0.035), scene)
    assert v.success and v.lifted_m > 0.07, v
    beyond = [bearing(0.25, 0.0), block("adapter", 0.25, 0.06, 0.0, 0.062, 0.044, 0.035 + 0.014)]  # past its reach
    v = verdict(grasp("bearing", 0.25, 0.0, 0.035), beyond)
    assert not v.success and v.failure == "blocked" and "adapter" in v.note, v


def test_steel_share_is_the_pole_face_over_the_annulus():
    (ring,) = solids([bearing(0.0, 0.0, r_out=0.04, r_in=0.02)], IDENTITY)
    centre = np.array([0.0, 0.0, 0.035])
    expected = (0.04 ** 2 - 0.02 ** 2) / 0.05 ** 2  # the whole annulus under a 50 mm pole face
    assert abs(steel_share(ring, centre, 0.05, ring.base, ring.rotation) - expected) < 0.03
    assert steel_share(ring, centre, 0.015, ring.base, ring.rotation) == 0.0  # a small face over the bore
    xs, ys = np.meshgrid(np.linspace(-0.05, 0.05, 801), np.linspace(-0.05, 0.05, 801))
    face = np.hypot(xs, ys) <= 0.05
    for offset in (0.01, 0.03, 0.06, 0.085):  # the face moved off the part's axis: a dense count agrees
        r = np.hypot(xs + offset, ys)[face]
        counted = float(np.mean((r >= 0.02) & (r <= 0.04)))
        assert abs(steel_share(ring, centre + [offset, 0, 0], 0.05, ring.base, ring.rotation) - counted) < 0.002


def test_a_neighbour_under_the_hand_blocks_the_descent():
    scene = [bearing(0.25, 0.0), block("box", 0.25, 0.075, 0.0, 0.12, 0.08, 0.09)]  # a taller box 75 mm beside
    v = verdict(grasp("bearing", 0.25, 0.0, 0.035), scene)
    assert not v.success and v.failure == "blocked" and "box" in v.note


def on(item: dict, z: float) -> dict:
    """ITEM lifted so that its base lies at height Z: stacked on what is under it."""
    item = {**item, "solid": {**item["solid"], "base_camera_m": [*item["solid"]["base_camera_m"][:2], z]}}
    item["point_camera_m"] = [*item["point_camera_m"][:2], item["point_camera_m"][2] + z]
    return item


def test_what_the_target_rests_on_stays_when_a_nearer_neighbour_intersects_it():
    # an adapter on the end of a long box; a bearing placed 13 mm into that box, nearer the adapter
    # than the box's centre: the bearing is left out, not the box the adapter stands on
    support = block("box", 0.40, 0.0, 0.0, 0.30, 0.09, 0.05)
    target = on(block("adapter", 0.285, 0.0, 0.0, 0.062, 0.044, 0.036), 0.05)
    v = verdict(grasp("adapter", 0.285, 0.0, 0.086, math.pi / 2), [target, support, bearing(0.30, 0.07)])
    assert v.success and v.left_out == 1, v


def test_a_failure_of_a_target_that_was_not_at_rest_is_the_scenes():
    # an adapter at the height of a disk's hub but beside it, over its lower ring: it falls before
    # the hand reaches it
    target = on(block("adapter", 0.25 + 0.10, 0.0, 0.0, 0.062, 0.044, 0.036), 0.055)
    v = verdict(grasp("adapter", 0.35, 0.0, 0.091, math.pi / 2), [target, disk(0.25, 0.0)])
    assert not v.success and v.failure == "unsettled" and "moved" in v.note, v


def test_an_object_the_camera_does_not_see_still_holds_up_what_rests_on_it():
    # a bearing hidden under a box: without it in the scene, the box would fall onto the table
    target = on(block("box", 0.25, 0.0, 0.0, 0.16, 0.09, 0.06), 0.035)
    record = grasp("box", 0.25, 0.0, 0.095, math.pi / 2)
    assert verdict(record, [target]).failure == "unsettled"
    v = physics_verdict(record, [target], IDENTITY, PLACE, hidden=[bearing(0.25, 0.0)])
    assert v.success and v.lifted_m > 0.07, v


def test_a_false_detection_is_judged_without_simulating():
    v = verdict(grasp("disk", 0.25, 0.0, 0.05), [bearing(0.25, 0.0)])
    assert v.to_dict() == {"success": False, "failure": "false detection", "lifted_m": 0.0, "ms": 0.0}


def test_the_same_inputs_give_the_same_verdict():
    scene = [block("box", 0.25, 0.05, 0.4, 0.16, 0.09, 0.08), bearing(0.2, -0.1)]
    record = grasp("box", 0.252, 0.047, 0.081, 0.4 + math.pi / 2 + 0.1)
    first, second = verdict(record, scene), verdict(record, scene)
    assert replace(first, ms=None) == replace(second, ms=None)


def test_a_check_says_where_it_left_the_objects_it_simulated():
    """physics_run (what a clutter-removal round goes on from): the part carried to the place pose, a
    neighbour where it stood, both by their truth's id; an object without an id is not listed."""
    from edgepick.sim.physics import physics_run

    scene = [{**block("adapter", 0.25, 0.0, 0.0, 0.062, 0.044, 0.036), "id": 3}, {**bearing(0.25, 0.12), "id": 8},
             bearing(0.1, -0.15)]
    run = physics_run(grasp("adapter", 0.25, 0.0, 0.036, math.pi / 2), scene, IDENTITY, PLACE)
    assert run.verdict.success and run.target == 3 and set(run.poses) == {3, 8}
    carried, rotation = run.poses[3]
    assert np.linalg.norm(carried[:2] - np.array(PLACE[:2])) < 0.02 and carried[2] > 0.08
    assert np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6)
    stood, _ = run.poses[8]
    assert np.linalg.norm(stood - [0.25, 0.12, 0.0]) < 0.002


def test_a_part_near_the_target_stays_on_what_it_rests_on_however_far_that_lies():
    """A bearing 0.29 m from the target lies on a box whose centre is 0.34 m from it (farther than
    the check's reach): the box is simulated too, and the bearing stays on it, not dropped onto the
    table into the box's place (where a round's next settling would fling the two apart)."""
    from edgepick.sim.physics import NEAR_M, physics_run

    support = {**block("box", 0.25, -0.34, math.pi / 2, 0.16, 0.09, 0.06), "id": 1}
    resting = {**on(bearing(0.25, -0.29), 0.06), "id": 2}
    target = {**block("adapter", 0.25, 0.0, 0.0, 0.062, 0.044, 0.036), "id": 3}
    assert 0.29 < NEAR_M < 0.34
    run = physics_run(grasp("adapter", 0.25, 0.0, 0.036, math.pi / 2), [target, resting, support], IDENTITY, PLACE)
    assert run.verdict.success and set(run.poses) == {1, 2, 3}, run
    stayed, _ = run.poses[2]
    assert np.linalg.norm(stayed - [0.25, -0.29, 0.06]) < 0.003, stayed


def test_settle_brings_objects_to_rest_and_stiff_contacts_hold_a_heavy_disk_on_light_parts():
    """MuJoCo's default contacts scale with the lighter body: a brake disk resting on two adapters pushes
    them millimetres into the table; contacts as stiff as a step allows (a round's) keep them on it."""
    import mujoco

    from edgepick.sim.physics_scene import settle

    under = [block("adapter", 0.25 + dx, 0.0, math.pi / 2, 0.062, 0.044, 0.036) for dx in (-0.05, 0.05)]
    scene = solids([*under, on(disk(0.25, 0.0), 0.036)], IDENTITY)
    sunk = {}
    for name, cfg in (("default", PhysicsConfig()), ("stiff", PhysicsConfig(contact_s=0.012))):
        rested = settle(mujoco, scene, cfg)
        sunk[name] = -min(base[2] for base, _ in rested[:2])  # the adapters' bases below the table
        disk_base, disk_rotation = rested[2]
        assert disk_rotation[2, 2] > 0.99  # the disk still lies flat on them
    assert sunk["default"] > 0.003 > 0.002 > sunk["stiff"], sunk
    falling = solids([on(bearing(0.25, 0.0), 0.02)], IDENTITY)  # 2 cm above the table: it falls and rests
    ((base, rotation),) = settle(mujoco, falling, PhysicsConfig(contact_s=0.012))
    assert abs(base[2]) < 0.001 and rotation[2, 2] > 0.999


def test_a_magnet_that_holds_steel_only_leaves_a_plastic_neighbour_under_its_rim():
    """MuJoCo's adhesion pulls at every contact of the pole face: an adapter under its rim goes along with
    the bearing, unless the face touches steel alone once switched on (a round's check)."""
    from edgepick.sim.physics import physics_run

    scene = [{**bearing(0.25, 0.0), "id": 1}, {**block("adapter", 0.31, 0.0, math.pi / 2, 0.062, 0.044, 0.036), "id": 2}]
    for steel_only, stays in ((False, False), (True, True)):
        run = physics_run(grasp("bearing", 0.25, 0.0, 0.035), scene, IDENTITY, PLACE,
                          cfg=PhysicsConfig(magnet_steel_only=steel_only))
        assert run.verdict.success, run.verdict
        moved = float(np.linalg.norm(run.poses[2][0] - [0.31, 0.0, 0.0]))
        assert (moved < 0.01) == stays, moved


def test_physics_config_refuses_what_is_not_a_positive_number():
    with pytest.raises(ParameterError, match="jaw_force_n=-1"):
        PhysicsConfig(jaw_force_n=-1)


def test_pick_gives_each_cycle_a_physics_verdict_after_its_commands(tmp_path):
    import json

    from tests.conftest import run_cli

    proc = run_cli("pick", "--cycles", "3", "--verdict", "both", "--log", str(tmp_path / "log.jsonl"))
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["physics"]["success"] + sum(summary["physics"]["failures"].values()) == 3
    for r in summary["results"]:
        assert set(r["physics"]) >= {"success", "failure"} and "physics: " in proc.stderr
        assert r["scene"]["lighting"] in ("ceiling", "ceiling+white", "single", "hazard")
    refused = run_cli("pick", "--verdict", "physics", "--camera", "dir:" + str(tmp_path), "--model", "m.onnx",
                      "--log", str(tmp_path / "other.jsonl"))
    assert refused.returncode == 2 and refused.stderr.count("\n") == 1 and "--verdict physics" in refused.stderr


@pytest.mark.parametrize("neighbour_height, lift_over", [(0.11, None), (0.20, 0.20)], ids=["box", "tower"])
def test_the_hand_carries_along_the_plans_path_over_the_parts_in_view(neighbour_height, lift_over):
    """The check's hand follows the plan's carry (robot/pick.py carry_path), whose lift clears the
    tallest top in view: a part carried straight at 10 cm above its grasp point (the path a check
    without a plan takes) drags a taller neighbour on its way off the table; the plan's way up and
    over leaves it standing. A tower taller than the via points' height needs the higher lift."""
    from edgepick.robot.pick import PickConfig, carry_path, plan_pick
    from edgepick.sim.physics import physics_run

    record = grasp("bearing", 0.30, 0.10, 0.035)
    low = carry_path(plan_pick(record, PickConfig()))
    a, b = np.array(low[0][:2]), np.array(low[1][:2])
    where = a + 0.55 * (b - a)  # on the way from the lift to the first via point, across it
    scene = [{**bearing(0.30, 0.10), "id": 1},
             {**block("box", *where, math.atan2(*(b - a)[::-1]) + math.pi / 2, 0.16, 0.09, neighbour_height), "id": 2}]
    paths = {"straight": [], "the plan's": carry_path(plan_pick(record, PickConfig(), tallest_z_m=lift_over))}
    if lift_over is not None:
        paths["the plan's, lifted as if nothing stood taller"] = low
    moved = {}
    for name, path in paths.items():
        run = physics_run(record, scene, IDENTITY, PLACE, path=path)
        assert run.verdict.success, (name, run.verdict)
        moved[name] = float(np.linalg.norm(run.poses[2][0][:2] - where))
    assert moved.pop("the plan's") < 0.005 and all(m > 0.05 for m in moved.values()), moved
