"""Task metrics: how far one list of decisions is from a reference list (fp32's, or the truth), 1.0
when they are the same: box F1 at IoU 0.5, character accuracy of strings, top-1 agreement, pixel
agreement of masks."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from edgepick.quant.strings import edit_distance

from .detectors import Boxes, iou_matrix
from .spec import Metric


def box_f1(reference: Sequence[Boxes], found: Sequence[Boxes], iou: float = 0.5, classes: bool = True) -> float:
    """F1 of FOUND against REFERENCE over all inputs: a found box is a hit when it has IoU >= IOU with a
    reference box of its class not yet matched (greedy, best pairs first). 1.0 when neither has a box."""
    hits = found_n = ref_n = 0
    for ref, got in zip(reference, found):
        found_n, ref_n = found_n + len(got), ref_n + len(ref)
        if not len(ref) or not len(got):
            continue
        overlap = iou_matrix(got.xyxy, ref.xyxy)
        if classes:
            overlap = np.where(got.classes[:, None] == ref.classes[None, :], overlap, 0.0)
        pairs = sorted(zip(*np.nonzero(overlap >= iou)), key=lambda p: -overlap[p])
        used_got, used_ref = set(), set()
        for g, r in pairs:
            if g not in used_got and r not in used_ref:
                used_got.add(g)
                used_ref.add(r)
        hits += len(used_got)
    return 1.0 if found_n + ref_n == 0 else 2 * hits / (found_n + ref_n)


def char_accuracy(reference: Sequence[str], found: Sequence[str]) -> float:
    """1 - the summed edit distances over the summed reference lengths (at least 0)."""
    total = sum(max(len(r), 1) for r in reference)
    return max(0.0, 1.0 - sum(edit_distance(r, f) for r, f in zip(reference, found)) / max(total, 1))


def exact_rate(reference: Sequence[object], found: Sequence[object]) -> float:
    """The share of inputs whose decision equals the reference's (strings read exactly, top-1 classes)."""
    return sum(r == f for r, f in zip(reference, found)) / max(len(reference), 1)


def pixel_agreement(reference: Sequence[np.ndarray], found: Sequence[np.ndarray]) -> float:
    """The share of pixels whose decision (mask or label) equals the reference's."""
    same = sum(int((r == f).sum()) for r, f in zip(reference, found))
    return same / max(sum(r.size for r in reference), 1)


BOX_F1 = Metric("box F1 @ IoU 0.5", box_f1)
CHAR_ACCURACY = Metric("character accuracy", char_accuracy)
EXACT_STRINGS = Metric("strings read the same", exact_rate)
TOP1 = Metric("top-1 agreement", exact_rate)
PIXELS = Metric("pixel agreement", pixel_agreement)
