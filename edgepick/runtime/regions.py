"""One class region -> one mask per object (docs/contracts.md#grasp-record): touching objects of one
class form one connected region, split here at holes, at flat faces of different heights, at the
notches of a seam, or at distance-transform cores. numpy + OpenCV only."""

from __future__ import annotations

import math

import cv2
import numpy as np

from edgepick.runtime.grasp_config import GraspConfig
from edgepick.runtime.readings import histogram, readings


def split_touching(region: np.ndarray, cfg: GraspConfig, background: np.ndarray | None = None,
                   depth: np.ndarray | None = None, depth_scale: float = 0.001) -> list[np.ndarray]:
    """One class region -> one mask per object. Touching objects of one class (two bearings side by
    side) form one connected region whose centroid lies between them. Seeds: the region's holes when
    it has two or more (rings: one hole each; a hole is BACKGROUND, the table, enclosed by the region
    and other objects lying on it), else its top faces at different heights (DEPTH, the camera's
    readings, DEPTH_SCALE metres each: two boxes of different heights side by side); a region with
    holes but not two large ones is one ring (a disk whose rim other objects cover in places, with
    its bolt holes) and goes no further; else the two sides of a cut between the two deepest
    notches of its outline (two boxes side by side at one height), else its cores, the pixels
    farther than cfg.split_core x the region's largest distance from its edge. Each pixel goes to
    its nearest seed; a region with one seed is returned as it is."""
    holes = _holes(region, cfg, background)
    hole_area = sum(cv2.countNonZero(h) for h in holes)
    seeds = [h for h in holes if cv2.countNonZero(h) >= cfg.split_min_share * hole_area]
    if depth is not None and len(seeds) < 2:
        seeds = _top_faces(region, depth, depth_scale, cfg)
    if len(seeds) < 2 and not holes:
        seeds = _notch_cut(region, cfg, depth, depth_scale)
    if len(seeds) < 2 and not holes:
        dist = _edge_distance(region)
        seeds = _components((dist > cfg.split_core * dist.max()).view(np.uint8), cfg) if dist.max() > 0 else []
    if len(seeds) < 2:
        return [region]
    to_seed = np.stack([cv2.distanceTransform(1 - seed, cv2.DIST_L2, 3) for seed in seeds])
    nearest = np.argmin(to_seed, axis=0)
    return [((nearest == i) & (region > 0)).view(np.uint8) for i in range(len(seeds))]


def _top_faces(region: np.ndarray, depth: np.ndarray, depth_scale: float, cfg: GraspConfig) -> list[np.ndarray]:
    """Flat faces of the region at different heights: for each peak of its depth histogram holding
    cfg.split_min_share of its depth pixels, the connected parts at that depth that are large and
    compact (cfg.face_compactness: a side wall seen at an angle is a long, thin band). Two faces
    each of whose centroid lies in the other's convex hull are one object (a disk's hub inside its
    friction ring); faces left apart are objects side by side or one on another (two boxes of
    different heights)."""
    inside = (region > 0) & (depth > 0)
    vals, found = readings(depth[inside], depth_scale, np.float32)  # the readings in metres, once each
    total = int(found.sum())
    if total < cfg.min_depth_px:
        return []
    tol = cfg.top_tolerance_m
    counts, edges = histogram(vals, found, max(1, int((vals[-1] - vals[0]) / (tol / 2)) + 1))
    near = counts.copy()  # a level may straddle two bins: count three at a time
    near[1:] += counts[:-1]
    near[:-1] += counts[1:]
    faces: list[np.ndarray] = []
    holes = None
    for i in map(int, np.flatnonzero(near >= cfg.split_min_share * total)):
        if (i > 0 and counts[i - 1] > counts[i]) or (i + 1 < counts.size and counts[i + 1] >= counts[i]):
            continue  # not a peak
        level = (edges[i] + edges[i + 1]) / 2
        at = cv2.morphologyEx((inside & near_level(depth, depth_scale, level, tol)).view(np.uint8), cv2.MORPH_CLOSE,
                              np.ones((5, 5), np.uint8))  # bridge depth holes
        # blobs with no depth (shiny metal, a black part) join the parts they lie between: one
        # object's top broken by depth holes is one face; two objects at one height, with the table
        # between them, are two.
        holes = depth_holes(region, depth) if holes is None else holes
        n, comp, sizes = components(at | holes)
        least = cfg.split_min_share * cv2.countNonZero(region)
        for k in np.flatnonzero(sizes[1:] >= least) + 1:  # a smaller part holds fewer face pixels
            part = (comp == k).view(np.uint8)
            face = part & at
            if cv2.countNonZero(face) >= least and sizes[k] <= cfg.face_compactness * float(_edge_distance(part).max()) ** 2:
                faces.append(face)
    groups: list[list[int]] = []
    for i in range(len(faces)):
        joined = [g for g in groups if any(_nested(faces[i], faces[j]) for j in g)]
        groups = [g for g in groups if g not in joined] + [[i] + [j for g in joined for j in g]]
    return [np.bitwise_or.reduce([faces[j] for j in g]) for g in groups] if len(groups) > 1 else []


def components(mask: np.ndarray, connectivity: int = 8) -> tuple[int, np.ndarray, np.ndarray]:
    """(count, labels, pixels per label) of MASK's connected components: connectedComponentsWithStats's
    labels and areas, at a third of its cost (OpenCV's per-label statistics cost more than the labelling)."""
    n, comp = cv2.connectedComponents(mask, connectivity=connectivity)
    return n, comp, np.bincount(comp.ravel(), minlength=n)


def near_level(depth: np.ndarray, depth_scale: float, level: float, tolerance: float) -> np.ndarray:
    """Whether each integer depth reading of DEPTH (an image or a 1-D array) lies within TOLERANCE
    metres of LEVEL, as `np.abs(depth.astype(np.float32) * depth_scale - level) <= tolerance` says,
    worked once per possible reading and looked up per pixel."""
    within = np.abs(np.arange(int(depth.max()) + 1, dtype=np.float32) * depth_scale - level) <= tolerance
    return within[depth]


def depth_holes(mask: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """MASK's pixels with no depth reading, in blobs of 5x5 or more (uint8 0/1): the holes a shiny
    or black surface leaves, not the thin lines of missing depth along every object's outline."""
    return cv2.morphologyEx(((mask > 0) & (depth <= 0)).view(np.uint8), cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))


def row_ends(mask: np.ndarray) -> np.ndarray:
    """The leftmost and rightmost pixel of each row of MASK (bool or 0/1) that has one (Nx1x2 int32,
    in raster order as cv2.findNonZero lists them): every vertex of the convex hull of MASK's pixels
    is one of them, so a hull or a minimum-area rectangle made from them is the one all the pixels
    make (the same vertices from the same start, hence the same rectangle where two tie), at a
    fraction of the cost of listing every pixel or tracing the blobs' outlines."""
    on = mask.view(bool)
    rows = np.flatnonzero(on.any(axis=1))
    on = on[rows]
    ends = np.empty((rows.size, 2, 2), np.int32)
    ends[:, 0, 0] = on.argmax(axis=1)
    ends[:, 1, 0] = mask.shape[1] - 1 - on[:, ::-1].argmax(axis=1)
    ends[:, :, 1] = rows[:, None]
    points = ends.reshape(-1, 2)
    single = np.zeros(len(points), bool)  # a row with one pixel lists it once
    single[1::2] = points[1::2, 0] == points[0::2, 0]
    return points[~single].reshape(-1, 1, 2)


def _nested(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether each mask's centroid lies in the other's convex hull (concentric parts of one object)."""
    for one, other in ((a, b), (b, a)):
        m = cv2.moments(one, binaryImage=True)
        hull = cv2.convexHull(row_ends(other))
        if cv2.pointPolygonTest(hull, (m["m10"] / m["m00"], m["m01"] / m["m00"]), False) < 0:
            return False
    return True


def _notch_cut(region: np.ndarray, cfg: GraspConfig, depth: np.ndarray | None = None,
               depth_scale: float = 0.001) -> list[np.ndarray]:
    """Two convex objects side by side at one height (boxes, adapters) leave a notch on each side
    of their seam: cut the region along the line between its two deepest notches (convexity defects
    deeper than cfg.notch_depth x the square root of its area) when each side holds cfg.split_min_part
    of it or more and is convex (cfg.split_solidity). A model's mask rounds the corners at a seam, so
    when both notches are deep (cfg.deep_notch) and open onto the table (DEPTH, readings of
    DEPTH_SCALE metres: farther than the region, not an object lying over its rim) the sides need
    only be nearly convex (cfg.split_solidity_deep). Returns the two sides, or [] when there is no
    such cut."""
    contours, _ = cv2.findContours(region, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return []
    contour = max(contours, key=cv2.contourArea)
    hull = cv2.convexHull(contour, returnPoints=False)
    if len(hull) < 4 or len(contour) < 8:
        return []
    try:
        defects = cv2.convexityDefects(contour, np.sort(hull, axis=0))
    except cv2.error:  # a self-touching outline
        return []
    if defects is None:
        return []
    area = cv2.countNonZero(region)
    defects = defects.reshape(-1, 4)
    deep = defects[defects[:, 3] / 256.0 > cfg.notch_depth * math.sqrt(area)]  # depths are fixed-point, 8 bits
    if len(deep) < 2:
        return []
    two = deep[np.argsort(-deep[:, 3])[:2]]
    p, q = (tuple(int(v) for v in contour[i, 0]) for i in two[:, 2])
    cut = region.copy()
    cv2.line(cut, p, q, 0, 2)
    n, comp, sizes = components(cut, connectivity=4)
    sides = [(comp == k).view(np.uint8) for k in range(1, n) if sizes[k] >= cfg.split_min_part * area]
    convex = cfg.split_solidity
    if two[:, 3].min() / 256.0 > cfg.deep_notch * math.sqrt(area) and depth is not None and \
            all(_opens_onto_table(region, contour, d, depth, depth_scale, cfg) for d in two):
        convex = cfg.split_solidity_deep
    return sides if len(sides) == 2 and all(_solidity(side) >= convex for side in sides) else []


def _opens_onto_table(region: np.ndarray, contour: np.ndarray, defect: np.ndarray, depth: np.ndarray,
                      depth_scale: float, cfg: GraspConfig, below_m: float = 0.01) -> bool:
    """Whether the notch of DEFECT (start, end, deepest point, depth) shows a surface at least
    BELOW_M farther from the camera than the region's own: the table between two objects, not an
    object lying over the region's rim."""
    start, end = int(defect[0]), int(defect[1])
    arc = contour[start:end + 1] if start <= end else np.concatenate([contour[start:], contour[:end + 1]])
    pocket = cv2.fillPoly(np.zeros(region.shape, np.uint8), [arc], 1).astype(bool) & (region == 0) & (depth > 0)
    own = (region > 0) & (depth > 0)
    if pocket.sum() < cfg.min_depth_px or own.sum() < cfg.min_depth_px:
        return False
    metres = [np.median(depth[pixels].astype(np.float32) * depth_scale) for pixels in (pocket, own)]
    return float(metres[0]) > float(metres[1]) + below_m


def _solidity(mask: np.ndarray) -> float:
    """Pixel count over the area of the convex hull of the mask's outline (~1.0 when convex)."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    hull = cv2.convexHull(max(contours, key=cv2.contourArea))
    return cv2.countNonZero(mask) / max(1.0, cv2.contourArea(hull))


def _edge_distance(mask: np.ndarray) -> np.ndarray:
    """Each pixel's distance to the nearest pixel outside MASK, the crop's border counting as
    outside (a region is worked on its bounding box, which it touches on every side)."""
    return cv2.distanceTransform(cv2.copyMakeBorder(mask, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0), cv2.DIST_L2,
                                 5)[1:-1, 1:-1]


def _components(mask: np.ndarray, cfg: GraspConfig) -> list[np.ndarray]:
    """The connected components of MASK that hold cfg.split_min_share of its area or more."""
    n, comp, sizes = components(mask)
    areas = sizes[1:]
    return [(comp == k + 1).view(np.uint8) for k in np.flatnonzero(areas >= cfg.split_min_share * areas.sum())] \
        if n > 2 else []


def _holes(region: np.ndarray, cfg: GraspConfig, background: np.ndarray | None) -> list[np.ndarray]:
    """The region's holes: table pixels (BACKGROUND; without it, all non-region pixels) not connected
    to its bounding box's edge, large ones only, and ringed mostly (cfg.hole_rim share) by the region
    itself: a ring's bore, even with an object lying across it, but not a pocket of table closed
    off by a box and the objects lying around it. One mask per hole, in the region's frame."""
    free = (region == 0) if background is None else (background & (region == 0))
    outside = cv2.copyMakeBorder(free.view(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=1)
    n, comp, sizes = components(outside, connectivity=4)
    if n <= 2:
        return []
    edge, padded = comp[0, 0], cv2.copyMakeBorder(region, 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    holes = []
    for k in range(1, n):
        if k == edge or sizes[k] < 20:
            continue
        hole = (comp == k).view(np.uint8)
        rim = (cv2.dilate(hole, np.ones((3, 3), np.uint8)) > 0) & (hole == 0)
        if padded[rim].mean() >= cfg.hole_rim:
            holes.append(k)
    return [(comp == k).view(np.uint8)[1:-1, 1:-1] for k in holes]
