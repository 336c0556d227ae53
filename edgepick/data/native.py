"""Read and validate the native data set layout (docs/contracts.md#data-set-layout). numpy + OpenCV, no torch."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from edgepick.data.config import Split
from edgepick.errors import ConfigError, DatasetError
from edgepick.files import atomic_dir
from edgepick.frames import read_grasps
from edgepick.geometry import Intrinsics, check_depth_scale
from edgepick.schema import Where, as_dict, as_names, as_number, field, member, read_json

IGNORE = 255  # mask value of pixels that are neither trained on nor scored (e.g. Cityscapes' void)


@dataclass
class NativeDataset:
    """One split of a native data set: sorted scene ids and readers for their files."""

    root: Path
    split: Split
    classes: list[str]
    ids: list[str]
    intrinsics: Intrinsics | None

    @classmethod
    def open(cls, root: str | Path, split: Split | str) -> NativeDataset:
        root = Path(root)
        if not (root / "meta.json").is_file():
            raise DatasetError(f"{root} is not an edgepick data set (no meta.json)")
        meta = read_meta(root)
        split = member(Split, "split", split)
        rgb_dir, mask_dir = root / split / "rgb", root / split / "mask"
        if not rgb_dir.is_dir() or not mask_dir.is_dir():
            raise DatasetError(f"{root} has no {split}/rgb and {split}/mask folders")
        ids = sorted(p.stem for p in rgb_dir.glob("*.png"))
        masks = {p.stem for p in mask_dir.glob("*.png")}
        missing = [i for i in ids if i not in masks]
        if missing:
            raise DatasetError(f"{split} has {len(missing)} images without a mask (first: {missing[0]}); "
                               "the data set looks half-written")
        if not ids:
            raise DatasetError(f"{root}/{split} holds no images")
        return cls(root, split, meta.classes, ids, meta.intrinsics)

    def __len__(self) -> int:
        return len(self.ids)

    def _path(self, kind: str, sid: str) -> Path:
        return self.root / self.split / kind / f"{sid}.png"

    def _same_size(self, kind: str, sid: str, image: np.ndarray) -> np.ndarray:
        """Every image of a data set has one size (docs/contracts.md#data-set-layout): the
        split's first colour image sets it; another size names its file."""
        if not hasattr(self, "_hw"):
            first = cv2.imread(str(self._path("rgb", self.ids[0])), cv2.IMREAD_UNCHANGED)
            self._hw = first.shape[:2] if first is not None else image.shape[:2]
        if image.shape[:2] != self._hw:
            (h, w), (h0, w0) = image.shape[:2], self._hw
            raise DatasetError(f"{self._path(kind, sid)} is {w}x{h} but the data set's images are {w0}x{h0} "
                               f"(like {self.ids[0]}.png); all images of a data set must have one size")
        return image

    def check_files(self) -> None:
        """Every colour image and mask of the split a PNG of the split's one size, read from the files'
        headers alone (no decoding: milliseconds for thousands of scenes), so that a command refuses a
        broken data set before its work starts. A PNG whose data is damaged behind a sound header
        is found when it is decoded."""
        first = None
        for sid in self.ids:
            for kind in ("rgb", "mask"):
                path = self._path(kind, sid)
                size = _png_size(path)
                if size is None:
                    raise DatasetError(f"cannot read {'image' if kind == 'rgb' else 'mask'} {path} (not a PNG file)")
                first = first or size
                if size != first:
                    raise DatasetError(f"{path} is {size[0]}x{size[1]} but the data set's images are "
                                       f"{first[0]}x{first[1]} (like {self.ids[0]}.png); all images of a data set "
                                       "must have one size")

    def rgb(self, sid: str) -> np.ndarray:
        img = cv2.imread(str(self._path("rgb", sid)), cv2.IMREAD_COLOR)
        if img is None:
            raise DatasetError(f"cannot read image {self._path('rgb', sid)}")
        return self._same_size("rgb", sid, np.ascontiguousarray(img[..., ::-1]))

    def mask(self, sid: str) -> np.ndarray:
        m = cv2.imread(str(self._path("mask", sid)), cv2.IMREAD_UNCHANGED)
        if m is None or m.ndim != 2:
            raise DatasetError(f"cannot read mask {self._path('mask', sid)} as a single-channel label image")
        labelled = m[m != IGNORE]
        top = int(labelled.max()) if labelled.size else 0
        if top >= len(self.classes):
            raise DatasetError(f"mask {self._path('mask', sid)} has class id {top} but the data set "
                               f"has {len(self.classes)} classes")
        return self._same_size("mask", sid, m)

    def depth(self, sid: str) -> np.ndarray:
        d = cv2.imread(str(self._path("depth", sid)), cv2.IMREAD_UNCHANGED)
        if d is None:
            raise DatasetError(f"cannot read depth {self._path('depth', sid)}")
        return self._same_size("depth", sid, d)

    def grasps(self) -> dict[str, list[dict]]:
        """The split's grasp truth by scene id (synthetic data sets), or {} when it has none."""
        path = self.root / self.split / "grasps.json"
        return read_grasps(path) if path.is_file() else {}


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_size(path: Path) -> tuple[int, int] | None:
    """(width, height) from a PNG file's IHDR chunk, or None when the file is not a PNG."""
    try:
        with open(path, "rb") as f:
            head = f.read(24)
    except OSError:
        return None
    if len(head) < 24 or not head.startswith(PNG_SIGNATURE) or head[12:16] != b"IHDR":
        return None
    return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")


@dataclass(frozen=True)
class DatasetMeta:
    """What DATA/meta.json says (docs/contracts.md#data-set-layout)."""

    classes: list[str]
    intrinsics: Intrinsics | None


def read_meta(root: str | Path) -> DatasetMeta:
    """DATA/meta.json, checked: at least 2 distinct class names, optional intrinsics and depth scale."""
    path = Path(root) / "meta.json"
    where = Where(str(path))
    meta = as_dict(read_json(path, "data set meta"), where)
    classes = as_names(field(meta, "classes", where), where.at("classes"), min_length=2)
    if len(classes) > IGNORE:
        where.at("classes").fail(f"lists {len(classes)} classes; masks are uint8 with {IGNORE} = ignored, so at "
                                 f"most {IGNORE}")
    intr = meta.get("intrinsics")
    intr = Intrinsics.from_dict(intr, where.at("intrinsics")) if intr is not None else None
    if "depth_scale" in meta:
        check_depth_scale(as_number(meta["depth_scale"], where.at("depth_scale"), above=0), where.at("depth_scale"))
    return DatasetMeta(classes, intr)


@contextmanager
def atomic_folder(out: str | Path) -> Iterator[Path]:
    """Write a folder all or nothing: yields a temporary folder beside OUT that is renamed to OUT
    when the block ends, and removed if it raises (Ctrl-C included). OUT must be new or empty."""
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ConfigError(f"{out} already exists and is not empty; choose a new folder")
    with atomic_dir(out) as tmp:
        yield tmp
