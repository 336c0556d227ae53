"""A detector's decision read off its box table (quant/detections.py): the threshold, class-wise NMS,
either table orientation, objectness, and which boxes another model finds again."""

from __future__ import annotations

import numpy as np
import pytest

from edgepick.quant.detections import detections, found_again, table_rows


def rows(*boxes: tuple) -> np.ndarray:
    """A [1, N, K] table of (cx, cy, w, h, scores...) rows, padded with rows that score 0 to 16 rows
    (a detector's table has more rows than attributes: the shorter axis holds the attributes)."""
    table = np.zeros((1, 16, len(boxes[0])), np.float32)
    table[0, :len(boxes)] = boxes
    table[0, len(boxes):, :4] = [200, 200, 10, 10]
    return table


def test_rows_come_out_the_same_from_either_orientation():
    table = rows((10, 10, 4, 4, 0.9, 0.1), (30, 30, 4, 4, 0.2, 0.8), (50, 50, 4, 4, 0.1, 0.1))
    assert np.array_equal(table_rows(table), table_rows(table.transpose(0, 2, 1)))
    with pytest.raises(ValueError, match="box table"):
        table_rows(np.zeros((1, 3, 8, 8), np.float32))


def test_detections_keep_scores_above_the_threshold_and_suppress_overlaps_of_one_class():
    table = rows((10, 10, 10, 10, 0.9, 0.0),  # class 0
                 (11, 10, 10, 10, 0.8, 0.0),  # class 0, IoU 0.82 with the first: suppressed
                 (11, 10, 10, 10, 0.0, 0.7),  # class 1 in the same place: kept
                 (40, 40, 10, 10, 0.3, 0.0),  # class 0 elsewhere: kept
                 (60, 60, 10, 10, 0.2, 0.1))  # under the threshold
    corners, classes, scores = detections(table, 0.25, objectness=False)
    assert classes.tolist() == [0, 1, 0] and np.allclose(scores, [0.9, 0.7, 0.3])
    assert np.allclose(corners[0], [5, 5, 15, 15])
    same = detections(table.transpose(0, 2, 1), 0.25, objectness=False)
    assert all(np.array_equal(a, b) for a, b in zip(same, (corners, classes, scores)))


def test_objectness_multiplies_the_class_score():
    table = rows((10, 10, 10, 10, 0.2, 0.9, 0.1), (40, 40, 10, 10, 0.9, 0.1, 0.6))
    _, classes, scores = detections(table, 0.25, objectness=True)
    assert classes.tolist() == [1] and np.allclose(scores, [0.54])  # 0.2 x 0.9 = 0.18 falls under 0.25
    assert len(detections(table, 0.25, objectness=False)[0]) == 2  # read without it: column 4 is a class


def test_a_box_is_found_again_by_one_of_its_class_overlapping_by_half_or_more():
    ref = detections(rows((10, 10, 10, 10, 0.9, 0.0), (40, 40, 10, 10, 0.0, 0.8), (70, 70, 10, 10, 0.7, 0.0)), 0.25,
                     False)
    test = detections(rows((11, 10, 10, 10, 0.8, 0.0),  # IoU 0.82: found
                           (40, 40, 10, 10, 0.8, 0.0),  # the right place, the wrong class
                           (75, 70, 10, 10, 0.6, 0.0)), 0.25, False)  # IoU 0.33: not found
    assert found_again(ref, test) == 1 and found_again(test, ref) == 1
    twice = detections(rows((10, 10, 10, 10, 0.9, 0.0), (10, 30, 10, 10, 0.8, 0.0)), 0.25, False)
    once = detections(rows((10, 10, 10, 10, 0.9, 0.0)), 0.25, False)
    assert found_again(twice, once) == 1 and found_again(once, once) == 1
    empty = detections(rows((10, 10, 10, 10, 0.1, 0.0)), 0.25, False)
    assert found_again(ref, empty) == 0 and found_again(empty, ref) == 0
