"""Render one synthetic RGB-D tabletop scene: z-buffered solids, lights, shadows, sensor noise.

A scene is a tilted table plane seen by a D415-like camera, 1-4 objects from `shapes.py`
(touching, sometimes resting on each other where they would stay: `stacking.py`), one of the
thesis's lighting conditions (Table 5.3), and a depth map with the D415's failure modes (noise
growing with distance, holes on shiny metal, at depth edges and in the left invalid band).

A scene is its layout (camera, light, table, objects: `lay_out`) and a frame of it (`draw`): a
clutter-removal round (sim/clutter.py) lays out 4-10 objects once and draws a frame after each
pick with the objects posed where they settled, each with its id in the truth.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from edgepick.data.posed import draw_marched, paint
from edgepick.data.shading import footprints_small, lights_for, shade, shadow, table_albedo
from edgepick.data.shapes import MAKERS, Placed
from edgepick.data.stacking import rest_height
from edgepick.geometry import Intrinsics

CLASSES = ("background", "bearing", "disk", "adapter", "box")
LIGHTINGS = ("ceiling", "ceiling+white", "single", "hazard")
TABLES = ("wood", "laminate", "mat", "steel")
MARCH_TILT_DEG = 30.0  # a posed object tilted farther than this is marched ray by ray (data/posed.py)
OBJECT_WEIGHTS = {"bearing": 0.28, "disk": 0.16, "adapter": 0.28, "box": 0.28}


@dataclass
class Scene:
    rgb: np.ndarray  # uint8 [H, W, 3] RGB
    depth: np.ndarray  # uint16 [H, W] millimetres, 0 = no reading
    mask: np.ndarray  # uint8 [H, W] class ids
    grasps: list[dict]
    info: dict
    hidden: list[dict]  # the placed objects no pixel shows, as grasp truth (e.g. under a box): physics needs them


@dataclass
class Layout:
    """What every frame of one scene shares: the table plane (n . X = d, camera frame; d is the
    camera's height over it), its tilt, the light condition and its lights, the table's material,
    and the objects. `SceneRenderer.draw` renders a frame of it; a clutter-removal round
    (sim/clutter.py) draws one after each pick, with the objects where they settled."""

    n: np.ndarray
    d: float
    tilt: float
    lighting: str
    table: str
    albedo: np.ndarray  # the table's linear-RGB albedo, full size
    t_ks: float
    t_shin: float
    placed: list[Placed]
    ambient: np.ndarray
    lights: list[dict]
    ndotr: np.ndarray  # each pixel's ray . n


def _plane_frame(n: np.ndarray, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    x = np.array([1.0, 0.0, 0.0]) - n[0] * n
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    a1 = np.cos(yaw) * x + np.sin(yaw) * y
    return a1, np.cross(n, a1)


def solid_truth(p: Placed, n: np.ndarray) -> dict:
    """The placed object as a solid (docs/contracts.md#data-set-layout, "solid"): its base centre,
    up and major axes in the camera frame, and its dimensions in metres."""
    m, down = p.model, p.axis(n)
    dims = {"length": m.length, "width": m.width} if m.major_axis else dict(m.extra)
    return {"base_camera_m": [round(float(c), 6) for c in p.ground - down * p.base_elev],
            "up_camera": [round(float(c), 6) for c in -down], "axis_camera": [round(float(c), 6) for c in p.a1],
            "height": round(m.height, 6), **{k: round(float(v), 6) for k, v in dims.items()}}


class SceneRenderer:
    """Renders scenes for one image size; reuses the per-pixel ray table."""

    def __init__(self, intr: Intrinsics):
        self.intr = intr
        self.rays = intr.rays()
        # Noise pools drawn once (fixed seed) and cropped at per-scene random offsets: a full
        # frame of fresh normal samples per scene costs more than the rest of the sensor model.
        pool = np.random.default_rng(20231)
        h, w = intr.height, intr.width
        self._gauss = pool.standard_normal((h + 64, w + 64, 3), dtype=np.float32)
        self._unif = pool.random((h + 64, w + 64), dtype=np.float32)
        self._gamma = (np.power(np.linspace(0, 1, 4096, dtype=np.float32), 1 / 2.2) * 255).astype(np.float32)

    def _crop(self, pool: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        oy, ox = rng.integers(0, 64, 2)
        return pool[oy:oy + self.intr.height, ox:ox + self.intr.width]

    # ------------------------------------------------------------------ sampling
    def sample_objects(self, rng: np.random.Generator, n: np.ndarray, d: float,
                       area: Callable[[np.ndarray], bool] | None = None, count: tuple[int, int] = (1, 4),
                       tries: int = 20) -> list[Placed]:
        """COUNT (a range: 1-4 by default) objects on the table plane n . X = d, in view, each resting
        on the table or on those under it where it would stay (data/stacking.py); with AREA, only where
        AREA(ground point, camera frame) holds (a robot cell's pick area). An object with no such
        place in TRIES draws is left out."""
        intr = self.intr
        classes = list(OBJECT_WEIGHTS)
        probs = np.array(list(OBJECT_WEIGHTS.values()))
        placed: list[Placed] = []
        for _ in range(int(rng.integers(count[0], count[1] + 1))):
            cls = str(rng.choice(classes, p=probs / probs.sum()))
            if cls == "disk" and any(p.model.cls == "disk" for p in placed):
                cls = "bearing"
            model = MAKERS[cls](rng)
            rest = None
            for _try in range(tries):
                if placed and rng.random() < 0.45:  # touch or lean on a neighbour
                    other = placed[int(rng.integers(len(placed)))]
                    a = rng.uniform(0, 2 * np.pi)
                    dist = (other.model.radius + model.radius) * rng.uniform(0.55, 1.0)
                    cand = other.ground + _plane_frame(n, a)[0] * dist
                else:
                    m = 0.08
                    u = rng.uniform(m, 1 - m) * intr.width
                    v = rng.uniform(m, 1 - m) * intr.height
                    ray = np.array([(u - intr.cx) / intr.fx, (v - intr.cy) / intr.fy, 1.0])
                    cand = d / (n @ ray) * ray
                uv = cand[:2] / cand[2] * [intr.fx, intr.fy] + [intr.cx, intr.cy]
                inside = (0.04 * intr.width < uv[0] < 0.96 * intr.width) and (0.04 * intr.height < uv[1] < 0.96 * intr.height)
                if not inside or (area is not None and not area(cand)):
                    continue
                a1, a2 = _plane_frame(n, rng.uniform(-np.pi, np.pi))
                base = rest_height(placed, model, cand, a1, a2)  # None: it would tip over there
                if base is not None:
                    rest = Placed(model, cand, base, a1, a2)
                    break
            if rest is not None:
                placed.append(rest)
        return placed

    # ----------------------------------------------------------------- rendering
    def _bbox(self, p: Placed, n: np.ndarray) -> tuple[int, int, int, int] | None:
        intr = self.intr
        pts = []
        for elev in (p.base_elev, p.base_elev + p.model.height):  # any point lies within radius of this axis
            c = p.ground - p.axis(n) * elev
            r = p.model.radius * intr.fx / c[2] * 1.05 + 3
            u, v = c[0] / c[2] * intr.fx + intr.cx, c[1] / c[2] * intr.fy + intr.cy
            pts += [(u - r, v - r), (u + r, v + r)]
        corners = np.array(pts)
        x0, y0 = np.floor(corners.min(0)).astype(int)
        x1, y1 = np.ceil(corners.max(0)).astype(int)
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, intr.width), min(y1, intr.height)
        return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None

    def render(self, rng: np.random.Generator, camera_height_m: float | None = None,
               area: Callable[[np.ndarray], bool] | None = None) -> Scene:
        """One scene. `camera_height_m` fixes the camera straight above the table at that height
        (a calibrated robot cell); by default height and tilt are random. AREA: see sample_objects."""
        return self.draw(self.lay_out(rng, camera_height_m, area), rng)

    def lay_out(self, rng: np.random.Generator, camera_height_m: float | None = None,
                area: Callable[[np.ndarray], bool] | None = None, count: tuple[int, int] = (1, 4),
                tries: int = 20) -> Layout:
        """A scene's layout: the camera over the table, the light condition, the table and COUNT objects
        (see sample_objects), drawn from RNG in the order `render` has always drawn them."""
        intr = self.intr
        h, w = intr.height, intr.width
        cam_h = rng.uniform(0.55, 0.8)
        tilt = np.deg2rad(rng.uniform(0, 10))
        tdir = rng.uniform(0, 2 * np.pi)
        if camera_height_m is not None:  # the draws above still happen: the rest of the scene is unchanged
            cam_h, tilt = float(camera_height_m), 0.0
        n = np.array([np.sin(tilt) * np.cos(tdir), np.sin(tilt) * np.sin(tdir), np.cos(tilt)])
        d = cam_h  # table plane: n . X = d
        lighting = LIGHTINGS[int(rng.integers(len(LIGHTINGS)))]
        table = TABLES[int(rng.integers(len(TABLES)))]
        ndotr = (self.rays @ n.astype(np.float32)).astype(np.float32)
        albedo, t_ks, t_shin = table_albedo(rng, table, h // 2, w // 2)  # sensor blur hides the upsampling
        albedo = cv2.resize(albedo.astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
        placed = self.sample_objects(rng, n, d, area, count, tries)
        centre = (d / ndotr[h // 2, w // 2]) * self.rays[h // 2, w // 2]
        ambient, lights = lights_for(rng, lighting, centre, n)
        return Layout(n, d, tilt, lighting, table, albedo, t_ks, t_shin, placed, ambient, lights, ndotr)

    def draw(self, layout: Layout, rng: np.random.Generator) -> Scene:
        """A frame of LAYOUT: its objects z-buffered, shaded and shadowed under its lights, and the
        sensor's exposure, blur, noise and depth failures drawn from RNG."""
        intr = self.intr
        h, w = intr.height, intr.width
        n, d, ndotr, placed = layout.n, layout.d, layout.ndotr, layout.placed
        lighting, table, t_ks, t_shin = layout.lighting, layout.table, layout.t_ks, layout.t_shin
        ambient, lights = layout.ambient, layout.lights
        zbuf = (d / ndotr).astype(np.float32)
        albedo = layout.albedo.copy()  # the objects are painted into it
        normal = np.zeros((h, w, 3), np.float32)  # per-pixel materials: read on object pixels only
        ks = np.zeros((h, w), np.float32)
        shin = np.zeros((h, w), np.float32)
        metal = np.zeros((h, w), bool)
        label = np.zeros((h, w), np.uint8)
        inst = np.zeros((h, w), np.uint8)

        buffers = dict(zbuf=zbuf, albedo=albedo, normal=normal, ks=ks, shin=shin, metal=metal, label=label, inst=inst)
        footprints = [self._rasterize(p, k, n, d, ndotr, buffers) for k, p in enumerate(placed, start=1)]

        centre = (d / ndotr[h // 2, w // 2]) * self.rays[h // 2, w // 2]
        colours = np.stack([light["colour"] for light in lights]).astype(np.float32)  # [n_lights, 3]
        on_table = label == 0
        # The table is flat and its shadows are soft: light it at 1/4 resolution, then upsample.
        q = 4
        small = self.rays[q // 2::q, q // 2::q]
        gh, gw = small.shape[:2]
        pts_t = (small * (d / (small @ n.astype(np.float32)))[..., None]).reshape(-1, 3)
        nrm_t = np.broadcast_to((-n).astype(np.float32), pts_t.shape)
        dif_t, spc_t = shade(pts_t, nrm_t, t_ks, t_shin, lights, centre)
        objects_q = cv2.resize((~on_table).astype(np.float32), (gw, gh), interpolation=cv2.INTER_AREA)
        amb_q = 1 - 0.5 * cv2.GaussianBlur(objects_q, (0, 0), 1.5)  # contact shadow around bases
        masks_q = footprints_small(intr, footprints, (gw, gh))  # once per object, not per light
        vis = np.stack([shadow(intr, light, placed, footprints, masks_q, n, d, (gw, gh)) for light in lights], 1)
        light_q = amb_q[..., None] * ambient.astype(np.float32) + ((dif_t * vis) @ colours).reshape(gh, gw, 3)
        spec_q = ((spc_t * vis) @ colours).reshape(gh, gw, 3)
        light = cv2.resize(light_q, (w, h), interpolation=cv2.INTER_LINEAR)
        spec = cv2.resize(spec_q, (w, h), interpolation=cv2.INTER_LINEAR)
        # Objects: per pixel, no cast shadow; metal tints its highlights.
        ys, xs = np.nonzero(~on_table)
        pts_o = self.rays[ys, xs] * zbuf[ys, xs, None]
        dif_o, spc_o = shade(pts_o, normal[ys, xs], ks[ys, xs], shin[ys, xs], lights, centre)
        alb_o = albedo[ys, xs]
        spec_o = spc_o @ colours
        is_metal = metal[ys, xs]
        spec_o[is_metal] *= alb_o[is_metal] / (alb_o[is_metal].mean(1, keepdims=True) + 1e-3)
        light[ys, xs] = ambient.astype(np.float32) + dif_o @ colours
        spec[ys, xs] = spec_o
        spec_lum = np.zeros((h, w), np.float32)  # read on metal pixels only (depth holes)
        spec_lum[ys, xs] = spc_o.sum(1)
        linear = cv2.add(cv2.multiply(albedo, light), spec)
        mean_lin = float(np.mean(cv2.mean(linear)[:3]))
        gain = float(np.clip((0.2 / (mean_lin + 1e-4)) ** 0.7, 0.5, 4.0)) * rng.uniform(0.85, 1.15)
        idx = np.clip(linear * (gain * 4095), 0, 4095).astype(np.int16)
        img = self._gamma[idx]
        img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.5, 0.9))
        img = cv2.scaleAdd(self._crop(self._gauss, rng), float(2.0 * np.sqrt(gain)), img)
        rgb = cv2.convertScaleAbs(np.maximum(img, 0))  # rounds and saturates to uint8
        dark = np.zeros((h, w), bool)
        dark[ys, xs] = albedo[ys, xs].mean(1) < 0.01
        depth = self._depth(rng, zbuf, metal, spec_lum * gain, dark)
        grasps, hidden = self._grasps(placed, footprints, inst, n)
        info = {"lighting": lighting, "table": table, "camera_height_m": round(d, 4),
                "tilt_deg": round(float(np.rad2deg(layout.tilt)), 2), "exposure_gain": round(gain, 3),
                "objects": [f"{p.model.cls}:{p.model.variant}" for p in placed]}
        return Scene(rgb, depth, label, grasps, info, hidden)

    def _rasterize(self, p: Placed, k: int, n: np.ndarray, d: float, ndotr: np.ndarray, buf: dict) -> tuple | None:
        """Z-buffer object K (its parts as extruded footprints at four levels, top face first; more for
        a posed object tilted off the table's normal, whose side faces the camera) into the per-pixel
        buffers; returns its bounding box and footprint, or None when out of view."""
        zbuf = buf["zbuf"]
        box = self._bbox(p, n)
        if box is None:
            return None
        x0, y0, x1, y1 = box
        rays = self.rays[y0:y1, x0:x1]
        m = p.axis(n)
        count = 4
        if p.down is None:
            inv_nr = 1.0 / ndotr[y0:y1, x0:x1]
        elif m @ n < np.cos(np.deg2rad(MARCH_TILT_DEG)):  # tipped far over: its sides face the camera
            return draw_marched(self.rays[y0:y1, x0:x1], p, CLASSES.index(p.model.cls), k, box, buf)
        else:  # a level's plane m . X = m . c, at most MARCH_TILT_DEG off the table's
            inv_nr = (1.0 / (rays @ m.astype(np.float32))).astype(np.float32)
            slope = float(np.sqrt(max(0.0, 1 - (m @ n) ** 2)) / (m @ n))  # tan of its tilt
            count = min(32, max(4, int(np.ceil(p.model.height * slope / 0.002)) + 1))
        # A point on the ray at depth z has object-frame coordinates (ray.a1) z - c.a1:
        # project the rays once per object, then each level is two multiply-adds.
        ray_a1, ray_a2 = rays @ p.a1.astype(np.float32), rays @ p.a2.astype(np.float32)
        full = np.zeros((y1 - y0, x1 - x0), bool)
        for part in p.model.parts:
            done = np.zeros_like(full)
            levels = np.linspace(1.0, 0.0, count)
            for li, t in enumerate(levels):
                elev = p.base_elev + part.z0 + t * (part.z1 - part.z0)
                c = p.ground - m * elev
                z = np.float32(d - elev) * inv_nr if p.down is None else np.float32(m @ c) * inv_nr
                lx = ray_a1 * z - np.float32(c @ p.a1)
                ly = ray_a2 * z - np.float32(c @ p.a2)
                inside = (part.sdf(lx, ly) < 0) & ~done
                if not inside.any():
                    continue
                done |= inside
                sub_z = zbuf[y0:y1, x0:x1]
                win = inside & (z < sub_z)
                if not win.any():
                    continue
                sub_z[win] = z[win]
                ax, ay = lx[win], ly[win]
                col = part.albedo(ax, ay)
                if li == 0:  # top face: up, with the part's curvature tilt
                    tx, ty = part.tilt(ax, ay) if part.tilt else (0.0 * ax, 0.0 * ay)
                    nn = -m[None, :] + tx[:, None] * p.a1[None, :] + ty[:, None] * p.a2[None, :]
                else:  # side wall: outward gradient of the footprint
                    eps = 5e-4
                    gx = part.sdf(ax + eps, ay) - part.sdf(ax - eps, ay)
                    gy = part.sdf(ax, ay + eps) - part.sdf(ax, ay - eps)
                    nn = gx[:, None] * p.a1[None, :] + gy[:, None] * p.a2[None, :] - 0.15 * m[None, :]
                    col = col * 0.85
                nn /= np.linalg.norm(nn, axis=1, keepdims=True) + 1e-9
                paint(buf, box, win, col, nn, part, CLASSES.index(p.model.cls), k)
            full |= done
        return box, full

    def _depth(self, rng: np.random.Generator, z: np.ndarray, metal: np.ndarray, spec: np.ndarray,
               dark: np.ndarray) -> np.ndarray:
        """D415-like depth: noise ~ z^2, smooth error blobs, holes on shiny metal, edges, left band."""
        h, w = z.shape
        sigma = 0.0008 + 0.003 * z ** 2
        blob = cv2.resize(rng.standard_normal((h // 16, w // 16)).astype(np.float32), (w, h),
                          interpolation=cv2.INTER_CUBIC)
        zn = z + sigma * (0.6 * self._crop(self._gauss, rng)[..., 0] + 0.8 * blob)
        valid = np.ones((h, w), bool)
        valid &= ~(metal & (spec > rng.uniform(0.35, 0.6)))  # saturated highlights break the stereo match
        drop = cv2.resize(rng.random((h // 12, w // 12)).astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
        valid &= ~(metal & (drop < rng.uniform(0.15, 0.3)))
        valid &= ~(dark & (drop < 0.4))  # black plastic absorbs the IR pattern
        gx = np.abs(cv2.Sobel(z, cv2.CV_32F, 1, 0, ksize=3))
        gy = np.abs(cv2.Sobel(z, cv2.CV_32F, 0, 1, ksize=3))
        edge = cv2.dilate(((gx + gy) > 0.02).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        valid &= ~(edge & (self._crop(self._unif, rng) < 0.7))
        band = int(round(rng.uniform(0.012, 0.035) * w))
        valid[:, :band] = False
        mm = np.clip(np.round(zn * 1000.0), 0, 65535).astype(np.uint16)
        mm[~valid] = 0
        return mm

    def _grasps(self, placed: list[Placed], footprints: list, inst: np.ndarray,
                n: np.ndarray) -> tuple[list[dict], list[dict]]:
        """The grasp truth of the objects the image shows, and that of those it does not (no visible
        pixel, or out of view: only their class, top point and solid)."""
        intr = self.intr
        out, hidden = [], []
        for k, (p, fp) in enumerate(zip(placed, footprints), start=1):
            top = p.ground - p.axis(n) * (p.base_elev + p.model.height)
            visible = 0 if fp is None else int((inst == k).sum())
            key = {} if p.key is None else {"id": p.key}
            if visible == 0:
                hidden.append({"class": p.model.cls, "point_camera_m": [round(float(c), 5) for c in top],
                               "solid": solid_truth(p, n), **key})
                continue
            uv = top[:2] / top[2] * [intr.fx, intr.fy] + [intr.cx, intr.cy]
            angle = 0.0
            if p.model.major_axis:
                tip = top + p.a1 * p.model.length / 2
                tuv = tip[:2] / tip[2] * [intr.fx, intr.fy] + [intr.cx, intr.cy]
                angle = float(np.rad2deg(np.arctan2(tuv[1] - uv[1], tuv[0] - uv[0])))
                angle = angle - 180.0 if angle > 90.0 else (angle + 180.0 if angle <= -90.0 else angle)
            (x0, y0, x1, y1), full = fp
            out.append({
                "class": p.model.cls, "variant": p.model.variant,
                "pixel": [round(float(uv[0]), 2), round(float(uv[1]), 2)],
                "angle_deg": round(angle, 2), "orientation_defined": bool(p.model.major_axis),
                "point_camera_m": [round(float(c), 5) for c in top],
                "visible_fraction": round(visible / max(1, int(full.sum())), 3),
                "solid": solid_truth(p, n), **key,
            })
        return out, hidden
