import numpy as np
import pytest

from edgepick.metrics import confusion_matrix, segmentation_metrics


def test_hand_computed_example():
    target = np.array([[0, 0, 1], [1, 2, 2]])
    pred = np.array([[0, 1, 1], [1, 2, 0]])
    cm = confusion_matrix(target, pred, 3)
    assert cm.tolist() == [[1, 1, 0], [0, 2, 0], [1, 0, 1]]
    m = segmentation_metrics(cm, ["bg", "a", "b"])
    assert m["pixel_acc"] == pytest.approx(4 / 6)
    # IoU = TP / (TP + FP + FN): bg 1/(1+1+1), a 2/(2+1+0), b 1/(1+0+1)
    assert m["per_class"]["bg"]["iou"] == pytest.approx(1 / 3)
    assert m["per_class"]["a"]["iou"] == pytest.approx(2 / 3)
    assert m["per_class"]["b"]["iou"] == pytest.approx(1 / 2)
    assert m["miou"] == pytest.approx((1 / 3 + 2 / 3 + 1 / 2) / 3)
    # eq. 2.18 per class, one against the rest: (TP + TN) / all; for "a": TP 2, TN 3 -> 5/6
    assert m["per_class"]["a"]["pixel_acc"] == pytest.approx(5 / 6)
    assert m["per_class"]["b"]["recall"] == pytest.approx(1 / 2)


def test_class_absent_from_image_and_prediction_is_left_out_of_miou():
    target = np.array([0, 0, 1, 1])
    pred = np.array([0, 0, 1, 0])
    m = segmentation_metrics(confusion_matrix(target, pred, 3), ["bg", "a", "b"])
    assert m["per_class"]["b"]["iou"] is None  # no pixels anywhere: undefined, not 0
    assert m["miou"] == pytest.approx((2 / 3 + 1 / 2) / 2)


def test_class_predicted_but_absent_counts_as_zero_iou():
    target = np.array([0, 0, 0, 0])
    pred = np.array([0, 0, 0, 2])
    m = segmentation_metrics(confusion_matrix(target, pred, 3))
    assert m["per_class"]["2"]["iou"] == 0.0
    assert m["miou"] == pytest.approx((3 / 4 + 0.0) / 2)


def test_ignore_label_is_dropped():
    cm = confusion_matrix(np.array([0, 255, 1]), np.array([0, 1, 1]), 2)
    assert cm.sum() == 2
