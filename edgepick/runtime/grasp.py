"""Grasp records from a label image (docs/contracts.md#grasp-record): filters, moments, robust depth, robot pose.

Thesis 5.1 filters each class mask with a 3x3 median then a 5x5 dilation; each connected
region is one object, unless regions.py splits it (touching objects of one class). Its depth
comes from its own valid depth pixels (a bearing's centroid falls in its hole, shiny metal leaves
depth holes); its centroid and major-axis angle from the image moments (eq. 5.1, 5.2) of its top
face, which leaves out the side walls a tall object shows off the optical axis; with a
calibration, its pose in the robot base frame. numpy + OpenCV only.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import cv2
import numpy as np

from edgepick.errors import EdgepickError, ParameterError
from edgepick.geometry import Intrinsics, deproject
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp_config import GraspConfig
from edgepick.runtime.grasp_record import NO_DEPTH, Grasp
from edgepick.runtime.readings import histogram, median, percentile_25, readings
from edgepick.runtime.regions import components, depth_holes, near_level, row_ends, split_touching

DEFAULT_CLASSES = ("background", "bearing", "disk", "adapter", "box")
RAISED_FACE_SHARE = 0.6  # a top face at most this share of its object's region stands above the rest (a disk's hub)
NEIGHBOUR_READING_PX = 7  # occluded_fraction: a neighbour's rim pixel with no depth takes its nearest reading this close
LEVEL_M = 0.01  # an object whose own surface around its raised face spans no more depth than this lies flat
OWN_SURFACE_M = 0.01  # occluded_fraction: its own readings this far beyond its median one are no surface to rest on


class Laps:
    """Milliseconds spent in each sub-step of the grasp step over one or more frames, for `grasp
    --profile` and benchmarks/runtime_stages.py: call it with a step's name when that step ends."""

    STEPS = ("filters", "regions", "splits", "depth", "top face", "moments", "3d", "occlusion")

    def __init__(self) -> None:
        self.ms = dict.fromkeys(self.STEPS, 0.0)
        self.start()

    def start(self) -> None:
        """Start timing the next step from now."""
        self.t = time.perf_counter()

    def __call__(self, step: str) -> None:
        now = time.perf_counter()
        self.ms[step] += 1000 * (now - self.t)
        self.t = now


def _no_lap(step: str) -> None:
    """The lap function when nobody is timing the sub-steps."""


def filter_class_masks(labels: np.ndarray, num_classes: int, cfg: GraspConfig) -> dict[int, tuple[int, int, np.ndarray]]:
    """Per class present: median blur then dilation of its binary mask (uint8 0/1), worked on
    the class's bounding box plus a margin (the result is the same as on the whole frame, at a
    fraction of the cost). Returns {class: (x0, y0, mask crop)}."""
    out: dict[int, tuple[int, int, np.ndarray]] = {}
    kernel = np.ones((cfg.dilate_ksize, cfg.dilate_ksize), np.uint8)
    margin = cfg.median_ksize // 2 + cfg.dilate_ksize // 2 + 1
    h, w = labels.shape
    ox, oy, seen = 0, 0, labels  # where to look for the classes: on uint8, the box around all object pixels
    if labels.dtype == np.uint8:
        ox, oy, ow, oh = cv2.boundingRect(labels)
        if ow == 0:
            return out
        seen = labels[oy:oy + oh, ox:ox + ow]
    counts = (cv2.calcHist([seen], [0], None, [256], [0, 256]).ravel() if seen.dtype == np.uint8
              else np.bincount(seen.ravel(), minlength=num_classes))  # calcHist: ~2x faster on uint8
    for c in np.flatnonzero(counts[1:num_classes]) + 1:
        x, y, bw, bh = cv2.boundingRect((seen == c).view(np.uint8))
        x0, y0 = max(x + ox - margin, 0), max(y + oy - margin, 0)
        x1, y1 = min(x + ox + bw + margin, w), min(y + oy + bh + margin, h)
        m = (labels[y0:y1, x0:x1] == c).view(np.uint8)
        m = cv2.medianBlur(m, cfg.median_ksize)
        out[int(c)] = (x0, y0, cv2.dilate(m, kernel))
    return out


def border_contact(region: np.ndarray, x: int, y: int, frame_hw: tuple[int, int]) -> int:
    """How many of REGION's pixels (its top left at frame pixel (x, y)) lie on the frame's edge."""
    h, w = region.shape
    edges = ((x == 0, region[:, 0]), (y == 0, region[0, :]), (x + w == frame_hw[1], region[:, -1]),
             (y + h == frame_hw[0], region[-1, :]))
    return sum(int(line.sum()) for on_edge, line in edges if on_edge)


def moments_pose(region: np.ndarray, round_ratio: float) -> tuple[float, float, float, bool, int]:
    """(cx, cy, angle_deg, orientation_defined, area) of a binary region from its moments."""
    m = cv2.moments(region, binaryImage=True)
    area = int(m["m00"])
    cx, cy = m["m10"] / m["m00"], m["m01"] / m["m00"]
    mu20, mu02, mu11 = m["mu20"], m["mu02"], m["mu11"]
    common = math.sqrt(4 * mu11 ** 2 + (mu20 - mu02) ** 2)
    major, minor = (mu20 + mu02 + common) / 2, (mu20 + mu02 - common) / 2
    defined = major > 0 and minor / major < round_ratio
    angle = round(math.degrees(0.5 * math.atan2(2 * mu11, mu20 - mu02)), 2) if defined else 0.0
    if angle <= -90.0:  # after rounding: -89.999 -> -90.0 must become 90.0
        angle += 180.0
    return cx, cy, angle, defined, area


def rect_fill_and_axis(face: np.ndarray) -> tuple[float, float]:
    """The face's area over that of its minimum-area rectangle (~1 for a box's top, pi/4 for an
    ellipse), and the direction of that rectangle's long side in (-90, 90] degrees like
    moments_pose: a box's or adapter's axis even when a depth hole cuts a corner off its top face,
    which tilts the moments' axis of a nearly square face by tens of degrees."""
    (_, _), (w, h), a = cv2.minAreaRect(row_ends(face))
    angle = a if w >= h else a + 90.0
    angle = (angle + 90.0) % 180.0 - 90.0
    return cv2.countNonZero(face) / max(1.0, w * h), round(90.0 if angle == -90.0 else angle, 2)


def object_depth(depth: np.ndarray, region: np.ndarray, depth_scale: float, min_px: int,
                 share: float = 0.08, level_m: float = 0.004) -> float | None:
    """Depth of the object's top surface (metres) from its own valid pixels, or None when too few
    are valid: the nearest depth level (LEVEL_M bins, three at a time) that holds SHARE of them,
    then the 25th percentile of the pixels within 2 x LEVEL_M of its median. Not the median, nor
    a fixed percentile of all: a mask that bleeds onto the table, or covers a ring's hole, over a
    shiny object that returns few depth pixels may hold more table pixels than object ones.

    Worked on the distinct depth readings and their counts (runtime/readings.py): the same result,
    to the last bit, as np.histogram, np.median and np.percentile on every pixel's value."""
    return readings_depth(depth[(region > 0) & (depth > 0)], depth_scale, min_px, share, level_m)


def readings_depth(units: np.ndarray, depth_scale: float, min_px: int, share: float = 0.08,
                   level_m: float = 0.004) -> float | None:
    """object_depth of the valid depth readings UNITS (1-D, > 0) of an object's pixels."""
    if units.size < min_px:
        return None
    vals, counts = readings(units, depth_scale, np.float64)
    hist, edges = histogram(vals, counts, max(1, int((vals[-1] - vals[0]) / level_m) + 1))
    near = hist.copy()  # a level may straddle two bins: count three at a time
    near[1:] += hist[:-1]
    near[:-1] += hist[1:]
    i = int(np.argmax(near >= max(min_px, share * units.size)))  # near[argmax of hist] always qualifies
    lo, hi = edges[max(i - 1, 0)], edges[min(i + 2, hist.size)]
    at_level = (vals >= lo) & (vals <= hi)
    level = median(vals[at_level], counts[at_level])
    close = np.abs(vals - level) <= 2 * level_m
    return percentile_25(vals[close], counts[close])


def grasp_depth(units: np.ndarray, ys: np.ndarray, xs: np.ndarray, cx: float, cy: float, area: int,
                depth_scale: float, cfg: GraspConfig) -> float | None:
    """The surface the tool meets at the centroid: the nearer of the object's top (from all its
    own pixels) and the surface near its centroid (within `centre_fraction`, then twice that, of
    its equivalent radius). A disk's centroid lands on its raised hub, nearer than the friction
    ring, whose shiny top may leave few depth pixels; a ring's centroid falls in its hole, where a
    mask that covers the hole sees the table, farther than the ring. UNITS: the readings of the
    object's pixels that have one, at rows YS and columns XS."""
    top = readings_depth(units, depth_scale, cfg.min_depth_px)
    r2 = (xs - cx) ** 2 + (ys - cy) ** 2
    for fraction in (cfg.centre_fraction, 2 * cfg.centre_fraction):
        z = readings_depth(units[r2 <= fraction ** 2 * area / math.pi], depth_scale, cfg.min_depth_px)
        if z is not None:
            return z if top is None else min(z, top)
    return top


def top_pixels(units: np.ndarray, ys: np.ndarray, xs: np.ndarray, shape: tuple[int, int], z_top: float,
               depth_scale: float, cfg: GraspConfig) -> np.ndarray | None:
    """The object's top face, as its own pixels whose depth lies within cfg.top_tolerance_m of its
    top Z_TOP (bool mask of SHAPE), or None when too few have depth (UNITS, YS, XS as grasp_depth
    takes them). Seen off the optical axis a tall object shows side walls on the side facing the
    principal point, which pull the silhouette's centroid towards it (a 10 cm box 200 px off-axis
    at 0.7 m: ~10 px, 16 mm) and skew its axis. Groups of those pixels apart from the rest
    (cfg.stray_gap_px) and small (cfg.stray_share) are left out: a mask that spills onto a
    neighbour whose top lies at the same height would stretch the face to it."""
    near = near_level(units, depth_scale, z_top, cfg.top_tolerance_m)
    if np.count_nonzero(near) < cfg.min_depth_px:
        return None
    top = np.zeros(shape, bool)
    top[ys[near], xs[near]] = True
    k = cfg.stray_gap_px
    n, groups = cv2.connectedComponents(cv2.dilate(top.view(np.uint8), np.ones((k, k), np.uint8)), connectivity=8)
    if n > 2:
        counts = np.bincount(groups[top], minlength=n)
        top &= np.isin(groups, np.flatnonzero((counts >= cfg.stray_share * counts.sum()) | (counts == counts.max())))
    return top


def hull_mask(pixels: np.ndarray) -> np.ndarray:
    """The filled convex hull of PIXELS (uint8 0/1): it bridges the depth holes of a shiny top and
    a ring's bore."""
    hull = cv2.convexHull(row_ends(pixels))
    return cv2.fillConvexPoly(np.zeros(pixels.shape, np.uint8), hull, 1)


def top_down_pose(cal: Calibration, intr: Intrinsics, cx: float, cy: float, z: float, angle_deg: float,
                  defined: bool) -> list[float]:
    """[x, y, z, rx, ry, rz] in the robot base frame: tool z straight down, tool x (finger closing)
    across the object, i.e. along its minor axis, measured in the robot frame."""
    p_cam = deproject(intr, cx, cy, z)
    p_rob = cal.apply(p_cam)
    if defined:
        a = math.radians(angle_deg)
        step = 5.0  # pixels along the minor axis, at the object's depth
        q_cam = deproject(intr, cx - step * math.sin(a), cy + step * math.cos(a), z)
        d = cal.R @ (q_cam - p_cam)
        phi = math.atan2(d[1], d[0])
    else:
        phi = 0.0  # round object: yaw is free
    phi = (phi + math.pi / 2) % math.pi - math.pi / 2  # a two-finger grasp is symmetric under 180 deg
    # Rotation [x, y, z] with x = (cos phi, sin phi, 0), z = (0, 0, -1): a half turn about
    # the horizontal axis at phi/2, so its rotation vector is pi * (cos phi/2, sin phi/2, 0).
    rot = [math.pi * math.cos(phi / 2), math.pi * math.sin(phi / 2), 0.0]
    return [round(float(v), 6) for v in (*p_rob, *rot)]


def grasp_records(labels: np.ndarray, depth: np.ndarray, intr: Intrinsics, classes: list[str] | tuple[str, ...] =
                  DEFAULT_CLASSES, calib: Calibration | None = None, cfg: GraspConfig | None = None,
                  laps: Laps | None = None) -> list[Grasp]:
    """One Grasp per object region (docs/contracts.md#grasp-record), largest first. LAPS, when
    given, adds up the time of each sub-step."""
    cfg = cfg or GraspConfig()
    if len(set(classes)) != len(classes):  # two ids of one name: which object a record names would be a guess
        twice = next(n for n in classes if list(classes).count(n) > 1)
        raise ParameterError(f"{{classes}}: names {twice!r} twice; each class id needs its own name",
                             classes=list(classes))
    lap: Callable[[str], None] = _no_lap
    if laps is not None:
        laps.start()
        lap = laps
    if labels.shape != depth.shape:
        raise EdgepickError(f"label image {labels.shape[::-1]} and depth {depth.shape[::-1]} differ in size")
    if (labels.shape[1], labels.shape[0]) != (intr.width, intr.height):
        raise EdgepickError(f"image size {labels.shape[1]}x{labels.shape[0]} differs from the intrinsics "
                            f"{intr.width}x{intr.height}")
    records = []
    masks = filter_class_masks(labels, len(classes), cfg)
    lap("filters")
    for c, (ox, oy, mask) in masks.items():
        n, comp, sizes = components(mask)
        for k in np.flatnonzero(sizes[1:] >= cfg.min_area_px) + 1:
            # work on the region's bounding box, not the whole frame (this runs every frame)
            x, y, w, h = cv2.boundingRect((comp == k).view(np.uint8))
            region = (comp[y:y + h, x:x + w] == k).view(np.uint8)
            background = labels[y + oy:y + oy + h, x + ox:x + ox + w] == 0
            lap("regions")
            parts = split_touching(region, cfg, background, depth[y + oy:y + oy + h, x + ox:x + ox + w], intr.depth_scale)
            lap("splits")
            for part in parts:
                grasp = _grasp(part, x + ox, y + oy, c, labels, depth, intr, classes, calib, cfg, lap)
                if grasp is not None:
                    records.append(grasp)
                lap("regions")
    records.sort(key=lambda r: -r.area_px)
    return records


def _grasp(region: np.ndarray, x: int, y: int, c: int, labels: np.ndarray, depth: np.ndarray, intr: Intrinsics,
           classes, calib: Calibration | None, cfg: GraspConfig, lap: Callable[[str], None] = _no_lap) -> Grasp | None:
    """The grasp of one object's mask REGION, whose top left is frame pixel (x, y)."""
    h, w = region.shape
    if cv2.countNonZero(region) < cfg.min_area_px:
        return None
    cx, cy, angle, defined, area = moments_pose(region, cfg.round_ratio)
    lap("moments")
    own = (labels[y:y + h, x:x + w] == c) & (region > 0)  # unfiltered pixels: not the dilated rim
    ys, xs = np.nonzero(own & (depth[y:y + h, x:x + w] > 0))  # those with a reading, for depth and top face
    units = depth[y:y + h, x:x + w][ys, xs]
    z = grasp_depth(units, ys, xs, cx, cy, area, intr.depth_scale, cfg)
    lap("depth")
    pixels = None if z is None else top_pixels(units, ys, xs, own.shape, z, intr.depth_scale, cfg)
    hull = None
    if pixels is not None:  # the grasp point and axis of the top face, not of the silhouette with its walls
        hull = hull_mask(pixels)
        cx, cy, angle, defined, _ = moments_pose(hull, cfg.round_ratio)
        # the axis counts the top's blobs with no depth reading as top: a black adapter may return
        # depth on a third of its top, whose hull is no longer its shape (not for the centroid: a
        # disk's shiny friction ring would pull that of its raised hub)
        if defined:
            holes = depth_holes(own, depth[y:y + h, x:x + w])
            fill, axis = rect_fill_and_axis(hull_mask(pixels | (holes > 0)) if holes.any() else hull)
            angle = axis if fill >= cfg.rect_fill else angle
    lap("top face")
    cx, cy = cx + x, cy + y
    depth_m: float | None = None
    point: tuple[float, ...] | None = None
    pose: tuple[float, ...] | None = None
    width: float | None = None
    occluded = 0.0
    if z is not None:
        depth_m, point = round(z, 5), tuple(round(float(v), 5) for v in deproject(intr, cx, cy, z))
        width = minor_width_m(own, angle, z, intr) if defined else None
        pose = tuple(top_down_pose(calib, intr, cx, cy, z, angle, defined)) if calib is not None else None
        lap("3d")
        occluded = occluded_fraction(region, labels[y:y + h, x:x + w], depth[y:y + h, x:x + w], z, intr.depth_scale,
                                     own=own)
        lap("occlusion")
    # cut by the image border: its centroid is that of the part in view, unless the grasp point is that of a raised
    # top face wholly in view (a brake disk's hub, its ring cut)
    partial = border_contact(region, x, y, labels.shape) >= cfg.partial_contact * math.sqrt(area) and \
        not (hull is not None and raised_face_in_view(hull, region, np.where(own, depth[y:y + h, x:x + w], 0) *
                                                          intr.depth_scale, x, y, labels.shape, area))
    return Grasp(classes[c], (round(cx, 2), round(cy, 2)), angle, defined, area, depth_m, point, pose, occluded,
                 partial, None if z is not None else NO_DEPTH, width)


def raised_face_in_view(face: np.ndarray, region: np.ndarray, own_depth_m: np.ndarray, x: int, y: int,
                        frame_hw: tuple[int, int], area: int) -> bool:
    """Whether FACE (a top face's filled hull in REGION's frame, their top left at frame pixel (x, y))
    is the raised centre of a level object of AREA pixels, wholly in view: RAISED_FACE_SHARE of it
    at most; every face pixel 0.1 x the square root of AREA or more inside the object's outline,
    and the object's own readings farther out than that (OWN_DEPTH_M, metres, 0: none) within
    LEVEL_M of each other (a hub on a ring that lies flat, not the high edge of a tilted part); and
    farther than that and 4% of the frame's width from every frame edge (a D415 has no depth in a
    band at its left edge, where a face may seem to end for want of readings)."""
    ys, xs = np.nonzero(face)
    if not len(xs) or len(xs) > RAISED_FACE_SHARE * area:
        return False
    inset = 0.1 * math.sqrt(area)
    if min(x + xs.min(), y + ys.min(), frame_hw[1] - 1 - (x + xs.max()), frame_hw[0] - 1 - (y + ys.max())) < \
            max(inset, 0.04 * frame_hw[1]):
        return False
    outline = np.zeros((region.shape[0] + 2, region.shape[1] + 2), np.uint8)  # a pixel of background around it
    contours, _ = cv2.findContours(np.ascontiguousarray(region), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    cv2.drawContours(outline, contours, -1, 1, -1, offset=(1, 1))
    if cv2.distanceTransform(outline, cv2.DIST_L2, 5)[1:-1, 1:-1][ys, xs].min() < inset:
        return False
    k = 2 * int(inset) + 1
    ring = own_depth_m[(cv2.dilate(face.view(np.uint8), np.ones((k, k), np.uint8)) == 0) & (own_depth_m > 0)]
    return bool(ring.size and np.percentile(ring, 90) - np.percentile(ring, 10) <= LEVEL_M)


def minor_width_m(pixels: np.ndarray, angle_deg: float, z: float, intr: Intrinsics) -> float | None:
    """The extent of PIXELS (the object's own mask) across the major axis at ANGLE_DEG, in metres at
    depth Z: the width the jaw closes on, seen from above (side walls in view only widen it). None
    for an empty mask."""
    ys, xs = np.nonzero(pixels)
    if not len(xs):
        return None
    a = math.radians(angle_deg)
    across = ys * math.cos(a) - xs * math.sin(a)  # along the minor axis, (-sin a, cos a) in the image
    metres_per_px = z * math.hypot(math.sin(a) / intr.fx, math.cos(a) / intr.fy)
    return round(float(across.max() - across.min() + 1) * metres_per_px, 4)


def occluded_fraction(region: np.ndarray, labels: np.ndarray, depth: np.ndarray, z: float, depth_scale: float,
                      step_m: float = 0.005, own: np.ndarray | None = None) -> float:
    """Share of the region's rim where another object lies nearer the camera than this one (by
    STEP_M): an object partly under another, whose visible centroid is not its own, or one that
    carries another (lifting it would drop what lies on it). Nearer than its top (Z), or, with OWN
    (its own pixels), than its own surface beside the rim: a part lying on a brake disk's low ring
    stands no higher than the hub the grasp point is on, but well above the ring it lies on."""
    ys, xs = np.nonzero(cv2.dilate(region, np.ones((5, 5), np.uint8)) > region)  # the rim
    if ys.size == 0:
        return 0.0
    d = depth[ys, xs]
    missing = (d == 0) & (labels[ys, xs] != 0)
    if missing.any():  # a shiny neighbour (a steel bearing) returns depth on few pixels: its nearest reading close by
        mine = own if own is not None else region > 0
        far = np.iinfo(depth.dtype).max if depth.dtype.kind in "ui" else np.inf
        others = np.where((labels != 0) & (depth > 0) & ~mine, depth, far).astype(depth.dtype)
        nearest = cv2.erode(others, np.ones((2 * NEIGHBOUR_READING_PX + 1,) * 2, np.uint8))[ys[missing], xs[missing]]
        d = d.copy()
        d[missing] = np.where(nearest < far, nearest, 0)
    surface = np.full(ys.size, z)
    if own is not None and (own & (depth > 0)).any():
        # the mean of its own readings within 5 px, of those no more than OWN_SURFACE_M beyond its median one: the
        # surface a neighbour rests on there (a disk's ring), not a side wall's foot or a mask spilling onto the table
        read = own & (depth > 0)
        read = (read & (depth <= np.median(depth[read]) + OWN_SURFACE_M / depth_scale)).astype(np.float32)
        total = cv2.boxFilter(np.where(read > 0, depth, 0).astype(np.float32), -1, (11, 11), normalize=False)[ys, xs]
        count = cv2.boxFilter(read, -1, (11, 11), normalize=False)[ys, xs]
        surface = np.maximum(surface, np.divide(total, count, out=np.zeros_like(total), where=count > 0) * depth_scale)
    above = (labels[ys, xs] != 0) & (d > 0) & (d * depth_scale < surface - step_m)
    return round(int(above.sum()) / ys.size, 3)


def draw_overlay(rgb_or_labels: np.ndarray, records: list[Grasp], finger_px: float = 30.0) -> np.ndarray:
    """BGR picture with each record's centroid, major axis and finger positions."""
    img = rgb_or_labels
    if img.ndim == 2:
        img = cv2.applyColorMap((img.astype(np.uint16) * 50 % 256).astype(np.uint8), cv2.COLORMAP_JET)
    else:
        img = img[..., ::-1].copy()
    for r in records:
        cx, cy = r.pixel
        c = (int(round(cx)), int(round(cy)))
        cv2.drawMarker(img, c, (255, 255, 255), cv2.MARKER_CROSS, 14, 2)
        a = math.radians(r.angle_deg)
        if r.orientation_defined:
            d = (math.cos(a) * 40, math.sin(a) * 40)
            cv2.line(img, (int(cx - d[0]), int(cy - d[1])), (int(cx + d[0]), int(cy + d[1])), (0, 255, 255), 1,
                     cv2.LINE_AA)
        f = (-math.sin(a) * finger_px, math.cos(a) * finger_px)  # fingers close along the minor axis
        for s in (-1, 1):
            cv2.circle(img, (int(cx + s * f[0]), int(cy + s * f[1])), 4, (0, 0, 255), -1)
        cv2.putText(img, r.cls, (c[0] + 8, c[1] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1,
                    cv2.LINE_AA)
    return img
