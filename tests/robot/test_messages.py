"""Poses and rotations as a recording's messages carry them: robot pose <-> foxglove Pose, exactly."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

pytest.importorskip("foxglove_schemas_protobuf")

from edgepick.robot.messages import quaternion, robot_pose, rotation, schemas, set_pose  # noqa: E402

angles = st.floats(-math.pi, math.pi, allow_nan=False)


@given(st.tuples(angles, angles, angles), st.floats(0, math.pi))
def test_quaternion_is_the_rotation(axis_angles, turn):
    axis = np.array([math.cos(axis_angles[0]) * math.cos(axis_angles[1]),
                     math.sin(axis_angles[0]) * math.cos(axis_angles[1]), math.sin(axis_angles[1])])
    R = cv2.Rodrigues(axis * turn)[0]
    q = quaternion(R)
    assert abs(np.linalg.norm(q) - 1) < 1e-12
    assert np.allclose(rotation(q), R, atol=1e-12)


@pytest.mark.parametrize("rvec", [[math.pi, 0, 0], [0, math.pi, 0], [0, 0, math.pi], [2.78, -1.46, 0.0], [0, 0, 0]])
def test_robot_pose_survives_the_message(rvec):
    """Half turns (every top-down grasp is one) take the trace < 0 branch."""
    pose = [0.2, -0.1, 0.05, *rvec]
    message = schemas().PoseInFrame()
    set_pose(message.pose, pose)
    back = robot_pose(message.pose)
    assert np.allclose(back[:3], pose[:3])
    assert np.allclose(cv2.Rodrigues(np.array(back[3:]))[0], cv2.Rodrigues(np.array(pose[3:], float))[0], atol=1e-12)


def test_edgepick_messages_round_trip():
    m = schemas()
    cycle = m.PickCycle(cycle=3, outcome="done", pixel=[1.5, 2.5], inference_ms=12.5)
    cycle.frame_time.FromNanoseconds(1_700_000_000_123_456_789)
    back = m.PickCycle.FromString(cycle.SerializeToString())
    assert back.cycle == 3 and list(back.pixel) == [1.5, 2.5] and back.frame_time.ToNanoseconds() == 1_700_000_000_123_456_789
    assert schemas() is m  # built once per process
