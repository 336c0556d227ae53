"""A pick's plan: the way from the object to the place pose goes round the base when the straight
line would cut through the keep-out, and the whole plan then passes the envelope."""

from __future__ import annotations

import math

import pytest

from edgepick.robot.envelope import Envelope
from edgepick.robot.pick import PickConfig, plan_pick, plan_reason


@pytest.mark.parametrize("x, y, vias", [(0.28, 0.0, 0), (0.10, 0.25, 3), (0.2, 0.3, 3), (0.3, 0.15, 3)])
def test_place_transit_goes_round_the_base_when_needed(x, y, vias):
    """Via points, at most 60 degrees apart on the transit circle, when the line passes it."""
    record = {"pose_robot": [x, y, 0.05, math.pi, 0.0, 0.0]}
    cfg = PickConfig()
    plan = plan_pick(record, cfg)
    around = [s for s in plan if s.note == "around the base"]
    assert len(around) == vias and len(plan) == 10 + vias
    assert all(math.hypot(*s.target[:2]) == pytest.approx(cfg.transit_radius_m) for s in around)
    assert plan_reason(plan, Envelope(), cfg, start=list(cfg.home_pose)) is None
    straight = [s for s in plan if s.note != "around the base"]
    if y >= 0.25:  # without the via points these plans are refused: the line cuts the base keep-out
        assert "keep-out" in plan_reason(straight, Envelope(), cfg, start=list(cfg.home_pose))
