"""Where a new object comes to rest among those already on the table, and whether it can stay there.

A scene's objects are placed one by one. Each rests flat on the highest surface under its footprint
(the table, or the top faces of the parts of the objects below it), and is kept only if it would stay
there: its centre of mass (the footprint's centre) lies inside the polygon of the surface it touches,
with a margin, and what it touches rests on the table (a stack is two high at most). So the renderer
never draws a part intersecting another, nor one held up by nothing, and the physics check
(sim/physics.py) starts from a scene that stands.
"""

from __future__ import annotations

import cv2
import numpy as np

from edgepick.data.shapes import ObjectModel, Placed

CELL_M = 0.002  # the grid on which footprints and top faces are compared
CONTACT_M = 0.003  # a surface this close below the highest one touches the object's base too
MARGIN_M = 0.01  # the centre of mass must lie this far inside the touched surface's polygon


def rest_height(placed: list[Placed], model: ObjectModel, ground: np.ndarray, a1: np.ndarray,
                a2: np.ndarray) -> float | None:
    """The elevation at which MODEL (centre over GROUND on the table plane, local axes A1, A2) rests
    on the table or on the objects of PLACED under it; None when it would tip over."""
    near = [p for p in placed if np.linalg.norm(p.ground - ground) < p.model.radius + model.radius]
    if not near:
        return 0.0
    steps = np.arange(-model.radius, model.radius + CELL_M / 2, CELL_M)
    lx, ly = np.meshgrid(steps, steps)
    inside = np.zeros(lx.shape, bool)
    for part in model.parts:
        inside |= part.sdf(lx, ly) < 0
    lx, ly = lx[inside], ly[inside]  # the cells of the new object's footprint
    points = ground + lx[:, None] * a1 + ly[:, None] * a2
    top = np.zeros(len(lx))
    stacked = np.zeros(len(lx), bool)  # the highest surface there is an object that rests on another
    for p in near:
        rel = points - p.ground
        px, py = rel @ p.a1, rel @ p.a2
        for part in p.model.parts:
            higher = (part.sdf(px, py) < 0) & (p.base_elev + part.z1 > top)
            top[higher] = p.base_elev + part.z1
            stacked[higher] = p.base_elev > 0
    height = float(top.max()) if len(top) else 0.0
    if height <= 0.0:
        return 0.0
    touch = top >= height - CONTACT_M
    if stacked[touch].any():  # two high at most: the weight of a third could tip what holds the second
        return None
    support = np.stack([lx[touch], ly[touch]], 1).astype(np.float32)
    if len(support) < 3:
        return None
    hull = cv2.convexHull(support)
    return height if cv2.pointPolygonTest(hull, (0.0, 0.0), True) >= MARGIN_M else None
