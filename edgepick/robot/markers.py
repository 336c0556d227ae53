"""What a pick recording draws (docs/contracts.md#recordings): the camera's calibration, the grasp
records on the image and in the base frame, the plan, and a clutter-removal round's parts, as
Foxglove's messages built from a cycle's values (the classes of robot/messages.py's `schemas()`)."""

from __future__ import annotations

import numpy as np

from edgepick.geometry import Intrinsics
from edgepick.robot.messages import rotation, set_pose
from edgepick.robot.pick import Step
from edgepick.runtime.grasp_record import Grasp

BASE, CAMERA = "base", "camera"  # the frames (docs/contracts.md#recordings)
GREEN, GREY, BLUE = (0.1, 0.85, 0.2, 1.0), (0.7, 0.7, 0.7, 0.8), (0.2, 0.5, 1.0, 1.0)


def camera_calibration(m, intr: Intrinsics):
    """foxglove.CameraCalibration of pinhole intrinsics (no distortion: the frames are rectified)."""
    return m.CameraCalibration(frame_id=CAMERA, width=intr.width, height=intr.height, distortion_model="plumb_bob",
                               D=[0.0] * 5, K=[intr.fx, 0, intr.cx, 0, intr.fy, intr.cy, 0, 0, 1],
                               R=[1, 0, 0, 0, 1, 0, 0, 0, 1], P=[intr.fx, 0, intr.cx, 0, 0, intr.fy, intr.cy, 0, 0, 0, 1, 0])


def _colour(target, rgba) -> None:
    target.r, target.g, target.b, target.a = rgba


def image_annotations(m, records: list[Grasp], chosen: Grasp | None, time_ns: int):
    """Each record's grasp point (a circle) and finger axis (a line) on the colour image; the chosen
    one green. Each carries the frame's time: a viewer matches annotations to an image by it."""
    out = m.ImageAnnotations()
    for r in records:
        colour = GREEN if r is chosen else GREY
        cx, cy = r.pixel
        circle = out.circles.add(diameter=10, thickness=2)
        circle.position.x, circle.position.y = cx, cy
        _colour(circle.outline_color, colour)
        a = np.radians(r.angle_deg)
        dx, dy = -np.sin(a) * 30, np.cos(a) * 30  # fingers close along the minor axis
        line = out.points.add(type=3, thickness=2)  # LINE_STRIP
        for s in (-1, 1):
            p = line.points.add()
            p.x, p.y = float(cx + s * dx), float(cy + s * dy)
        _colour(line.outline_color, colour)
        text = out.texts.add(text=r.cls, font_size=12)
        text.position.x, text.position.y = cx + 8, cy - 8
        _colour(text.text_color, colour)
    for annotation in (*out.circles, *out.points, *out.texts):
        annotation.timestamp.FromNanoseconds(time_ns)
    return out


def grasp_markers(m, records: list[Grasp], chosen: Grasp | None, plan: list[Step], time_ns: int):
    """/grasp/markers: per record with a robot pose, an arrow along its finger axis (tool x) at the
    grasp point; the plan's targets as spheres joined by a line, in the base frame. Each entity
    replaces the one of the same id from the cycle before."""
    update = m.SceneUpdate()
    grasps = update.entities.add(id="grasps", frame_id=BASE)
    grasps.timestamp.FromNanoseconds(time_ns)
    for r in records:
        pose = r.pose_robot
        if pose is None:
            continue
        arrow = grasps.arrows.add(shaft_length=0.04, shaft_diameter=0.004, head_length=0.012, head_diameter=0.01)
        set_pose(arrow.pose, pose)
        _colour(arrow.color, GREEN if r is chosen else GREY)
        text = grasps.texts.add(text=r.cls, font_size=14, billboard=True, scale_invariant=True)
        set_pose(text.pose, [*pose[:2], pose[2] + 0.02, 0, 0, 0])
        _colour(text.color, GREEN if r is chosen else GREY)
    targets = [s.target for s in plan if s.target is not None]
    if targets:
        path = update.entities.add(id="plan", frame_id=BASE)
        path.timestamp.FromNanoseconds(time_ns)
        line = path.lines.add(type=0, thickness=0.003)  # LINE_STRIP
        line.pose.orientation.w = 1.0
        _colour(line.color, BLUE)
        for target in targets:
            p = line.points.add()
            p.x, p.y, p.z = (float(v) for v in target[:3])
            sphere = path.spheres.add()
            set_pose(sphere.pose, target)
            sphere.size.x = sphere.size.y = sphere.size.z = 0.012
            _colour(sphere.color, BLUE)
    return update


def scene_objects(m, objects: list[dict], time_ns: int):
    """/scene/objects: a round's parts as solids in the base frame (a box or adapter a cube, a bearing
    or disk a cylinder), at their poses; the entity replaces the one before."""
    update = m.SceneUpdate()
    entity = update.entities.add(id="parts", frame_id=BASE)
    entity.timestamp.FromNanoseconds(time_ns)
    for o in objects:
        x, y, z, qx, qy, qz, qw = o["pose"]
        h = o["size"]["height"]
        up = rotation((qx, qy, qz, qw))[:, 2] * h / 2  # the solid's centre: half its height above its base
        shape = entity.cubes.add() if "length" in o["size"] else entity.cylinders.add()
        shape.pose.position.x, shape.pose.position.y, shape.pose.position.z = x + up[0], y + up[1], z + up[2]
        shape.pose.orientation.x, shape.pose.orientation.y, shape.pose.orientation.z, shape.pose.orientation.w = qx, qy, qz, qw
        across = (o["size"]["length"], o["size"]["width"]) if "length" in o["size"] else (o["size"]["diameter"],) * 2
        shape.size.x, shape.size.y, shape.size.z = *across, h
        _colour(shape.color, GREY)
    return update


def point_cloud(m, points: list, colours: list):
    """foxglove.PointCloud in the base frame: x, y, z (float32) and red, green, blue, alpha (uint8)
    per point. The 3D views of both viewers draw it (Rerun draws no SceneUpdate)."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")]
    layout = np.dtype(fields)
    rows = np.zeros(len(points), layout)
    for i, (point, colour) in enumerate(zip(points, colours, strict=True)):
        rows[i] = (*point[:3], *(round(255 * c) for c in colour))
    cloud = m.PointCloud(frame_id=BASE, point_stride=layout.itemsize, data=rows.tobytes())
    cloud.pose.orientation.w = 1.0
    offset = 0
    for name, kind in fields:
        cloud.fields.add(name=name, offset=offset, type=7 if kind == "<f4" else 1)  # FLOAT32, UINT8
        offset += np.dtype(kind).itemsize
    return cloud
