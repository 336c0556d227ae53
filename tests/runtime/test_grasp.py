"""Moments grasps on analytic shapes with known centroid, angle and depth; bad input; random masks."""

import json
import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edgepick.errors import EdgepickError, ParameterError
from edgepick.geometry import Intrinsics, deproject
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp import grasp_records, object_depth
from tests.conftest import run_cli

INTR = Intrinsics.d415(640, 480)
BOX, BEARING, ADAPTER = 4, 1, 3


def rect(labels, cls, centre, size, angle_deg):
    pts = cv2.boxPoints((centre, size, angle_deg)).astype(np.float32)
    cv2.fillPoly(labels, [np.round(pts * 16).astype(np.int32)], cls, cv2.LINE_8, shift=4)


def flat_depth(mm=600):
    return np.full((480, 640), mm, np.uint16)


@pytest.mark.parametrize("angle", [0.0, 30.0, 60.0, 89.0, -45.0, -80.0])
def test_rotated_rectangle_centroid_and_angle(angle):
    labels = np.zeros((480, 640), np.uint8)
    rect(labels, BOX, (300.0, 250.0), (160, 70), angle)
    (r,) = grasp_records(labels, flat_depth(), INTR)
    assert r.cls == "box" and r.orientation_defined
    assert r.pixel == pytest.approx([300.0, 250.0], abs=0.6)
    diff = (r.angle_deg - angle + 90) % 180 - 90
    assert abs(diff) < 1.0 and -90 < r.angle_deg <= 90
    assert r.depth_m == pytest.approx(0.6) and r.point_camera_m[2] == pytest.approx(0.6)
    px = 0.6 / INTR.fx  # metres per pixel at 0.6 m
    assert r.width_m == pytest.approx(70 * px, abs=3 * px)  # across its major axis: where the jaw closes


def test_ellipse_angle_and_two_boxes_give_two_records():
    labels = np.zeros((480, 640), np.uint8)
    cv2.ellipse(labels, (200, 200), (80, 30), 25, 0, 360, ADAPTER, -1)
    rect(labels, BOX, (480.0, 300.0), (100, 50), -20)
    rect(labels, BOX, (480.0, 120.0), (90, 40), 70)
    records = grasp_records(labels, flat_depth(), INTR)
    assert sorted(r.cls for r in records) == ["adapter", "box", "box"]
    ell = next(r for r in records if r.cls == "adapter")
    assert ell.angle_deg == pytest.approx(25.0, abs=1.0) and ell.pixel == pytest.approx([200, 200], abs=0.6)


@pytest.mark.parametrize("mask", ["true", "covers the hole", "bleeds onto the table"])
def test_ring_depth_comes_from_the_ring_not_the_hole(mask):
    """A shiny bearing: the table shows through its hole, and its ring returns depth on few pixels.
    A model's mask may cover the hole too, or spill onto the table around the ring, so that table
    pixels outnumber the ring's; the depth is still the ring's top."""
    labels = np.zeros((480, 640), np.uint8)
    cv2.circle(labels, (320, 240), 40, BEARING, -1)
    cv2.circle(labels, (320, 240), 20, 0, -1)
    depth = flat_depth(700)  # the table, seen through the hole
    ring = labels == BEARING
    depth[ring] = 665
    shine = 0.4 if mask == "true" else 0.8
    depth[ring & (np.random.default_rng(0).random(depth.shape) < shine)] = 0  # shiny metal: holes
    if mask != "true":
        cv2.circle(labels, (320, 240), 55 if mask == "bleeds onto the table" else 40, BEARING, -1)
    (r,) = grasp_records(labels, depth, INTR)
    assert labels[240, 320] == (0 if mask == "true" else BEARING)  # the centroid lies in the hole
    assert r.pixel == pytest.approx([320, 240], abs=0.6)
    assert r.depth_m == pytest.approx(0.665)
    assert not r.orientation_defined and r.angle_deg == 0.0 and r.width_m is None  # the jaw opens all the way


def test_all_zero_depth_under_object_gives_a_reason_not_nan():
    labels = np.zeros((480, 640), np.uint8)
    rect(labels, BOX, (300.0, 250.0), (120, 60), 10)
    depth = flat_depth()
    depth[labels > 0] = 0
    (r,) = grasp_records(labels, depth, INTR, calib=Calibration(np.eye(3), np.zeros(3), 0.0, 4))
    assert r.depth_m is None and r.point_camera_m is None and "depth" in r.reason
    assert r.pose_robot is None


def test_empty_mask_and_size_mismatch():
    assert grasp_records(np.zeros((480, 640), np.uint8), flat_depth(), INTR) == []
    with pytest.raises(EdgepickError, match="intrinsics"):
        grasp_records(np.zeros((240, 320), np.uint8), np.zeros((240, 320), np.uint16), INTR)


def test_two_class_ids_of_one_name_are_refused_naming_the_parameter():
    labels = np.zeros((480, 640), np.uint8)
    rect(labels, BOX, (300.0, 250.0), (160, 70), 0.0)
    with pytest.raises(ParameterError, match=r"classes=\['background', 'box', 'disk', 'box', 'box'\]: names 'box' twice"):
        grasp_records(labels, flat_depth(), INTR, ["background", "box", "disk", "box", "box"])


@pytest.mark.parametrize("yaw_deg", [0.0, 35.0, 90.0, -120.0])
def test_robot_pose_with_camera_rotated_about_vertical(yaw_deg):
    """Camera looks straight down, rotated by yaw about the vertical: the finger direction must be
    the object's minor axis expressed in the ROBOT frame, not the image angle."""
    y = math.radians(yaw_deg)
    flip = np.diag([1.0, -1.0, -1.0])  # camera z down onto the table, camera y opposite robot y
    rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    R = rz @ flip
    cal = Calibration(R, np.array([0.3, -0.1, 0.8]), 0.0, 4)
    labels = np.zeros((480, 640), np.uint8)
    image_angle = 30.0
    rect(labels, BOX, (340.0, 220.0), (160, 60), image_angle)
    (r,) = grasp_records(labels, flat_depth(600), INTR, calib=cal)
    x, yy, z, rx, ry, rz_ = r.pose_robot
    assert np.allclose([x, yy, z], cal.apply(deproject(INTR, *r.pixel, 0.6)), atol=1e-4)
    rotvec = np.array([rx, ry, rz_])
    tool, _ = cv2.Rodrigues(rotvec)
    assert np.allclose(tool[:, 2], [0, 0, -1], atol=1e-6)  # tool z straight down
    a = math.radians(image_angle)
    minor_cam = np.array([-math.sin(a), math.cos(a), 0.0])  # minor axis direction in the camera frame
    minor_robot = R @ minor_cam
    assert abs(abs(tool[:, 0] @ minor_robot) - 1.0) < 1e-3  # fingers close across the object


@pytest.mark.slow
@given(st.integers(0, 2**31 - 1), st.floats(0.0, 1.0))
@settings(max_examples=60, deadline=None)
def test_random_masks_and_depth_never_raise_or_give_nan(seed, hole_fraction):
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 5, (12, 16)).astype(np.uint8)
    labels = cv2.resize(small, (640, 480), interpolation=cv2.INTER_NEAREST)
    labels[rng.random(labels.shape) < 0.02] = rng.integers(0, 5)
    depth = rng.integers(300, 1200, (480, 640)).astype(np.uint16)
    depth[rng.random(depth.shape) < hole_fraction] = 0
    cal = Calibration(np.eye(3), np.zeros(3), 0.0, 4)
    records = grasp_records(labels, depth, INTR, calib=cal)
    text = json.dumps([r.to_dict() for r in records])
    assert "NaN" not in text and "Infinity" not in text
    for r in records:
        assert -90 < r.angle_deg <= 90


def test_cli_mask_mode_with_calibration_and_overlay(tmp_path):
    labels = np.zeros((480, 640), np.uint8)
    rect(labels, BOX, (300.0, 250.0), (160, 70), 20)
    cv2.imwrite(str(tmp_path / "mask.png"), labels)
    cv2.imwrite(str(tmp_path / "depth.png"), flat_depth())
    (tmp_path / "intr.json").write_text(json.dumps(INTR.to_dict()))
    (tmp_path / "calib.json").write_text(json.dumps({"R": np.eye(3).tolist(), "t": [0, 0, 0], "rmse_m": 0, "n_pairs": 4}))
    proc = run_cli("grasp", "--mask", str(tmp_path / "mask.png"), "--depth", str(tmp_path / "depth.png"),
                   "--intrinsics", str(tmp_path / "intr.json"), "--calib", str(tmp_path / "calib.json"),
                   "--overlay", str(tmp_path / "o.png"), check=True)
    (r,) = json.loads(proc.stdout)
    assert r["class"] == "box" and len(r["pose_robot"]) == 6
    assert cv2.imread(str(tmp_path / "o.png")).shape == (480, 640, 3)


def _grasp_cli(tmp_path, mask, depth, *extra):
    cv2.imwrite(str(tmp_path / "mask.png"), mask)
    cv2.imwrite(str(tmp_path / "depth.png"), depth)
    (tmp_path / "intr.json").write_text(json.dumps(INTR.to_dict()))
    return run_cli("grasp", "--mask", str(tmp_path / "mask.png"), "--depth", str(tmp_path / "depth.png"),
                   "--intrinsics", str(tmp_path / "intr.json"), *extra)


def test_cli_refuses_size_mismatch_bad_rotation_and_8bit_depth(tmp_path):
    proc = _grasp_cli(tmp_path, np.zeros((240, 320), np.uint8), np.zeros((240, 320), np.uint16))
    assert proc.returncode == 2 and "differs from the intrinsics" in proc.stderr
    (tmp_path / "bad.json").write_text(json.dumps({"R": [[2, 0, 0], [0, 1, 0], [0, 0, 1]], "t": [0, 0, 0]}))
    proc = _grasp_cli(tmp_path, np.zeros((480, 640), np.uint8), np.zeros((480, 640), np.uint16),
                      "--calib", str(tmp_path / "bad.json"))
    assert proc.returncode == 2 and "rotation" in proc.stderr
    proc = _grasp_cli(tmp_path, np.zeros((480, 640), np.uint8), np.zeros((480, 640), np.uint8))
    assert proc.returncode == 2 and "uint16" in proc.stderr and "Traceback" not in proc.stderr


@given(st.integers(0, 2**31 - 1))
@settings(max_examples=40, deadline=None)
def test_class_masks_filtered_on_crops_equal_whole_frame_filtering(seed):
    from edgepick.runtime.grasp import filter_class_masks
    from edgepick.runtime.grasp_config import GraspConfig

    rng = np.random.default_rng(seed)
    labels = np.zeros((120, 160), np.uint8)
    for _ in range(int(rng.integers(1, 6))):  # blobs, some touching the frame border
        x, y = int(rng.integers(-10, 160)), int(rng.integers(-10, 120))
        labels[max(y, 0):y + int(rng.integers(2, 40)), max(x, 0):x + int(rng.integers(2, 40))] = rng.integers(1, 5)
    labels[rng.random(labels.shape) < 0.01] = 2  # speckle
    cfg = GraspConfig()
    crops = filter_class_masks(labels, 5, cfg)
    for c in range(1, 5):
        full = cv2.dilate(cv2.medianBlur((labels == c).astype(np.uint8), 3), np.ones((5, 5), np.uint8))
        got = np.zeros_like(full)
        if c in crops:
            x0, y0, m = crops[c]
            got[y0:y0 + m.shape[0], x0:x0 + m.shape[1]] = m
        assert np.array_equal(got, full), c


def test_depth_is_the_surface_under_the_centroid_when_there_is_one():
    """A brake disk with a raised hub: the tool meets the hub (closer), not the plate."""
    labels = np.zeros((480, 640), np.uint8)
    cv2.circle(labels, (320, 240), 120, 2, -1)  # disk
    depth = np.full((480, 640), 700, np.uint16)
    depth[labels == 2] = 660  # plate
    cv2.circle(depth, (320, 240), 30, 630, -1)  # hub, 3 cm higher
    (r,) = grasp_records(labels, depth, INTR)
    assert r.depth_m == pytest.approx(0.630, abs=1e-3)


def test_axis_of_a_nearly_square_box_whose_top_has_a_depth_hole_at_a_corner():
    """A shiny corner returns no depth, so the top face loses it; the face's minimum-area rectangle
    still has the box's axis, where its moments would be tens of degrees off."""
    labels, depth = np.zeros((480, 640), np.uint8), flat_depth(700)
    rect(labels, ADAPTER, (320.0, 240.0), (100, 80), 30.0)
    depth[labels == ADAPTER] = 660
    corner = cv2.boxPoints(((320.0, 240.0), (100, 80), 30.0))[0]
    cv2.circle(depth, (int(corner[0]), int(corner[1])), 35, 0, -1)
    (r,) = grasp_records(labels, depth, INTR)
    assert r.orientation_defined and abs(r.angle_deg - 30.0) < 3.0


def test_axis_of_a_black_adapter_whose_top_returns_depth_on_one_third():
    """A black adapter returns depth on a quarter of its top, a triangle between one side and the
    centre: the hull of those pixels is that triangle, whose axis is not the adapter's. Its blobs
    with no depth count as top for the axis (not for the centroid)."""
    labels, depth = np.zeros((480, 640), np.uint8), flat_depth(700)
    rect(labels, ADAPTER, (320.0, 240.0), (80, 60), -75.0)
    depth[labels == ADAPTER] = 0
    a, b, c, _ = cv2.boxPoints(((320.0, 240.0), (80, 60), -75.0))
    seen = np.zeros_like(labels)
    cv2.fillConvexPoly(seen, np.round(np.array([a, b, (a + c) / 2])).astype(np.int32), 1)
    depth[(seen > 0) & (labels == ADAPTER)] = 660
    (r,) = grasp_records(labels, depth, INTR)
    assert r.orientation_defined and abs((r.angle_deg + 75.0 + 90.0) % 180.0 - 90.0) < 3.0


def test_grasp_point_is_the_top_face_centre_not_the_silhouette_centroid():
    """A 10 cm box 150 px left of the principal point, seen from 0.7 m: its right side wall shows
    as a band beside the top face, farther away. The grasp point is the top face's centre, and so
    is the record's pixel; taken from the whole silhouette it would sit ~8 px (13 mm) off."""
    labels, depth = np.zeros((480, 640), np.uint8), flat_depth(700)
    top = (170.0, 240.0)
    rect(labels, BOX, top, (100, 60), 0.0)
    depth[labels == BOX] = 600
    wall = np.zeros_like(labels)
    rect(wall, 1, (top[0] + 58.0, top[1]), (16, 60), 0.0)  # the wall between the top and the base
    wall &= labels == 0
    labels[wall > 0], depth[wall > 0] = BOX, 650
    (r,) = grasp_records(labels, depth, INTR)
    assert r.pixel == pytest.approx(list(top), abs=1.0)
    assert r.point_camera_m == pytest.approx(list(deproject(INTR, *top, 0.6)), abs=1.5e-3)
    silhouette = cv2.moments((labels == BOX).view(np.uint8), binaryImage=True)
    assert silhouette["m10"] / silhouette["m00"] - top[0] > 6.0  # what the test guards against


def test_grasp_point_ignores_a_mask_spilling_onto_a_neighbour_at_the_same_height():
    """A model's box mask that runs along a strip of table onto a patch of a neighbouring object
    whose top lies at the box's height: the patch is at the top's depth but apart from the top
    face and small, so the face's hull does not reach out to it."""
    labels, depth = np.zeros((480, 640), np.uint8), flat_depth(700)
    rect(labels, BOX, (320.0, 240.0), (120, 80), 0.0)
    depth[labels == BOX] = 600
    labels[236:244, 380:420] = BOX  # the strip, over the table
    labels[230:250, 420:440] = BOX  # the neighbour's patch, at the box's height
    depth[230:250, 420:440] = 600
    (r,) = grasp_records(labels, depth, INTR)
    assert r.pixel == pytest.approx([320.0, 240.0], abs=1.0)


def test_hub_depth_when_few_pixels_near_the_centroid_have_depth():
    """A brake disk whose centroid falls in its hub's bore and whose shiny hub top returns depth on a
    few pixels only: the tool still meets the hub, not the friction ring 3 cm lower."""
    labels = np.zeros((480, 640), np.uint8)
    cv2.circle(labels, (320, 240), 120, 2, -1)
    depth = np.full((480, 640), 700, np.uint16)
    depth[labels == 2] = 660  # friction ring
    cv2.circle(depth, (320, 240), 60, 630, -1)  # hub, 3 cm higher
    cv2.circle(depth, (320, 240), 40, 0, -1)  # no depth on most of the shiny hub...
    cv2.circle(labels, (320, 240), 25, 0, -1)  # ... around its bore
    (r,) = grasp_records(labels, depth, INTR)
    assert r.depth_m == pytest.approx(0.630, abs=1e-3)


def test_one_object_is_not_split_and_a_cut_one_is_marked_partial():
    labels = np.zeros((480, 640), np.uint8)
    rect(labels, ADAPTER, (300.0, 200.0), (200, 50), 20.0)
    cv2.circle(labels, (620, 300), 60, BEARING, -1)  # half out of the frame
    by_class = {r.cls: r for r in grasp_records(labels, flat_depth(), INTR)}
    assert set(by_class) == {"adapter", "bearing"}
    assert by_class["adapter"].partial is False and by_class["bearing"].partial is True


@pytest.mark.parametrize("case, partial", [("a mask bleeding to the border", False),
                                           ("a disk at the border", False),
                                           ("a disk a third over the border", True)])
def test_only_an_object_cut_by_the_border_along_a_real_stretch_is_partial(case, partial):
    """A partial object is not picked (its centroid is that of the part in view). A region that
    meets the border along a few pixels is not one: a model's mask that bleeds from an object near
    the edge to it, or a disk whose mask (dilated by the filters) runs a few pixels over the edge,
    which moves its centroid by under a pixel."""
    labels = np.zeros((480, 640), np.uint8)
    if case == "a mask bleeding to the border":
        rect(labels, BOX, (560.0, 240.0), (140, 90), 0.0)  # its right side 10 px from the edge
        labels[236:240, 625:] = BOX
    else:
        x = 553 if case == "a disk at the border" else 600  # 553: its rim 1 px from the edge
        cv2.circle(labels, (x, 240), 85, 2, -1)
    (r,) = grasp_records(labels, flat_depth(), INTR)
    assert r.partial is partial


@pytest.mark.parametrize("case, hub_y, partial", [("its ring cut", 380, False), ("its hub cut", 440, True),
                                                   ("tilted, its ring cut", 380, True)])
def test_a_disk_cut_by_the_border_is_partial_unless_its_level_raised_hub_is_in_view(case, hub_y, partial):
    """A brake disk's grasp point is its hub's centre (its raised top face): with only the friction
    ring of a disk lying flat cut by the border the hub is whole and the point right, so the disk
    is pickable. With the hub cut too, or a tilted disk (its top face the hub's high side), the
    point is that of the part in view."""
    labels = np.zeros((480, 640), np.uint8)
    cv2.circle(labels, (320, hub_y), 120, 2, -1)
    depth = flat_depth(700)
    ring = np.broadcast_to(660 + (np.arange(480)[:, None] - hub_y) * (0.1 if case.startswith("tilted") else 0.0),
                           depth.shape)
    depth[labels == 2] = ring[labels == 2].astype(np.uint16)  # friction ring
    cv2.circle(depth, (320, hub_y), 45, 630, -1)  # hub, 3 cm higher
    (r,) = grasp_records(labels, depth, INTR)
    assert r.partial is partial, case
    if not partial:
        assert r.pixel == pytest.approx((320, hub_y), abs=1.0)


def test_an_object_partly_under_another_is_marked_occluded():
    """A box lying across a larger disk, 30 mm nearer the camera: the disk's rim meets the box where
    the box is nearer; the box is not occluded, and the pick loop prefers it (robot/pick.py)."""
    from edgepick.robot.envelope import Envelope
    from edgepick.robot.pick import PickConfig, choose_target

    labels, depth = np.zeros((480, 640), np.uint8), flat_depth(650)
    cv2.circle(labels, (300, 240), 90, 2, -1)  # disk
    depth[labels == 2] = 620
    rect(labels, BOX, (390.0, 240.0), (120, 50), 0.0)  # over the disk's right edge
    depth[labels == BOX] = 590
    cal = Calibration(np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), np.array([0.28, 0.0, 0.7]), 0, 0)
    by_class = {r.cls: r for r in grasp_records(labels, depth, INTR, calib=cal)}
    assert by_class["disk"].occluded > 0.1 and by_class["box"].occluded == 0.0
    assert by_class["disk"].area_px > by_class["box"].area_px
    chosen, _, note = choose_target(list(by_class.values()), Envelope(), PickConfig())
    assert chosen.cls == "box", note


def test_a_part_lying_on_a_disks_low_ring_marks_the_disk_occluded():
    """A bearing on a brake disk's ring, inside its outline: its top stands no higher than the disk's hub,
    where the grasp point is, but 18 mm above the ring it lies on. The disk carries it (lifting the
    disk would drop it on the way), so the disk counts as occluded and the bearing is chosen first."""
    from edgepick.robot.envelope import Envelope
    from edgepick.robot.pick import OCCLUDED, PickConfig, choose_target

    labels, depth = np.zeros((480, 640), np.uint8), flat_depth(700)
    cv2.circle(labels, (300, 240), 120, 2, -1)  # disk: ring 20 mm above the table, hub 40 mm
    depth[labels == 2] = 680
    cv2.circle(depth, (300, 240), 40, 660, -1)
    cv2.circle(labels, (380, 240), 30, 1, -1)  # a bearing on the ring, its top level with the hub
    depth[labels == 1] = 662
    cal = Calibration(np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]), np.array([0.28, 0.0, 0.7]), 0, 0)
    by_class = {r.cls: r for r in grasp_records(labels, depth, INTR, calib=cal)}
    disk = by_class["disk"]
    assert abs(disk.depth_m - 0.660) < 0.003  # the grasp point is on the hub
    assert disk.occluded > OCCLUDED and by_class["bearing"].occluded == 0.0
    chosen, _, note = choose_target(list(by_class.values()), Envelope(), PickConfig(hand=None))
    assert chosen.cls == "bearing", note


def test_a_shiny_part_on_a_disks_ring_marks_it_occluded_and_a_mask_spilling_onto_the_table_does_not():
    """A steel bearing returns depth on few of its pixels: where its rim pixel has none, its nearest
    reading close by stands for it, so the disk it lies on still counts as carrying it. A box whose
    mask spills over the table onto a disk's low ring: the ring lies below the box's top, and the
    table and ring readings of its own mask do not make the ring stand above it."""
    from edgepick.robot.pick import OCCLUDED

    labels, depth = np.zeros((480, 640), np.uint8), flat_depth(700)
    cv2.circle(labels, (300, 240), 120, 2, -1)  # disk: ring 20 mm above the table, hub 40 mm
    depth[labels == 2] = 680
    cv2.circle(depth, (300, 240), 40, 660, -1)
    cv2.circle(labels, (380, 240), 30, 1, -1)  # a shiny bearing on the ring: depth on one pixel in 25
    depth[labels == 1] = 0
    sparse = np.zeros_like(depth, bool)
    sparse[::5, ::5] = True
    depth[(labels == 1) & sparse] = 662
    rect(labels, BOX, (468.0, 240.0), (80, 60), 0.0)  # a box 60 mm tall 8 px from the disk...
    depth[labels == BOX] = 640
    labels[210:270, 410:428] = BOX  # ... its mask spilling over the table onto the disk's ring
    by_class = {r.cls: r for r in grasp_records(labels, depth, INTR)}
    assert by_class["disk"].occluded > OCCLUDED, by_class["disk"]
    assert by_class["box"].occluded <= OCCLUDED, by_class["box"]


def numpy_object_depth(depth, region, depth_scale, min_px, share=0.08, level_m=0.004):
    """object_depth as first written, on every pixel's value with numpy's own histogram, median and
    percentile: the reference the counting version must match to the last bit."""
    vals = depth[(region > 0) & (depth > 0)].astype(np.float64) * depth_scale
    if vals.size < min_px:
        return None
    counts, edges = np.histogram(vals, bins=max(1, int(np.ptp(vals) / level_m) + 1))
    near = np.convolve(np.pad(counts, 1), np.ones(3, int), mode="valid")
    i = int(np.argmax(near >= max(min_px, share * vals.size)))
    lo, hi = edges[max(i - 1, 0)], edges[min(i + 2, counts.size)]
    level = float(np.median(vals[(vals >= lo) & (vals <= hi)]))
    return float(np.percentile(vals[np.abs(vals - level) <= 2 * level_m], 25.0))


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 3000), spread=st.sampled_from([0, 1, 3, 8, 40, 400]),
       scale=st.sampled_from([0.001, 0.0001, 0.000125, 0.00025]))
def test_object_depth_is_numpys_histogram_median_and_percentile_to_the_last_bit(seed, n, spread, scale):
    rng = np.random.default_rng(seed)
    base = int(rng.integers(200, 9000))
    depth = (base + rng.integers(0, spread + 1, n) * rng.choice([1, 1, 5], n)).astype(np.uint16)
    depth[rng.random(n) < 0.1] = 0  # no reading
    depth = depth.reshape(1, n)
    region = (rng.random((1, n)) < 0.9).astype(np.uint8)
    assert object_depth(depth, region, scale, 1) == numpy_object_depth(depth, region, scale, 1)
    assert object_depth(depth, region, scale, 10) == numpy_object_depth(depth, region, scale, 10)
