"""The hand's footprint on the frame's depth: a magnet face or a finger that would come down on a
taller neighbour, or a jaw too narrow for its object, is refused before the target is chosen."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from edgepick.errors import ParameterError
from edgepick.geometry import Intrinsics
from edgepick.robot.clearance import HandShape, hand_clearance, jaw_opening_m
from edgepick.robot.envelope import Envelope
from edgepick.robot.pick import PickConfig, along_its_length, choose_target
from edgepick.robot.verdict import closing_yaw_deg, yaw_difference_deg
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp_record import Grasp
from tests.conftest import make_grasp

INTR = Intrinsics.d415(640, 480)
MOUNT = 0.7
# a camera straight above robot point (0.28, 0): camera x = robot x, camera y = -robot y, depth = 0.7 - z
CAL = Calibration(np.diag([1.0, -1.0, -1.0]), np.array([0.28, 0.0, MOUNT]), 0.0, 0)


def depth_of(objects: list[tuple]) -> np.ndarray:
    """Depth readings (mm) of flat-topped objects on the table: (x, y, top height, inside(dx, dy))."""
    v, u = np.mgrid[0:INTR.height, 0:INTR.width].astype(np.float64)
    height = np.zeros(u.shape)
    for x, y, top, inside in objects:
        d = MOUNT - top  # where the ray meets the object's top plane
        rx, ry = 0.28 + (u - INTR.cx) * d / INTR.fx, -(v - INTR.cy) * d / INTR.fy
        height = np.where(inside(rx - x, ry - y) & (top > height), top, height)
    return np.round((MOUNT - height) / INTR.depth_scale).astype(np.uint16)


def disc(r: float):
    return lambda dx, dy: np.hypot(dx, dy) <= r


def rect(half_x: float, half_y: float):
    return lambda dx, dy: (np.abs(dx) <= half_x) & (np.abs(dy) <= half_y)


def record(cls: str, x: float, y: float, z: float, closing_yaw: float = 0.0, area: int = 1000) -> Grasp:
    return make_grasp(cls, [x, y, z, math.pi * math.cos(closing_yaw / 2), math.pi * math.sin(closing_yaw / 2), 0.0],
                      pixel=(0.0, 0.0), area_px=area, depth_m=MOUNT - z)


def test_a_magnet_face_over_a_taller_neighbour_is_refused():
    bearing = (0.28, 0.0, 0.035, disc(0.038))
    clear = hand_clearance(depth_of([bearing]), INTR, CAL)
    assert clear(record("bearing", 0.28, 0.0, 0.035)) is None
    beside = (0.28, 0.085, 0.045, rect(0.03, 0.022))  # an adapter 10 mm taller, its edge 63 mm from the centre
    clear = hand_clearance(depth_of([bearing, beside]), INTR, CAL)
    assert clear(record("bearing", 0.28, 0.0, 0.035)) is None  # beyond the 50 mm face
    near = (0.28, 0.065, 0.045, rect(0.03, 0.022))  # its edge 43 mm from the centre: under the face
    reason = hand_clearance(depth_of([bearing, near]), INTR, CAL)(record("bearing", 0.28, 0.0, 0.035))
    assert reason is not None and "magnet" in reason
    lower = (0.28, 0.065, 0.025, rect(0.03, 0.022))  # a lower neighbour: the face touches the bearing first
    assert hand_clearance(depth_of([bearing, lower]), INTR, CAL)(record("bearing", 0.28, 0.0, 0.035)) is None


def test_a_jaw_needs_its_opening_to_reach_past_the_object():
    box = (0.28, 0.0, 0.08, rect(0.08, 0.065))  # 130 mm across y
    across_y = record("box", 0.28, 0.0, 0.08, closing_yaw=math.pi / 2)
    reason = hand_clearance(depth_of([box]), INTR, CAL)(across_y)
    assert reason is not None and "finger" in reason  # the 110 mm jaw's fingers land on its top
    assert hand_clearance(depth_of([box]), INTR, CAL, HandShape(jaw_opening_m=0.16))(across_y) is None


def test_a_jaw_opened_to_the_parts_width_clears_a_twin_that_the_whole_stroke_lands_on():
    adapter = (0.28, 0.0, 0.036, rect(0.022, 0.031))  # 44 mm across x
    twin = (0.28 + 0.077, 0.0, 0.036, rect(0.022, 0.031))  # another one beside it, 33 mm away
    clear = hand_clearance(depth_of([adapter, twin]), INTR, CAL)
    whole = record("adapter", 0.28, 0.0, 0.036, closing_yaw=0.0, area=2000)  # no width: the jaw opens all the way
    assert jaw_opening_m(whole) == HandShape().jaw_opening_m and "finger" in clear(whole)
    fitted = replace(whole, width_m=0.044)
    assert jaw_opening_m(fitted) == pytest.approx(0.044 + 2 * HandShape().finger_room_m)
    assert clear(fitted) is None  # its fingers come down in the 33 mm between the two
    assert jaw_opening_m(replace(whole, width_m=0.2)) == HandShape().jaw_opening_m  # never past the stroke
    assert "finger" in hand_clearance(depth_of([adapter, twin]), INTR, CAL, HandShape(finger_room_m=0.04))(fitted)


def test_a_finger_is_refused_over_a_neighbour_within_the_margin_below_its_tip():
    """The physics hand stops on any contact below it: a surface a millimetre above or below the
    fingertips is in the way (heights grow by the margin, as footprints do)."""
    adapter = (0.28, 0.0, 0.036, rect(0.022, 0.031))
    fitted = replace(record("adapter", 0.28, 0.0, 0.036, closing_yaw=0.0, area=2000), width_m=0.044)
    for top, refused in ((0.022, True), (0.019, True), (0.016, False)):  # the fingertips at 21 mm, the margin 3 mm
        beside = (0.28 + 0.065, 0.0, top, rect(0.02, 0.05))  # under the right finger's pad
        reason = hand_clearance(depth_of([adapter, beside]), INTR, CAL)(fitted)
        assert (reason is not None and "finger" in reason) == refused, top
        if top == 0.019:  # under the fingertips, within the margin
            assert "within 3 mm of where it must go" in reason


def test_the_jaws_body_over_a_tall_neighbour_is_refused_where_its_fingers_pass():
    adapter = (0.28, 0.0, 0.036, rect(0.022, 0.031))
    fitted = replace(record("adapter", 0.28, 0.0, 0.036, closing_yaw=0.0, area=2000), width_m=0.044)
    # beside the part along the closing fingers' pads, under the 80 x 60 mm body whose underside is 35 mm up
    tall = (0.28, 0.040, 0.075, rect(0.01, 0.015))
    reason = hand_clearance(depth_of([adapter, tall]), INTR, CAL)(fitted)
    assert reason is not None and "body" in reason
    lower = (0.28, 0.040, 0.060, rect(0.01, 0.015))  # below the body: it passes over it
    assert hand_clearance(depth_of([adapter, lower]), INTR, CAL)(fitted) is None
    assert hand_clearance(depth_of([adapter, tall]), INTR, CAL, HandShape(body_above_m=0.05))(fitted) is None


def test_a_finger_over_a_taller_neighbour_is_refused_then_the_jaw_turned_to_the_parts_ends():
    adapter = (0.28, 0.0, 0.036, rect(0.022, 0.031))  # 44 mm across x, 62 mm along y
    tall = (0.28 + 0.065, 0.0, 0.09, rect(0.02, 0.05))  # a box beside it, where a finger of the open jaw goes
    depth = depth_of([adapter, tall])
    clear = hand_clearance(depth, INTR, CAL)
    across_x = record("adapter", 0.28, 0.0, 0.036, closing_yaw=0.0, area=2000)
    along_y = record("adapter", 0.28, 0.0, 0.036, closing_yaw=math.pi / 2, area=2000)
    assert "finger" in clear(across_x)
    assert clear(along_y) is None  # closing the other way the fingers miss the box
    chosen, plan, note = choose_target([across_x], Envelope(), PickConfig(), clear=clear)
    assert chosen == along_its_length(across_x) and note == "ok"
    assert yaw_difference_deg(closing_yaw_deg(chosen.chosen_pose()), 90.0) < 1e-6  # a quarter turn, at the same point
    assert chosen.pose_robot[:3] == across_x.pose_robot[:3]
    assert [s.width_m for s in plan if s.command == "open"] == [HandShape().jaw_opening_m]  # all the way: its length


def test_a_part_crowded_on_its_sides_and_its_ends_is_refused_and_another_object_chosen():
    adapter = (0.28, 0.0, 0.036, rect(0.022, 0.031))
    beside = (0.28 + 0.065, 0.0, 0.09, rect(0.02, 0.05))
    beyond = (0.28, 0.075, 0.09, rect(0.05, 0.02))  # and one past its end, where the turned jaw's finger goes
    clear = hand_clearance(depth_of([adapter, beside, beyond]), INTR, CAL)
    across_x = record("adapter", 0.28, 0.0, 0.036, closing_yaw=0.0, area=2000)
    assert clear(along_its_length(across_x)) is not None
    other = record("box", 0.345, 0.0, 0.09, closing_yaw=0.0, area=1500)
    chosen, _, note = choose_target([across_x, other], Envelope(), PickConfig(), clear=clear)
    assert chosen is other, note
    chosen, _, note = choose_target([across_x], Envelope(), PickConfig(), clear=clear)
    assert chosen is None and "adapter: a finger would land" in note


def test_a_box_longer_than_the_stroke_is_not_turned():
    box = (0.28, 0.0, 0.08, rect(0.045, 0.08))  # 90 mm across x, 160 mm along y
    beside = (0.28 + 0.085, 0.0, 0.12, rect(0.02, 0.05))  # a taller one where the jaw's finger goes
    clear = hand_clearance(depth_of([box, beside]), INTR, CAL)
    across_x = replace(record("box", 0.28, 0.0, 0.08, closing_yaw=0.0), width_m=0.09)
    assert "finger" in clear(across_x) and "finger" in clear(along_its_length(across_x))  # its own top, the 2nd time
    assert choose_target([across_x], Envelope(), PickConfig(), clear=clear)[0] is None


def test_pick_config_carries_the_hand_and_reads_it_back_from_a_recording():
    from dataclasses import asdict

    cfg = PickConfig(hand=HandShape(jaw_opening_m=0.16))
    assert PickConfig(**{**asdict(cfg)}).hand == cfg.hand  # asdict makes it a dict, as metadata holds it
    assert PickConfig(hand=None).hand is None


def test_hand_shape_refuses_what_is_not_a_size():
    with pytest.raises(ParameterError, match="jaw_opening_m"):
        HandShape(jaw_opening_m=-0.1)


def test_pick_with_an_rg2_checks_the_jaw_as_far_as_the_rg2_opens():
    from edgepick.cli.cell import check_gripper, with_gripper

    assert with_gripper(PickConfig(), check_gripper("rg2:host", None)).hand.jaw_opening_m == 0.10
    assert with_gripper(PickConfig(), check_gripper("digital:0", None)).hand == HandShape()
