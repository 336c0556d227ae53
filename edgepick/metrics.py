"""Segmentation metrics from a confusion matrix (thesis eq. 2.18 and 2.19). numpy only."""

from __future__ import annotations

import numpy as np


def confusion_matrix(target: np.ndarray, pred: np.ndarray, num_classes: int) -> np.ndarray:
    """[num_classes, num_classes] counts, rows = ground truth, columns = prediction."""
    t = target.reshape(-1).astype(np.int64)
    p = pred.reshape(-1).astype(np.int64)
    keep = (t >= 0) & (t < num_classes)  # ignore labels (e.g. 255) drop out
    return np.bincount(t[keep] * num_classes + p[keep], minlength=num_classes ** 2).reshape(num_classes, num_classes)


def _div(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.full(a.shape, np.nan)
    np.divide(a, b, out=out, where=b > 0)
    return out


def segmentation_metrics(cm: np.ndarray, classes: list[str] | None = None) -> dict:
    """Pixel accuracy (overall and per class), IoU per class and mIoU from a confusion matrix.

    Per-class pixel accuracy is eq. 2.18 for the class against the rest:
    (TP + TN) / all. `recall` is TP / (TP + FN). IoU = TP / (TP + FP + FN) (eq. 2.19).
    A class with no pixels in target or prediction has IoU null and does not count in mIoU.
    """
    cm = np.asarray(cm, dtype=np.float64)
    n = cm.shape[0]
    classes = classes or [str(i) for i in range(n)]
    total = cm.sum()
    tp = np.diag(cm)
    fp = cm.sum(0) - tp
    fn = cm.sum(1) - tp
    tn = total - tp - fp - fn
    iou = _div(tp, tp + fp + fn)
    acc_c = _div(tp + tn, np.full(n, total))
    recall = _div(tp, tp + fn)
    valid = ~np.isnan(iou)

    def clean(v: np.ndarray) -> list:
        return [None if np.isnan(x) else round(float(x), 6) for x in v]

    return {
        "pixel_acc": round(float(tp.sum() / total), 6) if total else None,
        "miou": round(float(iou[valid].mean()), 6) if valid.any() else None,
        "per_class": {c: {"pixel_acc": a, "recall": r, "iou": i}
                      for c, a, r, i in zip(classes, clean(acc_c), clean(recall), clean(iou))},
        "confusion_matrix": cm.astype(np.int64).tolist(),
        "classes": list(classes),
        "pixels": int(total),
    }
