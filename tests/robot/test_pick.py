"""A pick's plan: the way from the object to the place pose goes round the base when the straight
line would cut through the keep-out, and the whole plan then passes the envelope. Which object is
chosen: free ones first, buried ones never."""

from __future__ import annotations

import math

import pytest

from edgepick.errors import ParameterError
from edgepick.robot.envelope import Envelope
from edgepick.robot.pick import BURIED, OCCLUDED, PickConfig, choose_target, plan_pick, plan_reason
from tests.conftest import make_grasp


@pytest.mark.parametrize("x, y, vias", [(0.28, 0.0, 0), (0.10, 0.25, 3), (0.2, 0.3, 3), (0.3, 0.15, 3)])
def test_place_transit_goes_round_the_base_when_needed(x, y, vias):
    """Via points, at most 60 degrees apart on the transit circle, when the line passes it."""
    record = make_grasp("box", [x, y, 0.05, math.pi, 0.0, 0.0])
    cfg = PickConfig()
    plan = plan_pick(record, cfg)
    around = [s for s in plan if s.note == "around the base"]
    assert len(around) == vias and len(plan) == 10 + vias
    assert all(math.hypot(*s.target[:2]) == pytest.approx(cfg.transit_radius_m) for s in around)
    assert plan_reason(plan, Envelope(), cfg, start=list(cfg.home_pose)) is None
    straight = [s for s in plan if s.note != "around the base"]
    if y >= 0.25:  # without the via points these plans are refused: the line cuts the base keep-out
        assert "keep-out" in plan_reason(straight, Envelope(), cfg, start=list(cfg.home_pose))


def test_a_buried_object_is_never_chosen_and_a_partly_covered_one_last():
    """An object with a fifth or more of its rim under others is refused (lifting it would drag what
    lies on it; its visible centroid is not its own); one less covered is chosen after free ones."""
    def rec(cls, area, occluded):
        return make_grasp(cls, [0.28, 0.0, 0.05, math.pi, 0.0, 0.0], area_px=area, occluded=occluded, depth_m=0.6)

    covered, buried, free = rec("disk", 9000, (OCCLUDED + BURIED) / 2), rec("box", 8000, BURIED), rec("bearing", 500, 0.0)
    assert choose_target([covered, buried, free], Envelope(), PickConfig())[0] is free
    assert choose_target([covered, buried], Envelope(), PickConfig())[0] is covered
    chosen, plan, note = choose_target([buried], Envelope(), PickConfig())
    assert chosen is None and plan == [] and "box: under other objects (20% of its rim)" in note


def test_of_the_partly_covered_objects_the_least_covered_comes_first():
    """In a pile every part's rim meets another: the part on top, whose rim meets the others only
    where it leans on them, comes before the larger one it lies on (a bearing on a brake disk's
    ring, its top below the disk's hub), which would carry it off the table."""
    def rec(cls, area, z, occluded):
        return make_grasp(cls, [0.28, 0.0, z, math.pi, 0.0, 0.0], area_px=area, occluded=occluded, depth_m=0.7 - z)

    under, on_top = rec("disk", 40000, 0.058, 5 * OCCLUDED), rec("bearing", 4000, 0.055, 2 * OCCLUDED)
    assert choose_target([under, on_top], Envelope(), PickConfig())[0] is on_top
    free = make_grasp("box", [0.28, 0.1, 0.03, math.pi, 0.0, 0.0], area_px=3000, depth_m=0.67)
    assert choose_target([under, on_top, free], Envelope(), PickConfig())[0] is free


def test_a_part_still_where_an_earlier_pick_went_comes_after_the_others():
    """On one table picked from in turn, a part seen within retry_elsewhere_m of a point an earlier pick
    went to is still there: that pick failed, and it is tried again only once the others are refused;
    retry_elsewhere_m 0 forgets."""
    big = make_grasp("disk", [0.28, 0.0, 0.05, math.pi, 0.0, 0.0], area_px=9000)
    small = make_grasp("bearing", [0.22, 0.10, 0.05, math.pi, 0.0, 0.0], area_px=500)
    went = [(0.29, 0.01, 0.05)]  # 14 mm from the disk's grasp point
    assert choose_target([big, small], Envelope(), PickConfig())[0] is big
    assert choose_target([big, small], Envelope(), PickConfig(), tried=went)[0] is small
    assert choose_target([big], Envelope(), PickConfig(), tried=went)[0] is big  # the only one: tried again
    assert choose_target([big, small], Envelope(), PickConfig(retry_elsewhere_m=0.01), tried=went)[0] is big
    assert choose_target([big, small], Envelope(), PickConfig(retry_elsewhere_m=0), tried=went)[0] is big
    with pytest.raises(ParameterError, match="retry_elsewhere_m"):
        PickConfig(retry_elsewhere_m=-0.01)


def test_the_lift_clears_the_tallest_part_in_view_and_the_carry_path_follows_the_plan():
    """A part rises with the hand from where it stood, so lifting it as high as the tallest top in
    view stands above the table (plus the clearance) carries its underside over everything; never
    less than lift_m. carry_path: the plan's moves while it holds the part."""
    from edgepick.robot.pick import carry_path, lift_height_m

    cfg = PickConfig()
    assert lift_height_m(cfg) == cfg.lift_m
    assert lift_height_m(cfg, tallest_z_m=0.05) == cfg.lift_m
    assert lift_height_m(cfg, tallest_z_m=0.25, table_z_m=0.05) == pytest.approx(0.20 + cfg.transit_clearance_m)
    record = make_grasp("bearing", [0.30, 0.10, 0.035, math.pi, 0.0, 0.0])
    plan = plan_pick(record, cfg, tallest_z_m=0.20)
    path = carry_path(plan)
    assert path[0] == pytest.approx([0.30, 0.10, 0.035 + 0.22])
    assert path[-1] == pytest.approx([*cfg.place_pose[:2], cfg.place_pose[2] + cfg.approach_m])
    held = plan[[s.command for s in plan].index("grip") + 1:[s.clears_view for s in plan].index(True) + 1]
    assert [list(s.target[:3]) for s in held] == path
    with pytest.raises(ParameterError, match="transit_clearance_m"):
        PickConfig(transit_clearance_m=-0.01)
