"""Materials and light for the synthetic scenes: table surfaces (wood, laminate, mat, steel), the
thesis's lighting conditions as point lights (Table 5.3), Lambert + Blinn-Phong shading, and the
shadows objects cast on the table."""

from __future__ import annotations

import cv2
import numpy as np

from edgepick.data.shapes import Placed
from edgepick.geometry import Intrinsics


def table_albedo(rng: np.random.Generator, kind: str, h: int, w: int) -> tuple[np.ndarray, float, float]:
    """Linear-RGB albedo of the table surface, with its specular strength and shininess."""
    def noise(cells: int) -> np.ndarray:
        g = rng.standard_normal((cells, max(2, cells * w // h))).astype(np.float32)
        return cv2.resize(g, (w, h), interpolation=cv2.INTER_CUBIC)

    fine = noise(96) * 0.5 + noise(24) * 0.5
    if kind == "wood":  # planks: grain streaks along the plank, ring figure, seams, per-plank tint
        base = np.power(np.array([rng.uniform(0.55, 0.75), rng.uniform(0.38, 0.5), rng.uniform(0.22, 0.3)],
                                 np.float32), 2.2)
        along_x = rng.random() < 0.5
        L, A = (w, h) if along_x else (h, w)  # length along the grain, extent across it
        streak = cv2.resize(rng.standard_normal((A // 2, 4)).astype(np.float32), (L, A),
                            interpolation=cv2.INTER_LINEAR)
        warp = cv2.resize(rng.standard_normal((6, 5)).astype(np.float32), (L, A), interpolation=cv2.INTER_CUBIC)
        across = np.arange(A, dtype=np.float32)[:, None]
        rings = 0.5 + 0.5 * np.sin(across * rng.uniform(0.15, 0.3) + warp * 6.0)
        plank_w = int(rng.uniform(0.18, 0.35) * A) + 1
        plank = (across // plank_w).astype(int)[:, 0]
        tint = 1.0 + 0.1 * rng.standard_normal(plank.max() + 1).astype(np.float32)
        seam = (np.mod(across, plank_w) < 2).astype(np.float32)
        shade = (0.82 + 0.08 * streak + 0.12 * rings ** 4) * tint[plank][:, None] * (1 - 0.6 * seam)
        if not along_x:
            shade = shade.T
        shade = np.ascontiguousarray(shade) + 0.03 * fine
        return base * shade[..., None], 0.08, 12.0
    if kind == "laminate":
        g = rng.uniform(0.35, 0.75)
        base = np.power(np.array([g, g * rng.uniform(0.96, 1.02), g * rng.uniform(0.95, 1.05)], np.float32), 2.2)
        shade = 1.0 + 0.06 * fine + 0.05 * noise(8)
        return base * shade[..., None], 0.1, 10.0
    if kind == "mat":
        palette = [(0.12, 0.3, 0.2), (0.12, 0.18, 0.32), (0.2, 0.2, 0.22)]
        base = np.power(np.array(palette[rng.integers(len(palette))], np.float32), 2.2)
        step = rng.uniform(10, 18)
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        grid = ((np.mod(xx, step) < 0.8) | (np.mod(yy, step) < 0.8)).astype(np.float32)
        col = base * (1.0 + 0.05 * fine)[..., None]
        return col * (1 - grid[..., None] * 0.3) + grid[..., None] * 0.1, 0.03, 8.0
    # brushed steel workbench
    g = rng.uniform(0.35, 0.5)
    streaks = cv2.resize(rng.standard_normal((h, 8)).astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    if rng.random() < 0.5:
        streaks = cv2.resize(rng.standard_normal((8, w)).astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    shade = 1.0 + 0.05 * streaks + 0.04 * fine
    return np.power(np.float32(g), 2.2) * np.repeat(shade[..., None], 3, axis=2), 0.35, 18.0


def lights_for(rng: np.random.Generator, kind: str, centre: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, list[dict]]:
    """Ambient colour and point lights (position, colour, intensity, softness) for a lighting condition."""
    up = -n

    def lateral(lo: float, hi: float) -> np.ndarray:
        a = rng.uniform(0, 2 * np.pi)
        d = np.array([np.cos(a), np.sin(a), 0.0])
        d -= (d @ n) * n
        return d / np.linalg.norm(d) * rng.uniform(lo, hi)

    warm = np.array([1.0, rng.uniform(0.92, 1.0), rng.uniform(0.8, 0.95)], np.float32)
    ceiling = dict(pos=centre + up * rng.uniform(1.8, 2.6) + lateral(0.0, 0.8), colour=warm,
                   power=rng.uniform(0.75, 0.95), soft=15)
    white = dict(pos=centre + up * rng.uniform(0.25, 0.55) + lateral(0.3, 0.6),
                 colour=np.array([1.0, 1.0, 1.0], np.float32), power=rng.uniform(1.1, 1.6), soft=3)
    if kind == "ceiling":
        return warm * rng.uniform(0.3, 0.4), [ceiling]
    if kind == "ceiling+white":
        return warm * rng.uniform(0.25, 0.35), [ceiling, white]
    if kind == "single":
        white["power"] = rng.uniform(1.3, 1.9)
        return np.full(3, rng.uniform(0.02, 0.06), np.float32), [white]
    hazard = dict(pos=centre + up * rng.uniform(0.2, 0.5) + lateral(0.2, 0.5),
                  colour=np.array([1.0, rng.uniform(0.25, 0.5), rng.uniform(0.0, 0.08)], np.float32),
                  power=rng.uniform(1.4, 2.2), soft=4)
    ceiling["power"] *= rng.uniform(0.4, 0.7)
    return warm * rng.uniform(0.12, 0.2), [ceiling, hazard]


def shade(points: np.ndarray, normals: np.ndarray, ks, shin, lights: list[dict],
           centre: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lambert diffuse and Blinn-Phong specular per point and light: two [N, n_lights] arrays."""
    view = -points / np.sqrt(np.einsum("ij,ij->i", points, points))[:, None]
    diff = np.empty((len(points), len(lights)), np.float32)
    spec = np.empty_like(diff)
    for i, light in enumerate(lights):
        to_l = light["pos"].astype(np.float32) - points
        dist2 = np.einsum("ij,ij->i", to_l, to_l)
        ldir = to_l / np.sqrt(dist2)[:, None]
        fall = float(np.sum((light["pos"] - centre) ** 2)) / dist2 * light["power"]
        half = ldir + view
        half /= np.sqrt(np.einsum("ij,ij->i", half, half))[:, None] + 1e-9
        diff[:, i] = np.clip(np.einsum("ij,ij->i", normals, ldir), 0, None) * fall
        nh = np.clip(np.einsum("ij,ij->i", normals, half), 1e-6, None)
        spec[:, i] = np.exp(np.log(nh) * shin) * ks * fall * 2.5
    return diff, spec


def footprints_small(intr: Intrinsics, footprints: list, grid: tuple[int, int]) -> list[np.ndarray | None]:
    """Each object's footprint (the renderer's bounding box and mask) on the (width, height) shading grid."""
    h, w = intr.height, intr.width
    out: list[np.ndarray | None] = []
    for fp in footprints:
        if fp is None:
            out.append(None)
            continue
        (x0, y0, x1, y1), full = fp
        m = np.zeros((h, w), np.float32)
        m[y0:y1, x0:x1] = full
        out.append(cv2.resize(m, grid, interpolation=cv2.INTER_AREA))
    return out

def shadow(intr: Intrinsics, light: dict, placed: list[Placed], footprints: list, masks_q: list, n: np.ndarray,
           d: float, grid: tuple[int, int]) -> np.ndarray:
    """Light visibility on the table, flattened on the (width, height) grid: each object's
    footprint (MASKS_Q, on the grid) pushed away from the light."""
    wq, hq = grid
    q = intr.width / wq
    occl = np.zeros((hq, wq), np.float32)
    for p, fp, m in zip(placed, footprints, masks_q):
        if fp is None:
            continue
        top = p.ground - p.axis(n) * (p.base_elev + p.model.height)
        lvec = top - light["pos"]
        t = (d - top @ n) / (lvec @ n)  # where the light ray through the top hits the table
        hit = top + t * lvec
        du = (hit[0] / hit[2] - top[0] / top[2]) * intr.fx / q
        dv = (hit[1] / hit[2] - top[1] / top[2]) * intr.fy / q
        steps = 4
        for s in range(1, steps + 1):
            shift = np.array([[1, 0, du * s / steps], [0, 1, dv * s / steps]], np.float32)
            occl = np.maximum(occl, cv2.warpAffine(m, shift, (wq, hq)))
    occl = cv2.GaussianBlur(occl, (0, 0), max(0.7, light["soft"] / q))
    return 1.0 - 0.85 * occl.ravel()
