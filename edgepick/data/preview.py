"""`edgepick data preview`: a contact sheet of scenes with mask overlays, grasp truth and depth."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from edgepick.data.config import Split
from edgepick.data.native import NativeDataset
from edgepick.errors import EdgepickError
from edgepick.files import atomic_path

# BGR colours per class id (background uncoloured)
PALETTE = np.array([[0, 0, 0], [255, 80, 40], [40, 200, 255], [60, 220, 60], [200, 60, 220],
                    [0, 140, 255], [255, 255, 0], [128, 128, 255]], np.uint8)


def draw_tile(rgb: np.ndarray, mask: np.ndarray, depth: np.ndarray | None, grasps: list[dict]) -> np.ndarray:
    """One tile: RGB with translucent class colours, contours and grasp axes; depth beside it."""
    bgr = rgb[..., ::-1].copy()
    colour = PALETTE[mask % len(PALETTE)]
    obj = mask > 0
    bgr[obj] = (0.55 * bgr[obj] + 0.45 * colour[obj]).astype(np.uint8)
    for c in np.unique(mask[mask > 0]):
        contours, _ = cv2.findContours((mask == c).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(bgr, contours, -1, tuple(int(v) for v in PALETTE[c % len(PALETTE)]), 1)
    for g in grasps:
        u, v = g["pixel"]
        cv2.drawMarker(bgr, (int(round(u)), int(round(v))), (255, 255, 255), cv2.MARKER_CROSS, 12, 2)
        if g.get("orientation_defined", True):
            a = np.deg2rad(g["angle_deg"])
            d = 25 * np.array([np.cos(a), np.sin(a)])
            p0, p1 = (int(u - d[0]), int(v - d[1])), (int(u + d[0]), int(v + d[1]))
            cv2.line(bgr, p0, p1, (255, 255, 255), 1, cv2.LINE_AA)
    if depth is None:
        return bgr
    valid = depth > 0
    lo, hi = (np.percentile(depth[valid], [2, 98]) if valid.any() else (0, 1))
    d8 = np.clip((depth.astype(np.float32) - lo) / max(hi - lo, 1) * 255, 0, 255).astype(np.uint8)
    dv = cv2.applyColorMap(255 - d8, cv2.COLORMAP_TURBO)
    dv[~valid] = 0
    return np.hstack([bgr, dv])


def contact_sheet(data: str | Path, out: str | Path, split: Split = Split.TRAIN, count: int = 12, cols: int = 3,
                  tile_width: int = 640) -> int:
    """Write a PNG contact sheet of the first COUNT scenes; returns the number drawn."""
    ds = NativeDataset.open(data, split)
    grasps = ds.grasps()
    tiles = []
    for sid in ds.ids[:count]:
        tile = draw_tile(ds.rgb(sid), ds.mask(sid), ds.depth(sid), grasps.get(sid, []))
        scale = tile_width / tile.shape[1]
        tile = cv2.resize(tile, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
        cv2.putText(tile, sid, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(tile)
    while len(tiles) % cols:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.hstack(tiles[i:i + cols]) for i in range(0, len(tiles), cols)]
    with atomic_path(out) as tmp:
        if not cv2.imwrite(str(tmp), np.vstack(rows)):
            raise EdgepickError(f"cannot write {out}")
    return len(ds.ids[:count])
