"""The 95% intervals of the cell's rates, against published values: Wilson's score interval for one
rate (Newcombe 1998, "Two-sided confidence intervals for the single proportion", and Fagerland,
Lydersen and Laake's "Statistical Analysis of Contingency Tables", chapter 2) and Newcombe's
square-and-add interval for the difference of two paired rates (Fagerland et al., chapter 8:
complete response before and after consolidation therapy, Cavo et al. 2012)."""

from __future__ import annotations

import pytest

from edgepick.errors import ParameterError
from edgepick.intervals import clustered_difference, equivalence, paired_difference, paired_outcomes, wilson


@pytest.mark.parametrize("successes, total, lower, upper", [
    (81, 263, 0.2553, 0.3662),  # Newcombe 1998, example (a)
    (15, 148, 0.0624, 0.1605),  # (b)
    (0, 20, 0.0, 0.1611),  # (c)
    (1, 29, 0.0061, 0.1718),  # (d)
    (13, 16, 0.5699, 0.9341),  # Fagerland et al.
])
def test_wilson_interval_matches_the_published_values(successes, total, lower, upper):
    lo, hi = wilson(successes, total)
    assert (round(lo, 4), round(hi, 4)) == (lower, upper)


def test_wilson_has_no_interval_without_tries_and_refuses_more_successes_than_tries():
    assert wilson(0, 0) is None
    with pytest.raises(ParameterError, match="successes=5"):
        wilson(5, 3)


def test_paired_difference_matches_newcombes_square_and_add_interval():
    """Cavo et al. 2012: 59 pairs both, 6 the first only, 16 the second only, 80 neither:
    -0.0621 (95% CI -0.1186 to -0.0046)."""
    d, (lo, hi) = paired_difference(59, 6, 16, 80)
    assert (round(d, 4), round(lo, 4), round(hi, 4)) == (-0.0621, -0.1186, -0.0046)
    # the same pairs as outcome lists, try by try
    first = [True] * 59 + [True] * 6 + [False] * 16 + [False] * 80
    second = [True] * 59 + [False] * 6 + [True] * 16 + [False] * 80
    assert paired_outcomes(first, second) == (d, (lo, hi))


def test_pairing_narrows_the_interval_of_a_difference():
    """Two models that agree on every try: the interval of their difference is narrower than either
    rate's own, and centred on 0; flipping their order mirrors it."""
    d, (lo, hi) = paired_difference(470, 0, 0, 30)
    own = wilson(470, 500)
    assert d == 0 and lo < 0 < hi and hi - lo < own[1] - own[0]
    d2, (lo2, hi2) = paired_difference(460, 3, 10, 27)
    d3, (lo3, hi3) = paired_difference(460, 10, 3, 27)
    assert d2 == -d3 and (round(lo2, 12), round(hi2, 12)) == (round(-hi3, 12), round(-lo3, 12))


def test_clustered_difference_pairs_the_rounds():
    """Rounds of different lengths: the difference of the summed rates, an interval around it, and two
    identical runs centred on 0; rounds that disagree more give a wider interval."""
    a = [(7, 7), (5, 6), (9, 10), (4, 4)]
    d, (lo, hi) = clustered_difference(a, a)
    assert d == 0 and lo < 0 < hi
    b = [(6, 7), (5, 7), (8, 10), (4, 4)]
    d, (lo, hi) = clustered_difference(a, b)
    assert d == pytest.approx(25 / 27 - 23 / 28) and lo < d < hi
    c = [(3, 7), (6, 6), (5, 10), (4, 4)]  # as far from A but uncorrelated with it
    assert clustered_difference(a, c)[1][1] - clustered_difference(a, c)[1][0] > hi - lo
    with pytest.raises(ParameterError, match="must pair the same rounds"):
        clustered_difference(a, b[:2])


@pytest.mark.parametrize("interval, verdict", [((-0.004, 0.006), "within"), ((-0.012, 0.003), "undecided"),
                                               ((0.011, 0.03), "outside"), ((-0.05, -0.01), "outside")])
def test_equivalence_reads_an_interval_against_its_margin(interval, verdict):
    assert equivalence(interval, 0.01) == verdict


def test_equivalence_needs_a_positive_margin():
    with pytest.raises(ParameterError, match="margin=0"):
        equivalence((-0.01, 0.01), 0)
