"""Grasp (runtime/grasp_record.py): checked on creation; its to_dict() is the grasp record of
docs/contracts.md, keys in the order `grasp` prints them, with or without a depth and a robot pose."""

from __future__ import annotations

import math

import pytest

from edgepick.errors import ParameterError
from edgepick.runtime.grasp_record import NO_DEPTH, Grasp

POSE = (0.28, 0.0, 0.05, math.pi, 0.0, 0.0)


def test_the_record_holds_what_was_measured_in_the_contracts_order():
    posed = Grasp("box", [320.5, 240.25], 30.0, True, 900, 0.62, [0.01, 0.02, 0.62], list(POSE), 0.05, False,
                  width_m=0.09)
    assert posed.pixel == (320.5, 240.25) and posed.chosen_pose() == POSE  # lists become tuples
    assert list(posed.to_dict()) == ["class", "pixel", "angle_deg", "orientation_defined", "area_px", "depth_m",
                                     "point_camera_m", "pose_robot", "width_m", "occluded", "partial"]
    assert posed.to_dict()["pose_robot"] == list(POSE) and Grasp.from_dict(posed.to_dict()) == posed
    unposed = Grasp("disk", (10.0, 20.0), 0.0, False, 500, 0.6, (0.0, 0.0, 0.6), partial=True)
    assert "pose_robot" not in unposed.to_dict() and unposed.to_dict()["partial"] is True
    blind = Grasp("bearing", (1.0, 2.0), 0.0, False, 300, reason=NO_DEPTH)
    assert list(blind.to_dict()) == ["class", "pixel", "angle_deg", "orientation_defined", "area_px", "depth_m",
                                     "point_camera_m", "reason", "partial"]
    with pytest.raises(ValueError, match="no robot pose: no valid depth"):
        blind.chosen_pose()


@pytest.mark.parametrize("fields", [
    {"pixel": (1.0,)},
    {"pixel": (1.0, math.nan)},
    {"depth_m": 0.6},  # a depth without its camera point
    {"depth_m": 0.6, "point_camera_m": (0.0, 0.0, 0.6), "reason": NO_DEPTH},
    {"reason": None},  # no depth, and no reason why
    {"reason": NO_DEPTH, "pose_robot": POSE},
    {"depth_m": 0.6, "point_camera_m": (0.0, 0.0, 0.6), "pose_robot": POSE[:3]},
    {"depth_m": 0.6, "point_camera_m": (0.0, 0.0, 0.6), "occluded": 1.5},
    {"width_m": 0.05},  # a width without a depth
    {"depth_m": 0.6, "point_camera_m": (0.0, 0.0, 0.6), "width_m": 0.05},  # ... or of an object with no axis
    {"depth_m": 0.6, "point_camera_m": (0.0, 0.0, 0.6), "width_m": -0.05, "orientation_defined": True},
])
def test_a_grasp_that_cannot_be_is_refused(fields):
    values = {"pixel": (1.0, 2.0), "reason": None if "depth_m" in fields else NO_DEPTH, **fields}
    with pytest.raises(ParameterError):
        Grasp("box", angle_deg=0.0, area_px=200, **{"orientation_defined": False, **values})
