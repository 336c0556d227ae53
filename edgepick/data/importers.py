"""`edgepick data import FORMAT SRC OUT`: Cityscapes, BOP (LineMOD) and CVAT segmentation
exports converted into the native layout (docs/contracts.md#data-set-layout), so train/quantize/bench take them.

Every file is checked while converting: BOP's scene files field by field (edgepick.data.bop),
the labelmap, and each image's kind, size and integrity; a malformed one ends as one line that
names it. The output goes to a temporary folder beside OUT that is renamed into place at the
end, so a malformed tree leaves nothing half-imported. numpy + OpenCV only.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from edgepick.data.bop import BopImage, bop_scenes, object_name, read_scene
from edgepick.data.config import CityscapesClasses, ImportConfig, ImportFormat, Split
from edgepick.data.native import IGNORE, atomic_folder
from edgepick.errors import DatasetError, ParameterError
from edgepick.geometry import Intrinsics, check_axis
from edgepick.schema import Where, member, read_text

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
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
# libjpeg's warnings about damaged data: the image decodes, with grey where the data is missing
JPEG_DAMAGE = ("Premature end of JPEG file", "Corrupt JPEG data")


class NativeWriter:
    """Writes scenes into an `atomic_folder` beside OUT: renamed into place at the end, removed on error."""

    def __init__(self, tmp: Path):
        self.tmp = tmp
        self.counts: dict[str, int] = dict.fromkeys(Split, 0)
        self.has_depth = False

    def add(self, split: str, rgb: np.ndarray, mask: np.ndarray, depth_mm: np.ndarray | None, name: str) -> None:
        if rgb.shape[:2] != mask.shape or (depth_mm is not None and depth_mm.shape != mask.shape):
            raise DatasetError(f"{name}: image {_size(rgb)}, label {_size(mask)}"
                               + ("" if depth_mm is None else f" and depth {_size(depth_mm)}") + " differ in size")
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
        empty = [s for s in Split if self.counts[s] == 0]
        if empty:
            raise DatasetError(f"the source gives no images for the {', '.join(empty)} split(s)")
        meta = {"classes": classes, "ignore_index": IGNORE, "source": source}
        if intrinsics is not None:
            meta["intrinsics"] = intrinsics.to_dict()
            meta["depth_scale"] = intrinsics.depth_scale
        (self.tmp / "meta.json").write_text(json.dumps(meta, indent=1))
        return {"classes": len(classes), "splits": dict(self.counts), "depth": self.has_depth}


def assign_splits(names: list[str], fractions: tuple[float, float, float]) -> dict[str, Split]:
    """Deterministic train/val/test assignment (by a hash of each name, so adding files moves few),
    with at least one image in each split that has a non-zero fraction."""
    order = sorted(names, key=lambda n: hashlib.sha1(n.encode()).hexdigest())
    n = len(order)
    n_val = max(1, round(n * fractions[1])) if fractions[1] > 0 else 0
    n_test = max(1, round(n * fractions[2])) if fractions[2] > 0 else 0
    if n - n_val - n_test < 1:
        raise DatasetError(f"{n} image(s) are too few for train/val/test splits of {fractions}")
    return {name: Split.TRAIN if i < n - n_val - n_test else Split.VAL if i < n - n_test else Split.TEST
            for i, name in enumerate(order)}


def _size(img: np.ndarray) -> str:
    return f"{img.shape[1]}x{img.shape[0]}"


def _imread(path: Path, flags: int) -> tuple[np.ndarray | None, list[str]]:
    """cv2.imread, and what its decoders wrote on stderr meanwhile (kept off the user's terminal:
    edgepick says what is wrong with the file itself)."""
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (AttributeError, OSError, ValueError):  # no stderr to keep clean
        return cv2.imread(str(path), flags), []
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            img = cv2.imread(str(path), flags)
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        sink.seek(0)
        said = sink.read().decode("utf-8", "replace")
    return img, [line.strip() for line in said.splitlines() if line.strip()]


def _read(path: Path, flags: int, what: str) -> np.ndarray:
    """An image, or a one-line error: missing, not an image, or damaged (a JPEG cut short decodes
    with a grey bottom half; it is refused rather than imported so)."""
    img, said = _imread(path, flags)
    damage = next((line for line in said if line.startswith(JPEG_DAMAGE)), None)
    if img is None or damage:
        raise DatasetError(f"cannot read {what} {path}" + (f": {damage}" if damage else ""))
    return img


def _rgb(path: Path) -> np.ndarray:
    return np.ascontiguousarray(_read(path, cv2.IMREAD_COLOR, "image")[..., ::-1])


# ----------------------------------------------------------------------------- Cityscapes
def import_cityscapes(src: Path, writer: NativeWriter, cfg: ImportConfig) -> tuple[list[str], None, dict]:
    """leftImg8bit/<split>/<city>/*_leftImg8bit.png + gtFine/<split>/<city>/*_gtFine_labelIds.png.
    Cityscapes withholds its test labels, so its val split feeds both val and test."""
    lut = np.full(256, IGNORE, np.uint8)
    if cfg.cityscapes_classes == CityscapesClasses.TRAIN_IDS:
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
            raise DatasetError(f"{label} must be a single-channel labelIds image, not a colour one")
        if ids.dtype != np.uint8:
            raise DatasetError(f"{label} is a {ids.dtype.itemsize * 8}-bit image; labelIds images are 8-bit")
        if int(ids.max()) > 33:
            raise DatasetError(f"{label} holds label id {int(ids.max())}, outside Cityscapes' 0..33")
        rgb = _rgb(img)
        if rgb.shape[:2] != ids.shape:
            raise DatasetError(f"{img} is {_size(rgb)}, its labels {label} {_size(ids)}: they differ in size")
        writer.add(split, rgb, lut[ids], None, str(img.relative_to(src)))
    return classes, None, {"format": "cityscapes", "classes": cfg.cityscapes_classes.value, "test_from": "val"}


# ----------------------------------------------------------------------------------- BOP
def import_bop(src: Path, writer: NativeWriter, cfg: ImportConfig) -> tuple[list[str], Intrinsics | None, dict]:
    """rgb/, depth/, mask_visib/<im>_<k>.png, scene_gt.json (obj_id per gt), scene_camera.json
    (cam_K, depth_scale in mm per unit). One class per object id; depth converted to mm.
    Every scene's JSON is checked (edgepick.data.bop) before the first image is converted."""
    scenes = bop_scenes(src)
    if not scenes:
        raise DatasetError(f"{src} holds no BOP scene (a folder with scene_gt.json)")
    entries: list[BopImage] = [image for scene in scenes for image in read_scene(scene)]
    ordered = sorted({obj for image in entries for obj in image.obj_ids})
    if len(ordered) >= IGNORE:
        raise DatasetError(f"{src} holds {len(ordered)} object ids; a mask holds at most {IGNORE - 1} classes "
                           f"besides the background ({IGNORE} marks ignored pixels)")
    class_of = {obj: k + 1 for k, obj in enumerate(ordered)}
    intr = None
    splits = assign_splits([f"{e.scene.name}/{e.im:06d}" for e in entries], cfg.split_fractions)
    for entry in tqdm(entries, desc="bop", unit="img", disable=None):
        scene, im, K = entry.scene, entry.im, entry.cam_K
        name = f"{scene.name}/{im:06d}"
        rgb_path = next((p for p in (scene / "rgb" / f"{im:06d}.png", scene / "rgb" / f"{im:06d}.jpg") if p.is_file()),
                        None)
        if rgb_path is None:
            raise DatasetError(f"{scene}/rgb has no image {im:06d}.png or .jpg")
        rgb = _rgb(rgb_path)
        h, w = rgb.shape[:2]
        this = Intrinsics(w, h, K[0], K[4], K[2], K[5], 0.001)
        if intr is None:  # the intrinsics the data set records: as any intrinsics file's are checked
            at = Where(str(scene / "scene_camera.json"), f"image {im}").at("cam_K")
            check_axis(K[0], K[2], w, "width", at.at(0), at.at(2))
            check_axis(K[4], K[5], h, "height", at.at(4), at.at(5))
            intr = this
        elif (intr.width, intr.height) != (w, h) or max(abs(a - b) for a, b in zip(
                (intr.fx, intr.fy, intr.cx, intr.cy), (this.fx, this.fy, this.cx, this.cy))) > 0.5:
            raise DatasetError(f"{name}: camera differs from the first image's; import one camera at a time")
        mask = np.zeros((h, w), np.uint8)
        for k, obj_id in enumerate(entry.obj_ids):
            visib = scene / "mask_visib" / f"{im:06d}_{k:06d}.png"
            if not visib.is_file():
                raise DatasetError(f"mask file missing: {visib}")
            m = _read(visib, cv2.IMREAD_GRAYSCALE, "visible-mask")
            if m.shape != (h, w):
                raise DatasetError(f"{visib} is {_size(m)}, the image {w}x{h}")
            mask[m > 0] = class_of[obj_id]
        depth_mm = None
        depth_path = scene / "depth" / f"{im:06d}.png"
        if depth_path.is_file():
            raw = _read(depth_path, cv2.IMREAD_UNCHANGED, "depth image")
            if raw.ndim != 2 or raw.dtype != np.uint16:
                raise DatasetError(f"{depth_path} must be a single-channel uint16 depth image")
            if raw.shape != (h, w):
                raise DatasetError(f"{depth_path} is {_size(raw)}, the image {w}x{h}")
            # BOP: millimetres per unit
            depth_mm = np.clip(np.round(raw.astype(np.float64) * entry.depth_scale), 0, 65535).astype(np.uint16)
        writer.add(splits[name], rgb, mask, depth_mm, name)
    return ["background", *map(object_name, ordered)], intr, {"format": "bop", "obj_ids": ordered}


# ---------------------------------------------------------------------------------- CVAT
def read_labelmap(path: Path) -> list[tuple[str, tuple[int, int, int]]]:
    """CVAT / Pascal VOC labelmap.txt: `name:r,g,b:parts:actions` per line, each name once and
    each colour channel 0..255."""
    if not path.is_file():
        raise DatasetError(f"{path.parent} has no labelmap.txt (CVAT 'Segmentation mask 1.1' export)")
    out: list[tuple[str, tuple[int, int, int]]] = []
    line_of: dict[str, int] = {}
    for n, line in enumerate(read_text(path, "labelmap").splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        parts = line.split(":")
        try:
            rgb = tuple(int(v) for v in parts[1].split(","))
        except (IndexError, ValueError):
            rgb = ()
        if len(rgb) != 3:
            raise DatasetError(f"{path}:{n}: expected 'name:r,g,b::', got {line!r}")
        if not all(0 <= v <= 255 for v in rgb):
            raise DatasetError(f"{path}:{n}: colour {','.join(map(str, rgb))} is outside 0..255")
        name = parts[0].strip()
        if not name:
            raise DatasetError(f"{path}:{n}: the label has no name, got {line!r}")
        if name in line_of:
            raise DatasetError(f"{path}:{n}: lists the label {name!r} twice (first on line {line_of[name]})")
        line_of[name] = n
        out.append((name, rgb))
    if not out:
        raise DatasetError(f"{path} lists no labels")
    return out


def _images_by_stem(image_dir: Path) -> dict[str, list[Path]]:
    """The image files of IMAGE_DIR by name without suffix (a.jpg and a.png both under 'a')."""
    found: dict[str, list[Path]] = {}
    try:
        for p in sorted(image_dir.iterdir()):
            if p.suffix.lower() in IMAGE_SUFFIXES:
                found.setdefault(p.stem, []).append(p)
    except OSError as exc:
        raise DatasetError(f"cannot list the image folder {image_dir}: {exc.strerror or exc}") from None
    return found


def _colour_mask(mpath: Path) -> np.ndarray:
    """A CVAT mask as an [H, W, 3] int32 RGB array: 8-bit colour (grey or with alpha is taken too)."""
    raw = _read(mpath, cv2.IMREAD_UNCHANGED, "mask")
    if raw.dtype != np.uint8:
        raise DatasetError(f"{mpath} is a {raw.dtype.itemsize * 8}-bit image; CVAT masks are 8-bit colour PNGs")
    bgr = cv2.cvtColor(raw, cv2.COLOR_GRAY2BGR) if raw.ndim == 2 else raw[..., :3]
    return bgr[..., ::-1].astype(np.int32)


def import_cvat(src: Path, writer: NativeWriter, cfg: ImportConfig) -> tuple[list[str], Intrinsics | None, dict]:
    """labelmap.txt + SegmentationClass/*.png colour masks, images from SRC/JPEGImages or cfg.images,
    depth from cfg.depth (uint16 PNGs with the images' names) with cfg.intrinsics."""
    labelmap = src / "labelmap.txt"
    labels = read_labelmap(labelmap)
    names = [n for n, _ in labels]
    if "background" in names:  # class 0 is background, as the runtime expects
        labels.insert(0, labels.pop(names.index("background")))
    else:
        labels.insert(0, ("background", (0, 0, 0)))
    if len(labels) > IGNORE:
        raise DatasetError(f"{labelmap} lists {len(names)} labels; a mask holds at most {IGNORE} classes, the "
                           f"background included ({IGNORE} marks ignored pixels)")
    classes = [n for n, _ in labels]
    colour_key: dict[int, int] = {}
    for k, (name, (r, g, b)) in enumerate(labels):
        other = colour_key.setdefault(r * 65536 + g * 256 + b, k)
        if other != k:
            raise DatasetError(f"{labelmap} gives {classes[other]!r} and {name!r} the same colour {r},{g},{b}")
    masks = sorted((src / "SegmentationClass").glob("*.png"))
    if not masks:
        raise DatasetError(f"{src} has no SegmentationClass/*.png masks")
    image_dir = Path(cfg.images) if cfg.images else src / "JPEGImages"
    if not image_dir.is_dir():
        raise ParameterError(f"no image folder {image_dir}: export with images or give {{images:name}}",
                             images=cfg.images)
    images = _images_by_stem(image_dir)
    depth_dir = Path(cfg.depth) if cfg.depth else None
    intr = None
    if depth_dir is not None and cfg.intrinsics:  # ImportConfig refuses a depth folder without intrinsics
        if not depth_dir.is_dir():
            raise DatasetError(f"depth folder {depth_dir} does not exist")
        intr = Intrinsics.load(cfg.intrinsics)
    splits = assign_splits([m.stem for m in masks], cfg.split_fractions)
    lut_keys = np.array(sorted(colour_key))
    lut = np.array([colour_key[int(k)] for k in lut_keys], np.uint8)
    for mpath in tqdm(masks, desc="cvat", unit="img", disable=None):
        stem = mpath.stem
        found = images.get(stem, [])
        if not found:
            raise DatasetError(f"no image for mask {mpath.name} in {image_dir}")
        if len(found) > 1:
            raise DatasetError(f"{mpath} has {len(found)} images of its name, {' and '.join(map(str, found))}; "
                               "keep one of them")
        rgb = _rgb(found[0])
        colour = _colour_mask(mpath)
        if colour.shape[:2] != rgb.shape[:2]:
            raise DatasetError(f"{mpath} is {_size(colour)}, its image {found[0]} {_size(rgb)}: they differ in size")
        key = colour[..., 0] * 65536 + colour[..., 1] * 256 + colour[..., 2]
        unknown = [int(k) for k in np.unique(key) if int(k) not in colour_key]
        if unknown:
            k = unknown[0]
            raise DatasetError(f"{mpath} has colour {(k >> 16, (k >> 8) & 255, k & 255)} that labelmap.txt "
                               "does not list")
        mask = lut[np.searchsorted(lut_keys, key)]
        depth_mm = None
        if depth_dir is not None and intr is not None:
            dpath = depth_dir / f"{stem}.png"
            if not dpath.is_file():
                raise DatasetError(f"no depth image {dpath} for {mpath.name}")
            raw = _read(dpath, cv2.IMREAD_UNCHANGED, "depth image")
            if raw.ndim != 2 or raw.dtype != np.uint16:
                raise DatasetError(f"{dpath} must be a single-channel uint16 depth image")
            if (raw.shape[1], raw.shape[0]) != (intr.width, intr.height):
                raise DatasetError(f"{dpath} is {_size(raw)}, the intrinsics {intr.width}x{intr.height}")
            depth_mm = np.round(raw * (cfg.depth_scale_m * 1000.0))
            if depth_mm.max() > 65535:  # a wrong --depth-scale, not a depth any camera of a cell reads
                raise ParameterError(f"{{depth_scale_m}}: {dpath} holds {int(raw.max())} units, "
                                     f"{raw.max() * cfg.depth_scale_m:g} m at this scale, beyond the 65.535 m a "
                                     "millimetre depth image holds; is it metres per unit?",
                                     depth_scale_m=cfg.depth_scale_m)
            depth_mm = depth_mm.astype(np.uint16)
        writer.add(splits[stem], rgb, mask, depth_mm, mpath.name)
    if intr is not None:
        intr = Intrinsics(intr.width, intr.height, intr.fx, intr.fy, intr.cx, intr.cy, 0.001)  # written in mm
    return classes, intr, {"format": "cvat", "labelmap": [[n, list(c)] for n, c in labels]}


def import_dataset(fmt: ImportFormat, src: str | Path, out: str | Path, cfg: ImportConfig | None = None) -> dict:
    """Convert SRC (in FORMAT) into the native layout at OUT; all or nothing."""
    cfg = cfg or ImportConfig()
    fmt = member(ImportFormat, "fmt", fmt)
    src, out = Path(src), Path(out)
    if not src.is_dir():
        raise DatasetError(f"source folder {src} does not exist")
    importer = {ImportFormat.CITYSCAPES: import_cityscapes, ImportFormat.BOP: import_bop,
                ImportFormat.CVAT: import_cvat}[fmt]
    with atomic_folder(out) as tmp:
        writer = NativeWriter(tmp)
        summary = writer.finish(*importer(src, writer, cfg))
    return {"out": str(out), **summary}
