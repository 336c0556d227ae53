"""The thesis's four objects as extruded 2D solids with procedural materials.

Each object is a list of `Part`s: a signed-distance footprint in the object's local
table-plane frame (metres), an elevation range above the object's base, and a material
(albedo texture, specular strength and shininess, normal tilt for curved metal).
Everything is numpy; the renderer in `synth.py` ray-casts these per pixel.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

Array = np.ndarray
SdfFn = Callable[[Array, Array], Array]
TextureFn = Callable[[Array, Array], Array]  # (lx, ly) -> [..., 3] linear RGB albedo
TiltFn = Callable[[Array, Array], tuple[Array, Array]]  # (lx, ly) -> normal tilt (tx, ty)


@dataclass
class Part:
    sdf: SdfFn
    z0: float  # bottom elevation above the object's base (m)
    z1: float  # top elevation (m)
    albedo: TextureFn
    ks: float = 0.05  # specular strength
    shininess: float = 20.0
    metal: bool = False  # specular takes the albedo's tint; shiny metal loses depth
    tilt: TiltFn | None = None


@dataclass
class ObjectModel:
    cls: str
    variant: str
    parts: list[Part]
    radius: float  # bounding radius of the footprint (m)
    height: float  # total height (m)
    major_axis: bool  # False for round objects (no stable major axis)
    length: float = 0.0  # along the local x axis
    width: float = 0.0
    extra: dict = field(default_factory=dict)  # round objects: their radii and heights (the solid's truth)


# --------------------------------------------------------------------------- sdfs

def sdf_round_rect(half_l: float, half_w: float, r: float) -> SdfFn:
    def f(x: Array, y: Array) -> Array:
        qx = np.abs(x) - (half_l - r)
        qy = np.abs(y) - (half_w - r)
        outside = np.hypot(np.maximum(qx, 0), np.maximum(qy, 0))
        return outside + np.minimum(np.maximum(qx, qy), 0) - r
    return f


def sdf_annulus(r_out: float, r_in: float) -> SdfFn:
    def f(x: Array, y: Array) -> Array:
        rr = np.hypot(x, y)
        return np.maximum(rr - r_out, r_in - rr)
    return f


def sdf_with_holes(base: SdfFn, holes: list[tuple[float, float, float]]) -> SdfFn:
    """Subtract round holes (cx, cy, radius) from a footprint."""
    def f(x: Array, y: Array) -> Array:
        d = base(x, y)
        for hx, hy, hr in holes:
            d = np.maximum(d, hr - np.hypot(x - hx, y - hy))
        return d
    return f


# ----------------------------------------------------------------------- textures

class Noise:
    """Smooth value noise on a small random grid, sampled at local metric coordinates."""

    def __init__(self, rng: np.random.Generator, cells: int, extent_m: float, octaves: int = 2):
        grid = np.zeros((cells, cells), np.float32)
        amp = 1.0
        for o in range(octaves):
            n = max(2, cells // (2 ** (octaves - 1 - o)))
            g = rng.standard_normal((n, n)).astype(np.float32)
            grid += amp * cv2.resize(g, (cells, cells), interpolation=cv2.INTER_CUBIC)
            amp *= 0.5
        self.grid = grid / (np.abs(grid).max() + 1e-6)
        self.scale = (cells - 1) / (2 * extent_m)
        self.extent = extent_m

    def __call__(self, x: Array, y: Array) -> Array:
        mx = ((x + self.extent) * self.scale).astype(np.float32)
        my = ((y + self.extent) * self.scale).astype(np.float32)
        shape, size = mx.shape, mx.size
        if size == 0:
            return np.zeros(shape, np.float32)
        cols = 1024  # remap wants a 2D map with sides < 32767
        rows = -(-size // cols)
        pad = rows * cols - size
        mx = np.pad(mx.ravel(), (0, pad)).reshape(rows, cols)
        my = np.pad(my.ravel(), (0, pad)).reshape(rows, cols)
        out = cv2.remap(self.grid, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        return out.ravel()[:size].reshape(shape)


def _rgb(c: Array | tuple, shape: tuple) -> Array:
    return np.broadcast_to(np.asarray(c, np.float32), shape + (3,)).copy()


def _srgb_to_linear(c: tuple[float, float, float]) -> Array:
    return np.power(np.asarray(c, np.float32), 2.2)


# -------------------------------------------------------------------------- objects

def make_box(rng: np.random.Generator) -> ObjectModel:
    """Cardboard box: brown fibre texture, flap seam, tape or print variants. At most 100 mm wide, so
    that an RG2's 110 mm opening takes it across, as the thesis's boxes (5.2: picked with the RG2)."""
    length = rng.uniform(0.12, 0.22)
    width = rng.uniform(0.08, min(0.10, length * 0.85))
    height = rng.uniform(0.05, 0.11)
    variant = str(rng.choice(["plain", "tape", "clear-tape", "print", "label"]))
    base = _srgb_to_linear((rng.uniform(0.55, 0.72), rng.uniform(0.40, 0.52), rng.uniform(0.22, 0.33)))
    fibre = Noise(rng, 48, length, octaves=3)
    blotch = Noise(rng, 8, length, octaves=2)
    hl, hw = length / 2, width / 2
    tape_w = rng.uniform(0.04, 0.05) / 2
    tape_col = _srgb_to_linear((0.72, 0.56, 0.34))  # the "tape" variant's
    logo = (rng.uniform(-0.5, 0.2) * hl, rng.uniform(-0.6, 0.2) * hw,
            rng.uniform(0.15, 0.35) * hl, rng.uniform(0.2, 0.35) * hw)
    ink = _srgb_to_linear(tuple(rng.uniform(0.02, 0.35, 3)))

    def albedo(x: Array, y: Array) -> Array:
        shade = 1.0 + 0.10 * fibre(x, y) + 0.12 * blotch(x, y)
        edge = np.clip(np.minimum(hl - np.abs(x), hw - np.abs(y)) / 0.006, 0.6, 1.0)
        col = _rgb(base, x.shape) * (shade * edge)[..., None]
        seam = np.abs(y) < 0.0012
        col[seam] *= 0.35
        if variant == "tape":
            band = np.abs(y) < tape_w
            col[band] = tape_col * (1.0 + 0.05 * fibre(x[band] * 3, y[band]))[..., None]
        elif variant == "print":
            lx, ly, sx, sy = logo
            m = (np.abs(x - lx) < sx) & (np.abs(y - ly - hw * 0.5) < sy)
            col[m] = ink
            lines = (np.abs(y + hw * 0.55) < hw * 0.25) & (np.abs(x) < hl * 0.6) & \
                    (np.sin(y * 900.0) > 0.3)
            col[lines] *= 0.25
        elif variant == "label":
            m = (np.abs(x + hl * 0.35) < hl * 0.3) & (np.abs(y - hw * 0.45) < hw * 0.28)
            col[m] = 0.8
            bars = m & (np.abs(y - hw * 0.45) < hw * 0.12) & (np.sin(x * 2600.0 + 3 * np.sin(x * 700)) > 0)
            col[bars] = 0.03
        return col

    ks = 0.35 if variant == "clear-tape" else (0.12 if variant == "tape" else 0.03)
    part = Part(sdf_round_rect(hl, hw, 0.003), 0.0, height, albedo, ks=ks, shininess=40.0)
    return ObjectModel("box", variant, [part], radius=float(np.hypot(hl, hw)), height=height,
                       major_axis=True, length=length, width=width)


def make_adapter(rng: np.random.Generator) -> ObjectModel:
    """Outlet plug adapter: white body with a grey face, or black plastic; two pin holes."""
    variant = str(rng.choice(["white", "black"]))
    length = rng.uniform(0.055, 0.07)
    width = rng.uniform(0.038, 0.048)
    height = rng.uniform(0.03, 0.045)
    hl, hw = length / 2, width / 2
    grain = Noise(rng, 16, length, octaves=2)
    if variant == "white":
        body, face = _srgb_to_linear((0.90, 0.90, 0.88)), _srgb_to_linear((0.58, 0.58, 0.60))
        ks, shin = 0.15, 30.0
    else:
        body, face = _srgb_to_linear((0.06, 0.06, 0.065)), _srgb_to_linear((0.09, 0.09, 0.10))
        ks, shin = 0.45, 60.0
    pin_dx = hl * 0.42

    def albedo(x: Array, y: Array) -> Array:
        col = _rgb(body, x.shape) * (1.0 + 0.04 * grain(x, y))[..., None]
        inner = (np.abs(x) < hl * 0.78) & (np.abs(y) < hw * 0.72)
        col[inner] = face * (1.0 + 0.15 * grain(x[inner] * 4, y[inner] * 4))[..., None]
        for sx in (-pin_dx, pin_dx):
            pin = np.hypot(x - sx, y) < 0.0035
            col[pin] = 0.01
        return col

    part = Part(sdf_round_rect(hl, hw, 0.006), 0.0, height, albedo, ks=ks, shininess=shin)
    return ObjectModel("adapter", variant, [part], radius=float(np.hypot(hl, hw)), height=height,
                       major_axis=True, length=length, width=width)


def _radial_tilt(bumps: list[tuple[float, float, float]]) -> TiltFn:
    """Normal tilt of rounded metal races: each bump (r0, r1, strength) tilts outward at r1, inward at r0."""
    def f(x: Array, y: Array) -> tuple[Array, Array]:
        rr = np.hypot(x, y) + 1e-9
        slope = np.zeros_like(rr)
        for r0, r1, s in bumps:
            t = np.clip((rr - r0) / (r1 - r0), 0.0, 1.0)
            inside = (rr >= r0) & (rr <= r1)
            slope += np.where(inside, s * (2 * t - 1) ** 3, 0.0)
        return slope * x / rr, slope * y / rr
    return f


def make_bearing(rng: np.random.Generator) -> ObjectModel:
    """Car wheel bearing: polished inner and outer steel races around a dark seal."""
    r_out = rng.uniform(0.034, 0.042)
    r_in = r_out * rng.uniform(0.48, 0.58)
    height = rng.uniform(0.03, 0.04)
    r_inner_race = r_in + (r_out - r_in) * 0.3
    r_seal = r_in + (r_out - r_in) * 0.72
    steel = _srgb_to_linear((rng.uniform(0.62, 0.75),) * 3) * np.array([1.0, 1.0, 1.03], np.float32)
    seal = _srgb_to_linear((0.16, 0.16, 0.17)) if rng.random() < 0.6 else steel * 0.55
    rough = Noise(rng, 32, r_out, octaves=3)

    def albedo(x: Array, y: Array) -> Array:
        rr = np.hypot(x, y)
        col = _rgb(steel, x.shape) * (1.0 + 0.06 * rough(x, y) + 0.04 * np.sin(rr * 4000.0))[..., None]
        band = (rr > r_inner_race) & (rr < r_seal)
        col[band] = seal
        return col

    tilt = _radial_tilt([(r_in, r_inner_race, 0.7), (r_seal, r_out, 0.7)])
    part = Part(sdf_annulus(r_out, r_in), 0.0, height, albedo, ks=0.9, shininess=60.0, metal=True, tilt=tilt)
    return ObjectModel("bearing", "steel", [part], radius=r_out, height=height, major_axis=False,
                       extra={"r_out": r_out, "r_in": r_in})


def make_disk(rng: np.random.Generator) -> ObjectModel:
    """Brake disk: brushed friction ring with a raised hub (hat), centre bore and bolt holes."""
    r_out = rng.uniform(0.12, 0.145)
    r_hat = r_out * rng.uniform(0.48, 0.55)
    r_bore = r_hat * rng.uniform(0.42, 0.5)
    ring_h = rng.uniform(0.02, 0.028)
    hat_h = ring_h + rng.uniform(0.02, 0.035)
    n_bolts = int(rng.choice([4, 5, 5, 6]))
    bolt_r = (r_hat + r_bore) / 2
    phase = rng.uniform(0, 2 * np.pi)
    bolts = [(bolt_r * np.cos(phase + 2 * np.pi * k / n_bolts), bolt_r * np.sin(phase + 2 * np.pi * k / n_bolts),
              0.0065) for k in range(n_bolts)]
    steel = _srgb_to_linear((rng.uniform(0.5, 0.62),) * 3)
    rust = _srgb_to_linear((0.45, 0.25, 0.12))
    hat_col = _srgb_to_linear((0.22, 0.22, 0.23)) if rng.random() < 0.5 else steel * 0.8
    rust_map = Noise(rng, 12, r_out, octaves=2)
    grain = Noise(rng, 64, r_out, octaves=3)
    rust_amount = rng.uniform(0.0, 0.6)

    def ring_albedo(x: Array, y: Array) -> Array:
        rr = np.hypot(x, y)
        brushed = 1.0 + 0.07 * np.sin(rr * 2200.0 + 6.0 * grain(x, y)) + 0.05 * grain(x, y)
        col = _rgb(steel, x.shape) * brushed[..., None]
        r = np.clip(rust_map(x, y) * 2.0 - 1.0 + rust_amount, 0.0, 1.0)[..., None] * 0.7
        return col * (1 - r) + rust * r

    def hat_albedo(x: Array, y: Array) -> Array:
        return _rgb(hat_col, x.shape) * (1.0 + 0.08 * grain(x * 2, y * 2))[..., None]

    ring = Part(sdf_annulus(r_out, r_hat * 0.85), 0.0, ring_h, ring_albedo, ks=0.35, shininess=25.0, metal=True,
                tilt=_radial_tilt([(r_out - 0.004, r_out, 0.5)]))
    hat = Part(sdf_with_holes(sdf_annulus(r_hat, r_bore), bolts), 0.0, hat_h, hat_albedo, ks=0.25,
               shininess=15.0, metal=True, tilt=_radial_tilt([(r_hat - 0.006, r_hat, 0.8)]))
    return ObjectModel("disk", "cast-iron", [ring, hat], radius=r_out, height=hat_h, major_axis=False,
                       extra={"r_out": r_out, "r_ring_in": r_hat * 0.85, "ring_h": ring_h, "r_hat": r_hat,
                              "r_bore": r_bore, "hat_h": hat_h})


MAKERS: dict[str, Callable[[np.random.Generator], ObjectModel]] = {
    "bearing": make_bearing,
    "disk": make_disk,
    "adapter": make_adapter,
    "box": make_box,
}


@dataclass
class Placed:
    """One object laid out in a scene: its model, where it stands on the table, and how it is turned."""

    model: ObjectModel
    ground: np.ndarray  # point on the table plane under the object's centre (camera frame, m)
    base_elev: float  # elevation of the object's base above the table (stacked objects)
    a1: np.ndarray  # local x axis (major axis) in the table plane
    a2: np.ndarray
    # an object posed anywhere (where it settled: sim/clutter.py): its own down axis (its base's normal, away
    # from its top), with GROUND its base centre, BASE_ELEV 0 and A1, A2 across DOWN; None: upright on the table
    down: np.ndarray | None = None
    key: int | None = None  # the object's id in its grasp truth ("id"), when it has one (a clutter-removal round)

    def axis(self, n: np.ndarray) -> np.ndarray:
        """The object's down axis: its own when posed, else the table's normal N."""
        return n if self.down is None else self.down
