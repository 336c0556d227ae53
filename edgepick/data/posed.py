"""An object posed far off upright, drawn by marching each ray through it.

The renderer draws an object as its footprint at a few levels along its own axis (data/render.py):
exact for an object standing on the table, and good for one leaning a little. A part that settled
tipped far over (a bearing rolled onto its side, one upside down: sim/clutter.py) shows the camera
its side walls, which planes along its axis meet at a grazing angle or not at all. Here each ray
of the object's box is walked in depth steps until it first lies inside a part (its footprint and
its height range), and the hit refined by bisection; the surface there is the top, the bottom or
the side wall, whichever the point lies nearest.
"""

from __future__ import annotations

import numpy as np

from edgepick.data.shapes import Part, Placed

STEP_M = 0.0015  # the march's step in depth: thinner than any part
REFINE = 5  # bisections of the step a ray first enters a part in (0.05 mm)


def march(rays: np.ndarray, part: Part, base: np.ndarray, a1: np.ndarray, a2: np.ndarray, up: np.ndarray,
          reach: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Where the RAYS (camera frame, unit depth) first meet PART of an object whose base centre is
    BASE, its local axes A1, A2 and UP (camera frame), every point of which lies within REACH of its
    axis: (hit mask, depth, local x, local y, unit surface normal per hit in the camera frame)."""
    ends = np.array([base + up * part.z0, base + up * part.z1])
    near, far = max(0.05, float(ends[:, 2].min()) - reach), float(ends[:, 2].max()) + reach
    h, w = rays.shape[:2]
    hit = np.zeros((h, w), bool)
    depth = np.full((h, w), np.nan, np.float32)

    def inside(points: np.ndarray) -> np.ndarray:
        rel = points - base
        lz = rel @ up
        return (part.sdf(rel @ a1, rel @ a2) < 0) & (lz >= part.z0) & (lz <= part.z1)

    for z in np.arange(near, far + STEP_M, STEP_M, dtype=np.float64):
        first = inside(rays * z) & ~hit
        depth[first] = z
        hit |= first
    if not hit.any():
        return hit, depth, depth, depth, np.zeros((0, 3))
    ray = rays[hit].astype(np.float64)
    lo, hi = depth[hit].astype(np.float64) - STEP_M, depth[hit].astype(np.float64)
    for _ in range(REFINE):  # the entry lies between the last step outside and the first inside
        mid = (lo + hi) / 2
        entered = inside(ray * mid[:, None])
        hi, lo = np.where(entered, mid, hi), np.where(entered, lo, mid)
    depth[hit] = hi
    rel = ray * hi[:, None] - base
    lx, ly, lz = rel @ a1, rel @ a2, rel @ up
    eps = 5e-4
    gx = part.sdf(lx + eps, ly) - part.sdf(lx - eps, ly)
    gy = part.sdf(lx, ly + eps) - part.sdf(lx, ly - eps)
    wall = gx[:, None] * a1 + gy[:, None] * a2
    gaps = np.stack([part.z1 - lz, lz - part.z0, -part.sdf(lx, ly)], 1)  # to the top, the bottom, the wall
    nearest = gaps.argmin(1)[:, None]
    normal = np.where(nearest == 0, up, np.where(nearest == 1, -up, wall))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-9
    local_x, local_y = np.full((h, w), np.nan, np.float32), np.full((h, w), np.nan, np.float32)
    local_x[hit], local_y[hit] = lx, ly
    return hit, depth, local_x, local_y, normal


def draw_marched(rays: np.ndarray, p: Placed, label: int, k: int, box: tuple[int, int, int, int], buf: dict) -> tuple:
    """The renderer's rasterizing (data/render.py) of a posed object tipped far over, instance K of class
    LABEL: each part marched ray by ray (RAYS: those of BOX) into the per-pixel buffers BUF; returns
    BOX and the object's footprint in it."""
    x0, y0, x1, y1 = box
    assert p.down is not None, "only an object posed off upright is marched"
    full = np.zeros((y1 - y0, x1 - x0), bool)
    for part in p.model.parts:
        hit, z, lx, ly, nn = march(rays, part, p.ground, p.a1, p.a2, -p.down, p.model.radius)
        sub_z = buf["zbuf"][y0:y1, x0:x1]
        full |= hit
        win = hit & (z < sub_z)
        sub_z[win] = z[win]
        col = part.albedo(lx[win], ly[win])
        side = (nn[win[hit]] @ p.down) ** 2 < 0.5  # wall pixels darker, as the levels draw them
        col[side] *= 0.85
        paint(buf, box, win, col, nn[win[hit]], part, label, k)
    return box, full


def paint(buf: dict, box: tuple[int, int, int, int], win: np.ndarray, col: np.ndarray, nn: np.ndarray, part: Part,
          label: int, k: int) -> None:
    """A part's material, normal, class id LABEL and instance K into the renderer's per-pixel buffers BUF,
    where WIN (in BOX) holds."""
    x0, y0, x1, y1 = box
    buf["albedo"][y0:y1, x0:x1][win] = col
    buf["normal"][y0:y1, x0:x1][win] = nn
    buf["ks"][y0:y1, x0:x1][win] = part.ks
    buf["shin"][y0:y1, x0:x1][win] = part.shininess
    buf["metal"][y0:y1, x0:x1][win] = part.metal
    buf["label"][y0:y1, x0:x1][win] = label
    buf["inst"][y0:y1, x0:x1][win] = k
