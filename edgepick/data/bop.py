"""BOP scene files (scene_gt.json, scene_camera.json) read and checked for `edgepick data import bop`.

Every field the importer uses is checked here, before any image is converted, so a malformed
scene ends as one line naming the file and the field, never as a traceback or a data set built
on a NaN depth scale (docs/contracts.md#data-set-layout for what the import writes).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from edgepick.geometry import DEPTH_SCALE_MAX_M, DEPTH_SCALE_MIN_M
from edgepick.schema import Where, as_dict, as_list, as_number, as_numbers, field, read_json

# LineMOD's object names by object id (1-based); other data sets' objects are named obj_<id>.
LINEMOD_NAMES = ["ape", "benchvise", "bowl", "cam", "can", "cat", "cup", "driller", "duck", "eggbox", "glue",
                 "holepuncher", "iron", "lamp", "phone"]
K_TOLERANCE = 1e-6  # how far cam_K's last row may be from 0, 0, 1


@dataclass(frozen=True)
class BopImage:
    """One image of a BOP scene: its id, the object id of each ground-truth entry (in the order of
    the mask_visib files), the camera matrix row by row and the depth scale in mm per unit."""

    scene: Path
    im: int
    obj_ids: list[int]
    cam_K: list[float]
    depth_scale: float


def object_name(obj_id: int) -> str:
    """The class name of a BOP object id: LineMOD's names, obj_<id> beyond them."""
    return LINEMOD_NAMES[obj_id - 1] if 1 <= obj_id <= len(LINEMOD_NAMES) else f"obj_{obj_id:06d}"


def bop_scenes(src: Path) -> list[Path]:
    """Scene folders (with scene_gt.json) under a BOP split folder, or a data set root."""
    if (src / "scene_gt.json").is_file():
        return [src]
    scenes = sorted(p.parent for p in src.glob("*/scene_gt.json"))
    return scenes or sorted(p.parent for p in src.glob("*/*/scene_gt.json"))


def _camera(cams: dict, key: str, cam_file: Path) -> tuple[list[float], float]:
    """cam_K (nine finite numbers, positive focal lengths, last row 0 0 1) and depth_scale (> 0)."""
    where = Where(str(cam_file), f"image {key}")
    if key not in cams:
        Where(str(cam_file)).fail(f"has no entry for image {key}, which scene_gt.json lists")
    cam = as_dict(cams[key], where)
    K = [float(v) for v in as_numbers(field(cam, "cam_K", where), where.at("cam_K"), 9)]
    if K[0] <= 0 or K[4] <= 0:
        where.at("cam_K").fail(f"must have positive focal lengths, got fx {K[0]} and fy {K[4]}")
    if max(abs(a - b) for a, b in zip(K[6:], (0.0, 0.0, 1.0))) > K_TOLERANCE:
        where.at("cam_K").fail(f"must be the 3x3 matrix row by row, [fx, 0, cx, 0, fy, cy, 0, 0, 1]; its last "
                               f"row is {K[6:]}")
    scale = float(as_number(field(cam, "depth_scale", where, 1.0), where.at("depth_scale"), above=0))
    low, high = DEPTH_SCALE_MIN_M * 1000, DEPTH_SCALE_MAX_M * 1000  # any depth scale's bounds, in BOP's millimetres
    if not low <= scale <= high:
        where.at("depth_scale").fail(f"must be in [{low:g}, {high:g}] millimetres per depth unit, got {scale!r}")
    return K, scale


def read_scene(scene: Path) -> list[BopImage]:
    """The images of one scene folder, from scene_gt.json (image id -> list of objects with obj_id)
    and scene_camera.json (image id -> cam_K, depth_scale), every field checked."""
    gt_file, cam_file = scene / "scene_gt.json", scene / "scene_camera.json"
    gt = as_dict(read_json(gt_file, "BOP ground truth"), Where(str(gt_file)))
    cams = as_dict(read_json(cam_file, "BOP camera file"), Where(str(cam_file)))
    images: list[BopImage] = []
    seen: dict[int, str] = {}
    for key, objs in gt.items():
        if not re.fullmatch(r"[0-9]+", key):
            Where(str(gt_file)).fail(f"image id {key!r} must be a whole number (BOP writes \"0\", \"1\", ...)")
        im = int(key)
        if im in seen:
            Where(str(gt_file)).fail(f"lists image {im} twice, as {seen[im]!r} and {key!r}")
        seen[im] = key
        where = Where(str(gt_file), f"image {key}")
        obj_ids = []
        for k, obj in enumerate(as_list(objs, where)):
            obj = as_dict(obj, where.at(k))
            obj_ids.append(int(as_number(field(obj, "obj_id", where.at(k)), where.at(k).at("obj_id"), integer=True,
                                         minimum=1)))
        K, scale = _camera(cams, key, cam_file)
        images.append(BopImage(scene, im, obj_ids, K, scale))
    return images
