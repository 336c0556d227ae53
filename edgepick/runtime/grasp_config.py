"""The grasp step's settings (runtime/grasp.py, runtime/regions.py): the mask filters' and the grasp
geometry's, in a frozen config that imports without numpy or OpenCV."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from edgepick.errors import ParameterError


@dataclass(frozen=True)
class GraspConfig:
    """The mask filters' and grasp geometry's settings, checked on creation."""

    median_ksize: int = 3
    dilate_ksize: int = 5
    min_area_px: int = 120  # regions smaller than this are noise, not objects
    round_ratio: float = 0.8  # minor/major variance ratio above which there is no stable major axis
    min_depth_px: int = 10  # valid depth pixels needed for a depth estimate
    centre_fraction: float = 0.3  # depth from pixels within this share of the equivalent radius of the centroid
    split_core: float = 0.5  # touching objects of one class: cores where the distance to the edge > this x its max
    hole_rim: float = 0.7  # a hole splits rings when this share of its rim is the region itself
    split_min_share: float = 0.15  # a core counts as an object when it holds this share of all cores' area
    notch_depth: float = 0.07  # objects side by side at one height: notches deeper than this x sqrt(area) mark a seam
    split_min_part: float = 0.25  # ... when each side of the cut holds at least this share of the region
    split_solidity: float = 0.98  # ... and is convex (pixels / hull area): not a disk with bites out of its rim
    deep_notch: float = 0.15  # ... or, when both notches are deeper than this x sqrt(area),
    split_solidity_deep: float = 0.95  # ... nearly convex: a model's mask rounds the corners at the seam
    face_compactness: float = 12.0  # a face at its own height: area <= this x (largest edge distance)^2,
    #                                 i.e. at most 3x as long as wide; a side wall is a longer, thin band
    top_tolerance_m: float = 0.008  # an object's top face: its pixels within this depth of the top
    stray_gap_px: int = 15  # ... less the groups of them farther than this - 1 pixels from the others
    stray_share: float = 0.1  # ... that hold less than this share of them: a mask spilling onto a neighbour
    partial_contact: float = 0.3  # cut by the image border: meets it along this x sqrt(area) pixels or more; a
    #                               shorter cut (an object a few pixels over the edge, a mask bleeding to it)
    #                               moves the centroid by 2 px or less
    rect_fill: float = 0.85  # a face filling this share of its minimum-area rectangle takes that rectangle's axis

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (math.isfinite(value) and value >= 0):
                raise ParameterError(f"{{{f.name}}}: must be 0 or more", **{f.name: value})
        if self.median_ksize % 2 != 1:
            raise ParameterError("{median_ksize}: a median filter's size must be odd", median_ksize=self.median_ksize)
