"""`edgepick data import FORMAT SRC OUT`: Cityscapes, BOP (LineMOD) and CVAT segmentation
exports converted into the native layout (docs/contracts.md#data-set-layout), so train/quantize/bench take them.

Everything is checked while converting; the output goes to a temporary folder beside OUT
that is renamed into place at the end, so a malformed tree leaves nothing half-imported.
numpy + OpenCV only.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from edgepick.data.native import IGNORE, SPLITS, atomic_folder
from edgepick.errors import DatasetError
from edgepick.geometry import Intrinsics

FORMATS = ("cityscapes", "bop", "cvat")

# Cityscapes label ids (cityscapesScripts' labels.py): name, id, train id (255 = not trained).
CITYSCAPES = [
    ("unlabeled", 0, 255), ("ego vehicle", 1, 255), ("rectification border", 2, 255), ("out of roi", 3, 255),
    ("static", 4, 255), ("dynamic", 5, 255), ("ground", 6, 255), ("road", 7, 0), ("sidewalk", 8, 1),
    ("parking", 9, 255), ("rail track", 10, 255), ("building", 11, 2), ("wall", 12, 3), ("fence", 13, 4),
    ("guard rail", 14, 255), ("bridge", 15, 255), ("tunnel", 16, 255), ("pole", 17, 5), ("polegroup", 18, 255),
    ("traffic light", 19, 6), ("traffic sign", 20, 7), ("vegetation", 21, 8), ("terrain", 22, 9), ("sky", 23, 10),
    ("person", 24, 11), ("rider", 25, 12), ("car", 26, 13), ("truck", 27, 14), ("bus", 28, 15),
    ("caravan", 29, 255), ("trailer", 30, 255), ("train", 31, 16), ("motorcycle", 32, 17), ("bicycle", 33, 18),
]
# The 30 classes of the Cityscapes benchmark are ids 4..33; ids 0..3 are outside the labelled area.
CITYSCAPES_30_FIRST_ID = 4
LINEMOD_NAMES = ["ape", "benchvise", "bowl", "cam", "can", "cat", "cup", "driller", "duck", "eggbox", "glue",
                 "holepuncher", "iron", "lamp", "phone"]


@dataclass
class ImportConfig:
    cityscapes_classes: str = "30"  # "30" (all benchmark classes) or "19" (the train ids)
    split_fractions: tuple[float, float, float] = (0.8, 0.1, 0.1)  # for sources without splits
    images: str | None = None  # CVAT: folder of the colour images (default SRC/JPEGImages)
    depth: str | None = None  # CVAT: folder of uint16 depth PNGs with the images' names
    intrinsics: str | None = None  # CVAT: intrinsics.json of the depth camera
    depth_scale_m: float = 0.001  # CVAT: metres per unit of the depth PNGs


class NativeWriter:
    """Writes scenes into an `atomic_folder` beside OUT: renamed into place at the end, removed on error."""

    def __init__(self, tmp: Path):
        self.tmp = tmp
        self.counts = dict.fromkeys(SPLITS, 0)
        self.has_depth = False

    def add(self, split: str, rgb: np.ndarray, mask: np.ndarray, depth_mm: np.ndarray | None, name: str) -> None:
        if rgb.shape[:2] != mask.shape or (depth_mm is not None and depth_mm.shape != mask.shape):
            raise DatasetError(f"{name}: image {rgb.shape[1]}x{rgb.shape[0]}, label {mask.shape[::-1]}"
                               + ("" if depth_mm is None else f" and depth {depth_mm.shape[::-1]}") + " differ in size")
        sid = f"{self.counts[split]:06d}"
        self.counts[split] += 1
        base = self.tmp / split
        for sub in ("rgb", "mask") + (("depth",) if depth_mm is not None else ()):
            (base / sub).mkdir(parents=True, exist_ok=True)
        ok = cv2.imwrite(str(base / "rgb" / f"{sid}.png"), rgb[..., ::-1])
        ok &= cv2.imwrite(str(base / "mask" / f"{sid}.png"), mask.astype(np.uint8))
        if depth_mm is not None:
            self.has_depth = True
            ok &= cv2.imwrite(str(base / "depth" / f"{sid}.png"), depth_mm)
        if not ok:
            raise OSError(f"could not write scene {split}/{sid}")
        with open(base / "sources.txt", "a") as f:  # which source file each scene came from
            f.write(f"{sid} {name}\n")

    def finish(self, classes: list[str], intrinsics: Intrinsics | None, source: dict) -> dict:
        """meta.json (classes, ignore index, intrinsics, where the data came from)."""
        empty = [s for s in SPLITS if self.counts[s] == 0]
        if empty:
            raise DatasetError(f"the source gives no images for the {', '.join(empty)} split(s)")
        meta = {"classes": classes, "ignore_index": IGNORE, "source": source}
        if intrinsics is not None:
            meta["intrinsics"] = intrinsics.to_dict()
            meta["depth_scale"] = intrinsics.depth_scale
        (self.tmp / "meta.json").write_text(json.dumps(meta, indent=1))
        return {"classes": len(classes), "splits": dict(self.counts), "depth": self.has_depth}


def assign_splits(names: list[str], fractions: tuple[float, float, float]) -> dict[str, str]:
    """Deterministic train/val/test assignment (by a hash of each name, so adding files moves few),
    with at least one image in each split that has a non-zero fraction."""
    order = sorted(names, key=lambda n: hashlib.sha1(n.encode()).hexdigest())
    n = len(order)
    n_val = max(1, round(n * fractions[1])) if fractions[1] > 0 else 0
    n_test = max(1, round(n * fractions[2])) if fractions[2] > 0 else 0
    if n - n_val - n_test < 1:
        raise DatasetError(f"{n} image(s) are too few for train/val/test splits of {fractions}")
    return {name: "train" if i < n - n_val - n_test else "val" if i < n - n_test else "test"
            for i, name in enumerate(order)}


def _read(path: Path, flags: int, what: str) -> np.ndarray:
    img = cv2.imread(str(path), flags)
    if img is None:
        raise DatasetError(f"cannot read {what} {path}")
    return img


def _rgb(path: Path) -> np.ndarray:
    return np.ascontiguousarray(_read(path, cv2.IMREAD_COLOR, "image")[..., ::-1])


# ----------------------------------------------------------------------------- Cityscapes
def import_cityscapes(src: Path, writer: NativeWriter, cfg: ImportConfig) -> tuple[list[str], None, dict]:
    """leftImg8bit/<split>/<city>/*_leftImg8bit.png + gtFine/<split>/<city>/*_gtFine_labelIds.png.
    Cityscapes withholds its test labels, so its val split feeds both val and test."""
    if cfg.cityscapes_classes not in ("30", "19"):
        raise DatasetError("Cityscapes classes must be 30 (all benchmark classes) or 19 (the train ids)")
    lut = np.full(256, IGNORE, np.uint8)
    if cfg.cityscapes_classes == "19":
        classes = [n for n, _, t in sorted(CITYSCAPES, key=lambda r: r[2]) if t != 255]
        for _, i, t in CITYSCAPES:
            lut[i] = t
    else:
        kept = [(n, i) for n, i, _ in CITYSCAPES if i >= CITYSCAPES_30_FIRST_ID]
        classes = [n for n, _ in kept]
        for k, (_, i) in enumerate(kept):
            lut[i] = k
    pairs = {}
    for split in ("train", "val"):
        images = sorted((src / "leftImg8bit" / split).glob("*/*_leftImg8bit.png"))
        if not images:
            raise DatasetError(f"{src} has no leftImg8bit/{split}/<city>/*_leftImg8bit.png images")
        pairs[split] = images
    jobs = [(s, p) for s in ("train", "val") for p in pairs[s]] + [("test", p) for p in pairs["val"]]
    for split, img in tqdm(jobs, desc="cityscapes", unit="img", disable=None):
        stem = img.name.removesuffix("_leftImg8bit.png")
        label = src / "gtFine" / ("val" if split == "test" else split) / img.parent.name / f"{stem}_gtFine_labelIds.png"
        if not label.is_file():
            raise DatasetError(f"label file missing for {img.name}: {label}")
        ids = _read(label, cv2.IMREAD_UNCHANGED, "label image")
        if ids.ndim != 2:
            raise DatasetError(f"{label} must be a single-channel labelIds image")
        if ids.dtype != np.uint8 or int(ids.max()) > 33:
            raise DatasetError(f"{label} holds label id {int(ids.max())}, outside Cityscapes' 0..33")
        writer.add(split, _rgb(img), lut[ids], None, str(img.relative_to(src)))
    return classes, None, {"format": "cityscapes", "classes": cfg.cityscapes_classes, "test_from": "val"}


# ----------------------------------------------------------------------------------- BOP
def _bop_scenes(src: Path) -> list[Path]:
    """Scene folders (with scene_gt.json) under a BOP split folder, or a data set root."""
    if (src / "scene_gt.json").is_file():
        return [src]
    scenes = sorted(p.parent for p in src.glob("*/scene_gt.json"))
    return scenes or sorted(p.parent for p in src.glob("*/*/scene_gt.json"))


def import_bop(src: Path, writer: NativeWriter, cfg: ImportConfig) -> tuple[list[str], Intrinsics, dict]:
    """rgb/, depth/, mask_visib/<im>_<k>.png, scene_gt.json (obj_id per gt), scene_camera.json
    (cam_K, depth_scale in mm per unit). One class per object id; depth converted to mm."""
    scenes = _bop_scenes(src)
    if not scenes:
        raise DatasetError(f"{src} holds no BOP scene (a folder with scene_gt.json)")
    entries, obj_ids = [], set()
    for scene in scenes:
        try:
            gt = json.loads((scene / "scene_gt.json").read_text())
            cams = json.loads((scene / "scene_camera.json").read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise DatasetError(f"{scene}: unreadable scene_gt.json or scene_camera.json: {exc}") from None
        for im, objs in gt.items():
            if im not in cams:
                raise DatasetError(f"{scene}/scene_camera.json has no entry for image {im}")
            obj_ids |= {int(o["obj_id"]) for o in objs}
            entries.append((scene, int(im), objs, cams[im]))
    ordered = sorted(obj_ids)
    names = [LINEMOD_NAMES[i - 1] if 1 <= i <= len(LINEMOD_NAMES) else f"obj_{i:06d}" for i in ordered]
    class_of = {obj: k + 1 for k, obj in enumerate(ordered)}
    intr = None
    splits = assign_splits([f"{scene.name}/{im:06d}" for scene, im, _, _ in entries], cfg.split_fractions)
    for scene, im, objs, cam in tqdm(entries, desc="bop", unit="img", disable=None):
        name = f"{scene.name}/{im:06d}"
        rgb_path = next((p for p in (scene / "rgb" / f"{im:06d}.png", scene / "rgb" / f"{im:06d}.jpg") if p.is_file()),
                        None)
        if rgb_path is None:
            raise DatasetError(f"{scene}/rgb has no image {im:06d}.png or .jpg")
        rgb = _rgb(rgb_path)
        h, w = rgb.shape[:2]
        K = np.asarray(cam.get("cam_K", []), float).reshape(-1)
        if K.size != 9:
            raise DatasetError(f"{scene}/scene_camera.json: image {im} has no 3x3 cam_K")
        this = Intrinsics(w, h, K[0], K[4], K[2], K[5], 0.001)
        if intr is None:
            intr = this
        elif (intr.width, intr.height) != (w, h) or max(abs(a - b) for a, b in zip(
                (intr.fx, intr.fy, intr.cx, intr.cy), (this.fx, this.fy, this.cx, this.cy))) > 0.5:
            raise DatasetError(f"{name}: camera differs from the first image's; import one camera at a time")
        mask = np.zeros((h, w), np.uint8)
        for k, obj in enumerate(objs):
            visib = scene / "mask_visib" / f"{im:06d}_{k:06d}.png"
            m = _read(visib, cv2.IMREAD_GRAYSCALE, "visible-mask") if visib.is_file() else None
            if m is None:
                raise DatasetError(f"mask file missing: {visib}")
            if m.shape != (h, w):
                raise DatasetError(f"{visib} is {m.shape[1]}x{m.shape[0]}, the image {w}x{h}")
            mask[m > 0] = class_of[int(obj["obj_id"])]
        depth_mm = None
        depth_path = scene / "depth" / f"{im:06d}.png"
        if depth_path.is_file():
            raw = _read(depth_path, cv2.IMREAD_UNCHANGED, "depth image")
            if raw.ndim != 2 or raw.dtype != np.uint16:
                raise DatasetError(f"{depth_path} must be a single-channel uint16 depth image")
            scale = float(cam.get("depth_scale", 1.0))  # BOP: millimetres per unit
            depth_mm = np.clip(np.round(raw.astype(np.float64) * scale), 0, 65535).astype(np.uint16)
        writer.add(splits[name], rgb, mask, depth_mm, name)
    return ["background", *names], intr, {"format": "bop", "obj_ids": ordered}


# ---------------------------------------------------------------------------------- CVAT
def read_labelmap(path: Path) -> list[tuple[str, tuple[int, int, int]]]:
    """CVAT / Pascal VOC labelmap.txt: `name:r,g,b:parts:actions` per line."""
    if not path.is_file():
        raise DatasetError(f"{path.parent} has no labelmap.txt (CVAT 'Segmentation mask 1.1' export)")
    out = []
    for n, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip() or line.startswith("#"):
            continue
        try:
            name, colour = line.split(":")[:2]
            rgb = tuple(int(v) for v in colour.split(","))
            assert len(rgb) == 3 and all(0 <= v <= 255 for v in rgb)
        except (ValueError, AssertionError):
            raise DatasetError(f"{path}:{n}: expected 'name:r,g,b::', got {line!r}") from None
        out.append((name.strip(), rgb))
    if not out:
        raise DatasetError(f"{path} lists no labels")
    return out


def import_cvat(src: Path, writer: NativeWriter, cfg: ImportConfig) -> tuple[list[str], Intrinsics | None, dict]:
    """labelmap.txt + SegmentationClass/*.png colour masks, images from SRC/JPEGImages or --images,
    depth from --depth (uint16 PNGs with the images' names) with --intrinsics."""
    labels = read_labelmap(src / "labelmap.txt")
    names = [n for n, _ in labels]
    if "background" in names:  # class 0 is background, as the runtime expects
        labels.insert(0, labels.pop(names.index("background")))
    else:
        labels.insert(0, ("background", (0, 0, 0)))
    classes = [n for n, _ in labels]
    colour_key = {r * 65536 + g * 256 + b: k for k, (_, (r, g, b)) in enumerate(labels)}
    if len(colour_key) != len(labels):
        raise DatasetError(f"{src}/labelmap.txt gives two labels the same colour")
    masks = sorted((src / "SegmentationClass").glob("*.png"))
    if not masks:
        raise DatasetError(f"{src} has no SegmentationClass/*.png masks")
    image_dir = Path(cfg.images) if cfg.images else src / "JPEGImages"
    if not image_dir.is_dir():
        raise DatasetError(f"no image folder {image_dir}: export with images or give --images DIR")
    depth_dir = Path(cfg.depth) if cfg.depth else None
    intr = None
    if depth_dir is not None:
        if not depth_dir.is_dir():
            raise DatasetError(f"depth folder {depth_dir} does not exist")
        if not cfg.intrinsics:
            raise DatasetError("--depth needs --intrinsics (intrinsics.json of the depth camera)")
        intr = Intrinsics.load(cfg.intrinsics)
    splits = assign_splits([m.stem for m in masks], cfg.split_fractions)
    for mpath in tqdm(masks, desc="cvat", unit="img", disable=None):
        stem = mpath.stem
        img_path = next((p for p in sorted(image_dir.glob(f"{stem}.*")) if p.suffix.lower() in
                         (".png", ".jpg", ".jpeg", ".bmp")), None)
        if img_path is None:
            raise DatasetError(f"no image for mask {mpath.name} in {image_dir}")
        rgb = _rgb(img_path)
        colour = _read(mpath, cv2.IMREAD_COLOR, "mask")[..., ::-1].astype(np.int32)
        key = colour[..., 0] * 65536 + colour[..., 1] * 256 + colour[..., 2]
        found = np.unique(key)
        unknown = [k for k in found if int(k) not in colour_key]
        if unknown:
            k = int(unknown[0])
            raise DatasetError(f"{mpath.name} has colour {(k >> 16, (k >> 8) & 255, k & 255)} that labelmap.txt "
                               "does not list")
        lut_keys = np.array(sorted(colour_key))
        mask = np.array([colour_key[int(k)] for k in lut_keys], np.uint8)[np.searchsorted(lut_keys, key)]
        depth_mm = None
        if depth_dir is not None:
            dpath = depth_dir / f"{stem}.png"
            if not dpath.is_file():
                raise DatasetError(f"no depth image {dpath} for {mpath.name}")
            raw = _read(dpath, cv2.IMREAD_UNCHANGED, "depth image")
            if raw.ndim != 2 or raw.dtype != np.uint16:
                raise DatasetError(f"{dpath} must be a single-channel uint16 depth image")
            if (raw.shape[1], raw.shape[0]) != (intr.width, intr.height):
                raise DatasetError(f"{dpath} is {raw.shape[1]}x{raw.shape[0]}, the intrinsics "
                                   f"{intr.width}x{intr.height}")
            depth_mm = np.clip(np.round(raw * (cfg.depth_scale_m * 1000.0)), 0, 65535).astype(np.uint16)
        writer.add(splits[stem], rgb, mask, depth_mm, mpath.name)
    if intr is not None:
        intr = Intrinsics(intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy, 0.001)  # written in mm
    return classes, intr, {"format": "cvat", "labelmap": [[n, list(c)] for n, c in labels]}


def import_dataset(fmt: str, src: str | Path, out: str | Path, cfg: ImportConfig | None = None) -> dict:
    """Convert SRC (in FORMAT) into the native layout at OUT; all or nothing."""
    cfg = cfg or ImportConfig()
    src, out = Path(src), Path(out)
    if fmt not in FORMATS:
        raise DatasetError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if not src.is_dir():
        raise DatasetError(f"source folder {src} does not exist")
    fr = cfg.split_fractions
    if len(fr) != 3 or min(fr) < 0 or abs(sum(fr) - 1) > 1e-6:
        raise DatasetError("split fractions must be three non-negative numbers that sum to 1")
    importer = {"cityscapes": import_cityscapes, "bop": import_bop, "cvat": import_cvat}[fmt]
    with atomic_folder(out) as tmp:
        writer = NativeWriter(tmp)
        summary = writer.finish(*importer(src, writer, cfg))
    return {"out": str(out), **summary}
