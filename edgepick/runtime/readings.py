"""Histograms and order statistics of an object's depth readings, worked on its distinct readings
and their counts: a depth camera's readings are integers, so a few hundred distinct values stand for
thousands of pixels. Each result is, to the last bit, what np.histogram, np.median and np.percentile
give on every pixel's value (tests/runtime/test_readings.py checks it), at a fraction of the cost.
numpy only."""

from __future__ import annotations

import math

import numpy as np


def readings(units: np.ndarray, scale: float, dtype: type = np.float64) -> tuple[np.ndarray, np.ndarray]:
    """(values, counts) of 1-D integer depth UNITS: each distinct reading once, ascending, as
    `units.astype(dtype) * scale` makes it, and how many pixels hold it."""
    found = np.bincount(units)
    distinct = np.flatnonzero(found)
    return distinct.astype(dtype) * scale, found[distinct]


def histogram(vals: np.ndarray, counts: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray]:
    """np.histogram(..., bins) of the multiset (VALS sorted and distinct, each COUNTS times): the same
    edges and the same bin for every value, by numpy's own arithmetic (numpy/lib/_histograms_impl.py)."""
    first, last = vals[0], vals[-1]
    if first == last:
        first, last = first - 0.5, last + 0.5
    edges = np.arange(bins + 1, dtype=vals.dtype)  # np.linspace(first, last, bins + 1)'s own steps, without
    edges *= (last - first) / bins  # its overhead (a third of an object's depth estimate)
    edges += first
    edges[-1] = last
    index = (((vals - first) / (last - first)) * bins).astype(np.intp)
    index[index == bins] -= 1
    index[vals < edges[index]] -= 1  # within ~1 ULP of an edge
    index[(vals >= edges[index + 1]) & (index != bins - 1)] += 1
    return np.bincount(index, weights=counts, minlength=bins).astype(counts.dtype), edges


def _ranked(vals: np.ndarray, counts: np.ndarray, ranks: tuple[int, ...]) -> list[float]:
    """The values at RANKS (0-based) of the multiset with sorted distinct VALS, each COUNTS times."""
    where = np.searchsorted(np.cumsum(counts), ranks, side="right")
    return [float(vals[k]) for k in where]


def median(vals: np.ndarray, counts: np.ndarray) -> float:
    """np.median of the multiset (VALS sorted, each COUNTS times), computed as numpy does."""
    n = int(counts.sum())
    if n % 2:
        return _ranked(vals, counts, (n // 2,))[0]
    a, b = _ranked(vals, counts, (n // 2 - 1, n // 2))
    return (a + b) / 2


def percentile_25(vals: np.ndarray, counts: np.ndarray) -> float:
    """np.percentile(..., 25.0) (linear) of the multiset (VALS sorted, each COUNTS times), as numpy computes it."""
    n = int(counts.sum())
    virtual = (n - 1) * 0.25
    below = math.floor(virtual)
    if virtual >= n - 1:
        return _ranked(vals, counts, (n - 1,))[0]
    a, b = _ranked(vals, counts, (below, below + 1))
    t = virtual - below
    diff = b - a
    return b - diff * (1 - t) if t >= 0.5 else a + diff * t
