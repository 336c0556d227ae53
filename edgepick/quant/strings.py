"""A text recogniser's decision read off its CTC output, for `--task ctc`: the string of each
sequence by greedy CTC decoding (the best class per step, repeats merged, the blank dropped), and
how many of one model's characters another model reads the same (the reference's length less the
edit distance). What fidelity.py compares for a recogniser: a step's top class may flip between
the blank and a character on a letter's edge while the string stays the same, so the steps' top-1
agreement judges such a model far stricter than its reader does. Numpy only.
"""

from __future__ import annotations

import numpy as np

BLANK = 0  # the CTC blank class (PaddleOCR's, CRNN's and most exporters' convention)


def sequences(y: np.ndarray) -> list[np.ndarray]:
    """Y's sequences of class scores, each [steps, classes]: Y is [steps, classes], [batch, steps,
    classes], or time-major [steps, 1, classes]."""
    if y.ndim == 2:
        return [y]
    if y.ndim != 3:
        raise ValueError(f"a CTC output is [steps, classes], [batch, steps, classes] or [steps, 1, classes], "
                         f"not {list(y.shape)}")
    if y.shape[1] == 1 and y.shape[0] > 1:  # time-major, one sequence
        return [y[:, 0]]
    return list(y)


def greedy_ctc(steps: np.ndarray, blank: int = BLANK) -> list[int]:
    """The classes STEPS ([steps, classes]) reads: the best per step, repeats merged, BLANK dropped."""
    best = steps.argmax(-1)
    merged = best[np.r_[True, best[1:] != best[:-1]]]
    return [int(c) for c in merged if c != blank]


def edit_distance(a: list[int] | str, b: list[int] | str) -> int:
    """Levenshtein distance (insertions, deletions, substitutions) between A and B."""
    row = list(range(len(b) + 1))
    for i, ca in enumerate(a, 1):
        prev, row[0] = row[0], i
        for j, cb in enumerate(b, 1):
            prev, row[j] = row[j], min(row[j] + 1, row[j - 1] + 1, prev + (ca != cb))
    return row[-1]


def characters_read_again(ref: np.ndarray, test: np.ndarray) -> tuple[int, int]:
    """Over the sequences of REF (fp32's CTC output) and TEST: the characters read the same (each
    string's length, at least 1, less its edit distance, at least 0) and those lengths summed; their
    ratio is the character accuracy of TEST's strings against REF's."""
    same = total = 0
    for a, b in zip(sequences(ref), sequences(test)):
        read, shown = greedy_ctc(a), greedy_ctc(b)
        length = max(len(read), 1)
        same, total = same + max(0, length - edit_distance(read, shown)), total + length
    return same, total
