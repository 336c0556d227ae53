"""edgepick/data/stacking.py: an object rests on the highest surface under it and is kept only where
it would stay; the renderer's scenes hold no part inside another."""

from __future__ import annotations

import numpy as np
import pytest

from edgepick.data.render import SceneRenderer
from edgepick.data.shapes import MAKERS, Placed
from edgepick.data.stacking import rest_height
from edgepick.geometry import Intrinsics

UP = np.array([0.0, 0.0, 1.0])  # the table plane's normal (camera looking straight down)
X, Y = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])


def _make(cls: str, seed: int = 0):
    return MAKERS[cls](np.random.default_rng(seed))


def _at(model, x: float = 0.0, y: float = 0.0, base: float = 0.0) -> Placed:
    return Placed(model, np.array([x, y, 0.7]), base, X, Y)


def test_an_object_alone_or_beside_others_rests_on_the_table():
    box = _make("box")
    assert rest_height([], _make("adapter"), np.array([0.0, 0.0, 0.7]), X, Y) == 0.0
    beside = box.length / 2 + 0.05  # the adapter's footprint ends short of the box
    assert rest_height([_at(box)], _make("adapter"), np.array([beside, 0.0, 0.7]), X, Y) == 0.0


def test_an_object_centred_on_a_box_rests_on_its_top():
    box, adapter = _make("box"), _make("adapter")
    assert rest_height([_at(box)], adapter, np.array([0.0, 0.0, 0.7]), X, Y) == pytest.approx(box.height)



def test_a_stack_is_two_high_at_most():
    """A third object's weight could tip the second over the edge of the first."""
    box, adapter = _make("box"), _make("adapter")
    on_top = _at(adapter, base=box.height)
    assert rest_height([_at(box), on_top], _make("bearing"), np.array([0.0, 0.0, 0.7]), X, Y) is None
    beside = np.array([box.length / 2 - 0.02, 0.0, 0.7])  # on the box, clear of the adapter
    assert rest_height([_at(box), on_top], _make("bearing"), beside, X, Y) == pytest.approx(box.height)


def test_an_object_whose_centre_is_past_its_supports_edge_would_tip_over():
    box, adapter = _make("box"), _make("adapter")
    edge = box.length / 2
    assert rest_height([_at(box)], adapter, np.array([edge + 0.002, 0.0, 0.7]), X, Y) is None
    assert rest_height([_at(box)], adapter, np.array([edge - 0.02, 0.0, 0.7]), X, Y) == pytest.approx(box.height)


def test_a_box_over_a_disks_bore_rests_on_the_hub_around_it():
    disk, box = _make("disk"), _make("box")
    assert rest_height([_at(disk)], box, np.array([0.0, 0.0, 0.7]), X, Y) == pytest.approx(disk.extra["hat_h"])


def test_a_bearing_smaller_than_the_bore_is_not_held_by_the_hub():
    disk, bearing = _make("disk"), _make("bearing")
    bearing.parts[0].sdf = lambda x, y: np.hypot(x, y) - 0.5 * disk.extra["r_bore"]  # fits inside the bore
    bearing.radius = 0.5 * disk.extra["r_bore"]
    assert rest_height([_at(disk)], bearing, np.array([0.0, 0.0, 0.7]), X, Y) == 0.0


def _solid_cells(p: Placed, grid: np.ndarray) -> list[tuple[np.ndarray, float, float]]:
    """Each part of P as (its cells of GRID, bottom, top elevation)."""
    rel = grid - p.ground
    lx, ly = rel @ p.a1, rel @ p.a2
    return [(part.sdf(lx, ly) < 0, p.base_elev + part.z0, p.base_elev + part.z1) for part in p.model.parts]


@pytest.mark.parametrize("seed", range(40))
def test_no_rendered_object_holds_a_part_inside_another(seed):
    rng = np.random.default_rng(seed)
    renderer = SceneRenderer(Intrinsics.d415(320, 240))
    placed = renderer.sample_objects(rng, UP, 0.7)
    xs, ys = np.meshgrid(np.arange(-0.4, 0.4, 0.002), np.arange(-0.3, 0.3, 0.002))
    grid = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 0.7)], 1)
    parts = [_solid_cells(p, grid) for p in placed]
    for i in range(len(placed)):
        for j in range(i):
            for cells_i, lo_i, hi_i in parts[i]:
                for cells_j, lo_j, hi_j in parts[j]:
                    overlap_m = min(hi_i, hi_j) - max(lo_i, lo_j)
                    shared = np.count_nonzero(cells_i & cells_j)
                    assert overlap_m <= 1e-9 or shared <= 4, (seed, i, j, overlap_m, shared)  # 4 cells: rasters' edges
