"""The renderer's layout and its frames: a layout drawn again is the same frame, and an object posed
anywhere (where it settled: sim/clutter.py) is drawn where its pose puts it."""

from __future__ import annotations

import dataclasses

import numpy as np

from edgepick.data.render import CLASSES, SceneRenderer
from edgepick.data.shapes import Placed, make_box
from edgepick.geometry import Intrinsics

INTR = Intrinsics.d415(320, 240)
UP = np.array([0.0, 0.0, 1.0])  # the table's normal (away from the camera) of a camera straight above it


def _layout(renderer: SceneRenderer, seed: int = 4):
    return renderer.lay_out(np.random.default_rng(seed), camera_height_m=0.7)


def test_render_is_a_layout_and_its_frame():
    renderer = SceneRenderer(INTR)
    whole = renderer.render(np.random.default_rng(4), camera_height_m=0.7)
    rng = np.random.default_rng(4)
    parts = renderer.draw(renderer.lay_out(rng, camera_height_m=0.7), rng)
    assert np.array_equal(whole.rgb, parts.rgb) and np.array_equal(whole.depth, parts.depth)
    assert whole.grasps == parts.grasps and whole.info == parts.info


def test_a_layout_drawn_twice_with_the_same_noise_is_the_same_frame():
    """Drawing paints the objects into a copy of the table: the layout is left as it was."""
    renderer = SceneRenderer(INTR)
    layout = _layout(renderer)
    table = layout.albedo.copy()
    first = renderer.draw(layout, np.random.default_rng(9))
    second = renderer.draw(layout, np.random.default_rng(9))
    other = renderer.draw(layout, np.random.default_rng(10))
    assert np.array_equal(layout.albedo, table)
    assert np.array_equal(first.rgb, second.rgb) and np.array_equal(first.depth, second.depth)
    assert np.array_equal(first.mask, other.mask) and not np.array_equal(first.rgb, other.rgb)  # only the noise differs


def _box_frame(renderer: SceneRenderer, placed: Placed):
    layout = dataclasses.replace(_layout(renderer), placed=[placed])
    return renderer.draw(layout, np.random.default_rng(1))


def test_an_object_posed_upright_is_drawn_as_one_standing_on_the_table():
    renderer = SceneRenderer(INTR)
    box = make_box(np.random.default_rng(3))
    ground, a1 = np.array([0.02, 0.01, 0.7]), np.array([1.0, 0.0, 0.0])
    flat = _box_frame(renderer, Placed(box, ground, 0.0, a1, np.cross(UP, a1)))
    posed = _box_frame(renderer, Placed(box, ground, 0.0, a1, np.cross(UP, a1), down=UP.copy(), key=7))
    same = (flat.mask == posed.mask).mean()
    assert same > 0.999 and (posed.mask == CLASSES.index("box")).sum() > 500
    (truth,) = posed.grasps
    assert truth["id"] == 7 and "id" not in flat.grasps[0]
    assert np.allclose(truth["point_camera_m"], flat.grasps[0]["point_camera_m"], atol=1e-5)


def test_a_box_on_its_side_shows_a_side_face():
    """A box tipped onto a long side: seen from above, its footprint is its length by its height, and
    its grasp truth (the centre of the face that was its top) lies half its width above the table."""
    renderer = SceneRenderer(INTR)
    box = make_box(np.random.default_rng(3))
    a1 = np.array([1.0, 0.0, 0.0])
    side = np.array([0.0, -1.0, 0.0])  # its top now faces -y of the camera frame
    base = np.array([0.0, 0.0, 0.7 - box.width / 2])  # the base face's centre, half its width above the table
    down = -side
    frame = _box_frame(renderer, Placed(box, base, 0.0, a1, np.cross(down, a1), down=down))
    area = (frame.mask == CLASSES.index("box")).sum()
    px = INTR.fx / 0.7  # pixels per metre on the table
    expected = box.length * box.height * px * px  # its side, seen from above (plus a sliver of its top)
    assert 0.8 * expected < area < 1.4 * expected
    (truth,) = frame.grasps
    assert abs(truth["point_camera_m"][2] - (0.7 - box.width / 2)) < 0.002
    assert np.allclose(truth["solid"]["up_camera"], side)


def test_a_bearing_upside_down_or_on_its_side_is_drawn_whole():
    """Tipped far over, a part is marched ray by ray (data/posed.py): upside down, a bearing shows its
    ring as upright; on its side, its outer diameter by its height."""
    from edgepick.data.shapes import make_bearing

    renderer = SceneRenderer(INTR)
    bearing = make_bearing(np.random.default_rng(5))
    r_out, h = bearing.extra["r_out"], bearing.height
    a1 = np.array([1.0, 0.0, 0.0])
    px = INTR.fx / 0.7
    upright = _box_frame(renderer, Placed(bearing, np.array([0.0, 0.0, 0.7]), 0.0, a1, np.cross(UP, a1)))
    flipped = _box_frame(renderer, Placed(bearing, np.array([0.0, 0.0, 0.7 - h]), 0.0, a1, np.cross(-UP, a1), down=-UP))
    label = CLASSES.index("bearing")
    assert abs(int((flipped.mask == label).sum()) - int((upright.mask == label).sum())) < 0.03 * (upright.mask == label).sum()
    down = np.array([-1.0, 0.0, 0.0])  # rolled onto its side: its top faces the camera's -x
    a1 = np.array([0.0, 0.0, 1.0])
    side = _box_frame(renderer, Placed(bearing, np.array([0.0, 0.0, 0.7 - r_out]), 0.0, a1, np.cross(down, a1), down=down))
    area = (side.mask == label).sum()
    assert 0.85 * 2 * r_out * h * px * px < area < 1.3 * 2 * r_out * h * px * px
