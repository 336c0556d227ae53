"""The data stage's choices (splits, import formats) and how a tree is imported (`ImportConfig`),
without numpy or OpenCV: the command line builds its options and defaults from them."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from edgepick.errors import ParameterError
from edgepick.schema import member


class Split(enum.StrEnum):
    """A data set's splits, in the order a data set lists them."""

    TRAIN = "train"
    VAL = "val"
    TEST = "test"


class ImportFormat(enum.StrEnum):
    """The trees `data import` converts into the native layout."""

    CITYSCAPES = "cityscapes"
    BOP = "bop"
    CVAT = "cvat"


class CityscapesClasses(enum.StrEnum):
    """All 30 Cityscapes benchmark classes, or its 19 train ids (the rest ignored)."""

    ALL = "30"
    TRAIN_IDS = "19"


@dataclass(frozen=True)
class ImportConfig:
    """How `data import` reads a tree, checked on creation."""

    cityscapes_classes: CityscapesClasses = CityscapesClasses.ALL
    split_fractions: tuple[float, float, float] = (0.8, 0.1, 0.1)  # for sources without splits
    images: str | None = None  # CVAT: folder of the colour images (default SRC/JPEGImages)
    depth: str | None = None  # CVAT: folder of uint16 depth PNGs with the images' names
    intrinsics: str | None = None  # CVAT: intrinsics.json of the depth camera
    depth_scale_m: float = 0.001  # CVAT: metres per unit of the depth PNGs

    def __post_init__(self) -> None:
        object.__setattr__(self, "cityscapes_classes",
                           member(CityscapesClasses, "cityscapes_classes", self.cityscapes_classes))
        fr = tuple(self.split_fractions)
        object.__setattr__(self, "split_fractions", fr)
        if len(fr) != 3 or not all(math.isfinite(f) and f >= 0 for f in fr) or abs(sum(fr) - 1) > 1e-6:
            raise ParameterError("{split_fractions}: must be three non-negative numbers that sum to 1",
                                 split_fractions=fr)
        if not (math.isfinite(self.depth_scale_m) and self.depth_scale_m > 0):
            raise ParameterError("{depth_scale_m}: must be positive (metres per unit, e.g. 0.001)",
                                 depth_scale_m=self.depth_scale_m)
        from edgepick.geometry import DEPTH_SCALE_MAX_M, DEPTH_SCALE_MIN_M  # imports numpy: not at this module's import

        if not DEPTH_SCALE_MIN_M <= self.depth_scale_m <= DEPTH_SCALE_MAX_M:
            raise ParameterError(f"{{depth_scale_m}}: must be in [{DEPTH_SCALE_MIN_M:g}, {DEPTH_SCALE_MAX_M:g}] metres "
                                 "per depth unit (0.001: millimetres)", depth_scale_m=self.depth_scale_m)
        if self.depth and not self.intrinsics:
            raise ParameterError("{depth:name} needs {intrinsics:name} (intrinsics.json of the depth camera)",
                                 depth=self.depth, intrinsics=self.intrinsics)
