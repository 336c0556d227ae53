"""Touching objects of one class split into one record each (edgepick/runtime/regions.py), seen
through grasp_records: holes, faces at different heights, notches at a seam, cores."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edgepick.runtime.grasp import grasp_records
from edgepick.runtime.regions import near_level, row_ends
from tests.runtime.test_grasp import BEARING, BOX, INTR, flat_depth, rect


@pytest.mark.parametrize("shape", ["discs", "rings", "boxes offset", "boxes end to end"])
def test_touching_objects_of_one_class_are_split(shape):
    """Two objects of one class that touch form one region; each gets its own record, centred on it.
    Boxes side by side at one height are cut between the notches at their seam; flush ones leave
    none to cut at."""
    labels = np.zeros((480, 640), np.uint8)
    centres = {"boxes offset": [(230.0, 240.0), (369.0, 270.0)],
               "boxes end to end": [(230.0, 240.0), (369.0, 240.0)]}.get(shape, [(250.0, 240.0), (331.0, 240.0)])
    for c in centres:
        if shape.startswith("boxes"):
            rect(labels, BOX, c, (140, 60), 0.0 if shape == "boxes end to end" else 8.0)
        else:
            cv2.circle(labels, (int(c[0]), int(c[1])), 40, BEARING, -1)
            if shape == "rings":
                cv2.circle(labels, (int(c[0]), int(c[1])), 18, 0, -1)
    records = grasp_records(labels, flat_depth(), INTR)
    if shape == "boxes end to end":  # one straight-sided region: no notch, one core, one height
        assert len(records) == 1
        return
    assert sorted(r.pixel[0] for r in records) == pytest.approx([c[0] for c in centres], abs=2.0)
    assert sorted(r.pixel[1] for r in records) == pytest.approx(sorted(c[1] for c in centres), abs=1.5)


def test_a_box_lying_on_a_larger_one_is_split_at_its_height():
    """One box on another near its edge, both boxes: one region, but two top faces 8 cm apart in
    depth. The upper one gets its own record, centred on its top; the disk's hub inside its ring
    (two faces too, concentric) stays one object."""
    labels, depth = np.zeros((480, 640), np.uint8), flat_depth(700)
    rect(labels, BOX, (320.0, 240.0), (220, 160), 0.0)
    depth[labels == BOX] = 640
    upper = np.zeros_like(labels)
    rect(upper, 1, (400.0, 215.0), (120, 90), 20.0)
    labels[upper > 0], depth[upper > 0] = BOX, 560
    records = grasp_records(labels, depth, INTR)
    assert len(records) == 2
    top = min(records, key=lambda r: r.depth_m)
    assert top.pixel == pytest.approx([400.0, 215.0], abs=1.5) and top.depth_m == pytest.approx(0.560, abs=1e-3)
    disk = np.zeros_like(labels)
    cv2.circle(disk, (320, 240), 120, 2, -1)
    depth = flat_depth(700)
    depth[disk > 0] = 660
    cv2.circle(depth, (320, 240), 60, 630, -1)  # the hub
    assert len(grasp_records(disk, depth, INTR)) == 1


def test_a_notched_disk_is_not_cut_in_two():
    """A disk with two bites out of its rim (objects lying over it) is one object: the notches are
    there, but the sides of a cut between them would not be convex."""
    labels = np.zeros((480, 640), np.uint8)
    cv2.circle(labels, (320, 240), 100, 2, -1)
    cv2.circle(labels, (320, 145), 30, 0, -1)
    cv2.circle(labels, (320, 335), 30, 0, -1)
    (r,) = grasp_records(labels, flat_depth(), INTR)
    assert r.cls == "disk"


@pytest.mark.parametrize("in_the_notches", ["table", "objects lying over the rim"])
def test_a_seam_whose_mask_spills_into_one_notch_is_cut_when_the_table_shows_in_the_notches(in_the_notches):
    """Two boxes side by side at one height, whose mask (a model's) spills into one notch of their
    seam: the cut between the notches leaves a bump on one side, which is then not quite convex
    (solidity 0.95-0.98). With the table in both notches they are two boxes; the same outline
    whose notches hold objects lying nearer the camera is one object with bites out of its rim."""
    labels = np.zeros((480, 640), np.uint8)
    centres = [(250.0, 200.0), (400.0, 250.0)]
    rect(labels, BOX, centres[0], (200, 80), 0.0)
    rect(labels, BOX, centres[1], (150, 100), 50.0)
    cv2.circle(labels, (336, 250), 12, BOX, -1)  # the spill
    depth = np.full((480, 640), 700, np.uint16)  # the table
    depth[labels > 0] = 600
    if in_the_notches != "table":
        hull = cv2.convexHull(cv2.findNonZero(labels))
        notches = cv2.fillConvexPoly(np.zeros_like(labels), hull, 1).astype(bool) & (labels == 0)
        labels[notches], depth[notches] = BEARING, 560
    boxes = [r for r in grasp_records(labels, depth, INTR) if r.cls == "box"]
    if in_the_notches != "table":
        assert len(boxes) == 1
        return
    assert sorted(r.pixel[0] for r in boxes) == pytest.approx([c[0] for c in centres], abs=4.0)
    assert sorted(r.pixel[1] for r in boxes) == pytest.approx([c[1] for c in centres], abs=4.0)


def test_a_box_is_not_split_at_pockets_of_table_or_at_its_side_wall():
    """Table pockets closed off by a box and the bearings around it are not a ring's bores, and a
    tall box's side wall (a long band at a lower depth) is not a second box."""
    labels, depth = np.zeros((480, 640), np.uint8), flat_depth(700)
    rect(labels, BOX, (320.0, 240.0), (200, 120), 0.0)
    depth[labels == BOX] = 600
    for x in (250, 390):  # two pockets: a notch in the box's lower edge, closed by a bearing below
        cv2.rectangle(labels, (x - 12, 285), (x + 12, 300), 0, -1)
        cv2.circle(labels, (x, 318), 22, BEARING, -1)
        depth[labels == BEARING] = 670
    wall = np.zeros_like(labels)
    cv2.rectangle(wall, (220, 180), (420, 199), 1, -1)  # a 20 px band along the top edge, 5 cm lower
    depth[(wall > 0) & (labels == BOX)] = 650
    records = [r for r in grasp_records(labels, depth, INTR) if r.cls == "box"]
    assert len(records) == 1 and records[0].depth_m == pytest.approx(0.600, abs=1e-3)


def test_a_ring_with_objects_over_its_rim_stays_one_object():
    """A disk with its bore and two bearings lying over its rim, left and right: the band between
    bore and rim breaks in two, but a region ringed around one bore is one object, not two cores."""
    labels = np.zeros((480, 640), np.uint8)
    cv2.circle(labels, (320, 240), 110, 2, -1)
    cv2.circle(labels, (320, 240), 35, 0, -1)
    for x in (215, 425):
        cv2.circle(labels, (x, 240), 45, BEARING, -1)
    disks = [r for r in grasp_records(labels, flat_depth(), INTR) if r.cls == "disk"]
    assert len(disks) == 1 and disks[0].pixel == pytest.approx([320.0, 240.0], abs=1.5)


def test_a_top_broken_by_depth_holes_is_one_face():
    """A shiny box whose top returns no depth along a band across it is one object (its two halves
    lie at one height, joined by the band); two boxes at one height whose mask bridges the table
    between them are two."""
    labels, depth = np.zeros((480, 640), np.uint8), flat_depth(700)
    rect(labels, BOX, (320.0, 240.0), (160, 100), 20.0)
    depth[labels == BOX] = 600
    band = np.zeros_like(labels)
    rect(band, 1, (320.0, 240.0), (16, 200), 20.0)
    depth[(band > 0) & (labels == BOX)] = 0
    (r,) = grasp_records(labels, depth, INTR)
    assert r.pixel == pytest.approx([320.0, 240.0], abs=1.5)
    labels, depth = np.zeros((480, 640), np.uint8), flat_depth(700)
    for x in (250.0, 390.0):
        rect(labels, BOX, (x, 240.0), (110, 100), 0.0)
    depth[labels == BOX] = 600
    labels[200:280, 300:341] = BOX  # the mask spills over the table between them, which keeps its depth
    assert sorted(r.pixel[0] for r in grasp_records(labels, depth, INTR)) == pytest.approx([250.0, 390.0], abs=3.0)


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), size=st.integers(3, 120), blobs=st.integers(1, 3))
def test_row_ends_make_the_hull_and_rectangle_all_pixels_make(seed, size, blobs):
    rng = np.random.default_rng(seed)
    mask = np.zeros((size + 8, size + 8), np.uint8)
    for _ in range(blobs):  # filled convex polygons, as hull_mask makes them, and ragged blobs
        points = rng.integers(2, size + 6, (int(rng.integers(3, 9)), 2)).astype(np.int32)
        if rng.random() < 0.5:
            cv2.fillConvexPoly(mask, cv2.convexHull(points), 1)
        else:
            cv2.fillPoly(mask, [points], 1)
    if not mask.any():
        return
    every = cv2.findNonZero(mask)
    assert np.array_equal(cv2.convexHull(row_ends(mask)), cv2.convexHull(every))
    assert cv2.minAreaRect(row_ends(mask)) == cv2.minAreaRect(every)


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), scale=st.sampled_from([0.001, 0.0001, 0.000125, 0.00025]),
       tolerance=st.sampled_from([0.004, 0.008, 0.0005]))
def test_near_level_is_the_float32_test_on_every_pixel(seed, scale, tolerance):
    """The per-reading lookup says what the pixel-wise float32 arithmetic says, also at the edges
    of the tolerance band, for images and 1-D readings alike."""
    rng = np.random.default_rng(seed)
    depth = rng.integers(0, int(1.2 / scale), (24, 32)).astype(np.uint16)
    seen = np.float32(depth[rng.integers(0, 24), rng.integers(0, 32)] * np.float32(scale))
    for level in (seen, float(seen) + tolerance, np.float32(seen - np.float32(tolerance))):
        expected = np.abs(depth.astype(np.float32) * scale - level) <= tolerance
        assert np.array_equal(near_level(depth, scale, level, tolerance), expected)
        assert np.array_equal(near_level(depth.ravel(), scale, level, tolerance), expected.ravel())
