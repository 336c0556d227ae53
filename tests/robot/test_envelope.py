"""The safety envelope: property-based (no accepted target lies outside it) and each refusal."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edgepick.robot.envelope import UR3_SHOULDER_Z_M, Envelope, SafetyError

ENV = Envelope()
DOWN = [math.pi, 0.0, 0.0]
coord = st.floats(-1.0, 1.0) | st.sampled_from([math.nan, math.inf, -math.inf])


@given(st.lists(coord, min_size=3, max_size=3), st.floats(-4, 4))
@settings(max_examples=500, deadline=None)
def test_no_accepted_pose_lies_outside_the_envelope(xyz, rz):
    pose = [*xyz, math.pi, 0.0, rz]
    if ENV.pose_reason(pose) is not None:
        return
    x, y, z = xyz
    assert all(lo <= v <= hi for v, lo, hi in zip(xyz, ENV.box_min, ENV.box_max))
    assert math.sqrt(x * x + y * y + (z - UR3_SHOULDER_Z_M) ** 2) <= ENV.reach_m - ENV.reach_margin_m
    assert math.hypot(x, y) >= ENV.base_keepout_m
    assert z >= ENV.table_z_m + ENV.clearance_m


@given(st.floats(-1, 2) | st.just(math.nan), st.floats(-1, 5) | st.just(math.inf))
@settings(max_examples=200, deadline=None)
def test_no_accepted_speed_exceeds_the_caps(speed, acc):
    if ENV.speed_reason(speed, acc) is None:
        assert 0 < speed <= ENV.max_speed and 0 < acc <= ENV.max_acc


@pytest.mark.parametrize("pose, reason", [
    ([0.3, 0.0, 0.6, *DOWN], "outside the workspace box"),
    ([0.42, 0.2, 0.05, *DOWN], "beyond the UR3 reach"),
    ([0.05, 0.05, 0.2, *DOWN], "keep-out"),
    ([0.3, 0.0, 0.002, *DOWN], "below the table plane"),
    ([0.3, 0.0, float("nan"), *DOWN], "finite"),
    ([0.3, 0.0, 0.1], "6 finite numbers"),
])
def test_each_refusal_names_its_reason(pose, reason):
    with pytest.raises(SafetyError, match=reason):
        ENV.check_move_l(pose, 0.1, 0.5)


def test_speed_and_joint_caps():
    ENV.check_move_l([0.3, 0.0, 0.1, *DOWN], 0.25, 1.2)
    with pytest.raises(SafetyError, match="speed"):
        ENV.check_move_l([0.3, 0.0, 0.1, *DOWN], 0.5, 1.0)
    with pytest.raises(SafetyError, match="acceleration"):
        ENV.check_move_l([0.3, 0.0, 0.1, *DOWN], 0.1, 3.0)
    with pytest.raises(SafetyError, match="joint 1"):
        ENV.check_move_j([0, 7.0, 0, 0, 0, 0], 0.5, 0.5)
