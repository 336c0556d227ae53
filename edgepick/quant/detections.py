"""A detector's decision read off its box table, for `--task boxes|boxes-obj`: the boxes kept by a
score threshold and class-wise non-maximum suppression, and how many of one model's boxes another
model finds again (the same class, IoU 0.5 or more). What fidelity.py compares for a detector whose
graph ends in a table of box rows, as Ultralytics' YOLOv8 and later (`boxes`: cx, cy, w, h, then
one score per class) and YOLOv5 exports (`boxes-obj`: cx, cy, w, h, an objectness score, then
one score per class) write it. Numpy only.
"""

from __future__ import annotations

import numpy as np

NMS_IOU = 0.45  # a box overlapping a better one of its class this much is the same object (Ultralytics' default)
MATCH_IOU = 0.5  # a box of one model found again by the other: same class, overlapping this much
MAX_BOXES = 300  # kept per image at most, the best first (Ultralytics' max_det)


def table_rows(y: np.ndarray) -> np.ndarray:
    """Y, one image's box table ([N, K] or [1, N, K]; or [K, N] and [1, K, N], the attributes along
    the shorter axis), as rows of K attributes: [N, K]."""
    table = y[0] if y.ndim == 3 else y
    if table.ndim != 2:
        raise ValueError(f"a box table is [1, boxes, attributes] or [boxes, attributes], not {list(y.shape)}")
    return table.T if table.shape[0] < table.shape[1] else table


def detections(y: np.ndarray, threshold: float, objectness: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One image's detections in its box table Y: corners [n, 4] (x0, y0, x1, y1), classes [n] and
    scores [n], best first, after the THRESHOLD on each row's score (its best class's, times the
    row's OBJECTNESS where it has one) and class-wise non-maximum suppression (NMS_IOU)."""
    rows = table_rows(y).astype(np.float64)
    first = 5 if objectness else 4
    scores_by_class = rows[:, first:]
    classes = scores_by_class.argmax(1)
    scores = scores_by_class[np.arange(len(rows)), classes]
    if objectness:
        scores = scores * rows[:, 4]
    keep = scores > threshold
    rows, classes, scores = rows[keep], classes[keep], scores[keep]
    corners = np.concatenate([rows[:, :2] - rows[:, 2:4] / 2, rows[:, :2] + rows[:, 2:4] / 2], axis=1)
    kept = _suppress(corners, classes, scores)
    return corners[kept], classes[kept], scores[kept]


def found_again(ref: tuple[np.ndarray, np.ndarray, np.ndarray], test: tuple[np.ndarray, np.ndarray, np.ndarray]) -> int:
    """How many of REF's detections TEST finds again: each REF box, best first, paired with the
    unpaired TEST box of its class that overlaps it most, if by MATCH_IOU or more."""
    (ref_boxes, ref_classes, _), (test_boxes, test_classes, _) = ref, test
    free = np.ones(len(test_boxes), bool)
    found = 0
    for box, cls in zip(ref_boxes, ref_classes):
        overlap = np.where(free & (test_classes == cls), _iou(box, test_boxes), 0.0)
        if overlap.size and overlap.max() >= MATCH_IOU:
            free[int(overlap.argmax())] = False
            found += 1
    return found


def _iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Intersection over union of BOX (x0, y0, x1, y1) with each of BOXES."""
    low = np.maximum(box[:2], boxes[:, :2])
    high = np.minimum(box[2:], boxes[:, 2:])
    inter = np.prod(np.clip(high - low, 0.0, None), axis=1)
    area = np.prod(np.clip(box[2:] - box[:2], 0.0, None))
    areas = np.prod(np.clip(boxes[:, 2:] - boxes[:, :2], 0.0, None), axis=1)
    union = area + areas - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def _suppress(corners: np.ndarray, classes: np.ndarray, scores: np.ndarray) -> np.ndarray:
    """The indices NMS keeps, best first (at most MAX_BOXES): of the boxes of one class that
    overlap by more than NMS_IOU, the best scored."""
    order = np.argsort(-scores, kind="stable")
    kept: list[int] = []
    while order.size and len(kept) < MAX_BOXES:
        best, rest = order[0], order[1:]
        kept.append(int(best))
        same = classes[rest] == classes[best]
        order = rest[~(same & (_iou(corners[best], corners[rest]) > NMS_IOU))]
    return np.array(kept, dtype=np.int64)
