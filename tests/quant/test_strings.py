"""A text recogniser's strings read off its CTC scores (quant/strings.py) and `--task ctc`."""

from __future__ import annotations

import numpy as np
import pytest

from edgepick.errors import ParameterError
from edgepick.quant.fidelity import Task, TaskKind
from edgepick.quant.strings import characters_read_again, edit_distance, greedy_ctc, sequences


def _scores(classes: list[int], count: int = 5) -> np.ndarray:
    """[steps, COUNT] scores whose best class per step is CLASSES'."""
    y = np.full((len(classes), count), 0.1, np.float32)
    y[np.arange(len(classes)), classes] = 0.9
    return y


def test_greedy_decoding_merges_repeats_and_drops_the_blank():
    assert greedy_ctc(_scores([0, 3, 3, 0, 3, 2, 2, 0])) == [3, 3, 2]  # a blank between two 3s keeps both
    assert greedy_ctc(_scores([0, 0, 0])) == []


def test_sequences_are_read_batch_first_or_time_major():
    steps = _scores([1, 0, 2])
    assert [greedy_ctc(s) for s in sequences(steps[None])] == [[1, 2]]  # [1, steps, classes]
    assert [greedy_ctc(s) for s in sequences(steps[:, None])] == [[1, 2]]  # [steps, 1, classes]
    with pytest.raises(ValueError):
        sequences(steps[None, None])


def test_edit_distance_counts_insertions_deletions_and_substitutions():
    assert edit_distance("kitten", "sitting") == 3 and edit_distance([1, 2], [1, 2]) == 0 and edit_distance("", "ab") == 2


def test_a_ctc_task_scores_the_characters_read_the_same():
    ref = np.stack([_scores([1, 0, 2, 0, 3, 3]), _scores([4, 4, 0, 0, 0, 0])])  # "1 2 3" and "4"
    shifted = np.stack([_scores([0, 1, 2, 2, 0, 3]), _scores([4, 0, 0, 0, 0, 0])])  # steps moved: the same strings
    assert characters_read_again(ref, shifted) == (4, 4)
    task = Task.parse("ctc")
    assert task.kind == TaskKind.CTC and str(task) == "ctc"
    assert task.agree(ref, shifted) == (4, 4)  # the steps' top-1 classes: 7 of 12
    assert Task(TaskKind.TOP1).agree(ref, shifted) == (7, 12)
    misread = np.stack([_scores([1, 0, 4, 0, 3, 3]), _scores([0, 0, 0, 0, 0, 0])])  # one substitution, one lost
    assert task.agree(ref, misread) == (2, 4)


def test_a_ctc_task_on_an_output_with_no_class_scores_is_refused_naming_task():
    Task.parse("ctc").check_shape((1, 40, 6625), "softmax")
    with pytest.raises(ParameterError, match="task"):
        Task.parse("ctc").check_shape((1, 3, 48, 320), "map")
    with pytest.raises(ParameterError, match="task"):
        Task.parse("ctc:2")
