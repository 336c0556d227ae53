"""The marker's camera point: ArUco detection on rendered frames of the synthetic cell, against the
known truth; refusals when it is not seen, has no depth, or has the wrong size."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edgepick.errors import ConfigError
from edgepick.runtime.marker import MarkerSpec, detect_marker
from edgepick.sim.camera import SynthCamera, ToolMarker

SPEC = MarkerSpec.parse("aruco:4X4_50:7:40")


def _cell(pose: list[float], spec: MarkerSpec = SPEC, bias: float = 0.0, offset=(0.0, 0.0, 0.0)):
    cam = SynthCamera(640, 480, seed=5, mount_height_m=0.7)
    cam.show_tool_marker(ToolMarker(spec, lambda: pose, offset, depth_bias=bias))
    return cam


def test_marker_point_within_3_mm_at_half_a_metre():
    """Positions over the cell 0.45-0.6 m from the camera, some turned about the vertical: the
    detected centre's 3D point against the rendered truth (sensor noise 0.8 mm per pixel)."""
    errors = []
    for x, y, z, yaw in [(0.28, 0.0, 0.2, 0.0), (0.2, -0.12, 0.15, 0.6), (0.36, 0.1, 0.25, -1.2),
                         (0.24, 0.14, 0.1, 2.5), (0.33, -0.05, 0.2, 1.0)]:
        pose = [x, y, z, *_down(yaw)]
        cam = _cell(pose)
        sighting, why = detect_marker(cam.read(), SPEC)
        assert sighting is not None, why
        cal = cam.calibration()
        truth = (np.array([x, y, z]) - cal.t) @ cal.R
        assert 0.44 < truth[2] < 0.61
        errors.append(float(np.linalg.norm(sighting.point_camera_m - truth)))
    assert max(errors) <= 0.003, errors


def _down(yaw: float) -> list[float]:
    """Rotation vector of a tool pointing down, turned by YAW about the vertical."""
    import cv2

    rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
    return cv2.Rodrigues(rz @ np.diag([1.0, -1.0, -1.0]))[0].ravel().tolist()


def test_not_seen_no_depth_and_wrong_size_are_refused():
    pose = [0.28, 0.0, 0.2, math.pi, 0.0, 0.0]
    assert detect_marker(_cell(pose, offset=(0.0, 0.5, 0.0)).read(), SPEC)[1] == "marker not seen"
    assert detect_marker(_cell(pose).read(), MarkerSpec.parse("aruco:4X4_50:8"))[1] == "marker not seen"
    frame = _cell(pose).read()
    frame.depth[:] = 0
    assert "have depth" in detect_marker(frame, SPEC)[1]
    sighting, why = detect_marker(_cell(pose).read(), MarkerSpec.parse("aruco:4X4_50:7:80"))
    assert sighting is None and "printed 80 mm" in why


@pytest.mark.parametrize("spec, needle", [("apriltag:4X4_50:7", "aruco:DICT:ID"), ("aruco:9X9_50:7", "unknown ArUco"),
                                          ("aruco:4X4_50:70", "ids 0 to 49"), ("aruco:4X4_50:x", "numbers"),
                                          ("aruco:4X4_50:7:2000", "5 to 500")])
def test_bad_marker_specs(spec, needle):
    with pytest.raises(ConfigError, match=needle):
        MarkerSpec.parse(spec)
