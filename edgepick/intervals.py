"""Confidence intervals for the rates the cell reports (standard library only).

A success rate is a count of successes over a count of tries, and a handful of tries says little:
every rate `pick` and `bench --cell` print carries a 95% interval. For one rate it is Wilson's
score interval, which stays inside [0, 1] and keeps its coverage near 0 and 1, where the cell's
rates lie. For two models run on the same scenes the question is their difference, and the
scenes pair them: Newcombe's square-and-add interval (his method 10: each rate's Wilson interval,
combined with the correlation of the paired outcomes) uses that pairing, which two separate
intervals would throw away. Clutter-removal rounds pair the models by round, not by pick (after
the first pick two models may face different scenes); there the same construction takes the
correlation of the two rates across the rounds. `equivalence` turns a difference's interval into
the statement a comparison needs: within a stated margin, outside it, or not decided by the data.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from statistics import NormalDist

from edgepick.errors import ParameterError

LEVEL = 0.95


def _z(level: float) -> float:
    if not 0 < level < 1:
        raise ParameterError("{level}: must be in (0, 1)", level=level)
    return NormalDist().inv_cdf(0.5 + level / 2)


def wilson(successes: int, total: int, level: float = LEVEL) -> tuple[float, float] | None:
    """Wilson's score interval (lower, upper) of SUCCESSES out of TOTAL at LEVEL; None for no tries."""
    if not 0 <= successes <= total:
        raise ParameterError("{successes}: must be between 0 and {total}", successes=successes, total=total)
    if total == 0:
        return None
    z, p = _z(level), successes / total
    z2n = z * z / total
    centre = (p + z2n / 2) / (1 + z2n)
    half = z / (1 + z2n) * math.sqrt(p * (1 - p) / total + z2n / (4 * total))
    return max(0.0, centre - half), min(1.0, centre + half)


def _square_and_add(p1: float, ci1: tuple[float, float], p2: float, ci2: tuple[float, float],
                    correlation: float) -> tuple[float, float]:
    """The interval of p1 - p2 from each rate's own interval and the correlation of the two estimates."""
    (l1, u1), (l2, u2) = ci1, ci2
    d = p1 - p2
    down = math.sqrt(max(0.0, (p1 - l1) ** 2 + (u2 - p2) ** 2 - 2 * correlation * (p1 - l1) * (u2 - p2)))
    up = math.sqrt(max(0.0, (p2 - l2) ** 2 + (u1 - p1) ** 2 - 2 * correlation * (p2 - l2) * (u1 - p1)))
    return max(-1.0, d - down), min(1.0, d + up)


def paired_difference(both: int, first_only: int, second_only: int, neither: int,
                      level: float = LEVEL) -> tuple[float, tuple[float, float]] | None:
    """The difference of two success rates measured on the same tries (rate of the first minus rate
    of the second) and Newcombe's square-and-add interval of it, from the paired counts: tries both
    passed, only the first, only the second, neither. None for no tries."""
    counts = {"both": both, "first_only": first_only, "second_only": second_only, "neither": neither}
    for name, value in counts.items():
        if value < 0:
            raise ParameterError(f"{{{name}}}: must be 0 or more", **{name: value})
    n = both + first_only + second_only + neither
    if n == 0:
        return None
    first, second = both + first_only, both + second_only
    p1, p2 = first / n, second / n
    margins = first * (n - first) * second * (n - second)
    phi = 0.0
    if margins:
        a = both * neither - first_only * second_only
        phi = (a - n / 2) / math.sqrt(margins) if a > n / 2 else min(a, 0) / math.sqrt(margins)
    first_ci, second_ci = wilson(first, n, level), wilson(second, n, level)
    assert first_ci is not None and second_ci is not None, "n > 0: each rate has its interval"
    return p1 - p2, _square_and_add(p1, first_ci, p2, second_ci, phi)


def paired_outcomes(first: Sequence[bool], second: Sequence[bool],
                    level: float = LEVEL) -> tuple[float, tuple[float, float]] | None:
    """paired_difference of two lists of outcomes, try by try (the same scenes in the same order)."""
    if len(first) != len(second):
        raise ParameterError("{first:name} and {second:name} must pair the same tries (lengths {first} and {second})",
                             first=len(first), second=len(second))
    pairs = list(zip(first, second))
    return paired_difference(sum(a and b for a, b in pairs), sum(a and not b for a, b in pairs),
                             sum(b and not a for a, b in pairs), sum(not a and not b for a, b in pairs), level)


def clustered_difference(first: Sequence[tuple[int, int]], second: Sequence[tuple[int, int]],
                         level: float = LEVEL) -> tuple[float, tuple[float, float]] | None:
    """The difference of two success rates each summed over the same clusters (rounds: each entry a
    round's (successes, tries)), and the square-and-add interval of it: each rate's Wilson interval
    over its tries, with the correlation of the two rates across the clusters (that of their
    linearized per-cluster residuals, successes - rate x tries; 0 where either has no spread).
    None when either has no tries."""
    if len(first) != len(second):
        raise ParameterError("{first:name} and {second:name} must pair the same rounds (lengths {first} and {second})",
                             first=len(first), second=len(second))
    s1, n1 = sum(s for s, _ in first), sum(n for _, n in first)
    s2, n2 = sum(s for s, _ in second), sum(n for _, n in second)
    if n1 == 0 or n2 == 0:
        return None
    p1, p2 = s1 / n1, s2 / n2
    r1 = [s - p1 * n for s, n in first]
    r2 = [s - p2 * n for s, n in second]
    spread = math.sqrt(sum(v * v for v in r1) * sum(v * v for v in r2))
    correlation = sum(a * b for a, b in zip(r1, r2)) / spread if spread > 1e-12 else 0.0
    first_ci, second_ci = wilson(s1, n1, level), wilson(s2, n2, level)
    assert first_ci is not None and second_ci is not None, "n1, n2 > 0: each rate has its interval"
    return p1 - p2, _square_and_add(p1, first_ci, p2, second_ci, correlation)


def equivalence(interval: tuple[float, float], margin: float) -> str:
    """What a difference's interval says against +-MARGIN: "within" (the whole interval inside it),
    "outside" (the whole interval beyond it) or "undecided" (it reaches across the margin)."""
    if not (math.isfinite(margin) and margin > 0):
        raise ParameterError("{margin}: must be a positive number", margin=margin)
    lo, hi = interval
    if -margin <= lo and hi <= margin:
        return "within"
    if lo >= margin or hi <= -margin:
        return "outside"
    return "undecided"


def rounded(interval: tuple[float, float] | None, digits: int = 4) -> list[float] | None:
    """An interval as the JSON reports write it: [lower, upper] rounded, or None."""
    return None if interval is None else [round(interval[0], digits), round(interval[1], digits)]
