"""Histograms of activations over every calibration input, and the range rules read off them (quant/ranges.py)."""

from __future__ import annotations

import numpy as np
import pytest

from edgepick.errors import ParameterError
from edgepick.quant.config import CalibMethod, QuantConfig
from edgepick.quant.ranges import BINS, Histogram, RangeRule, candidate_rules


def _parts(seed: int = 0) -> list[np.ndarray]:
    """Values whose range grows from part to part, so that the histogram is widened several times."""
    rng = np.random.default_rng(seed)
    return [rng.normal(shift, scale, 50_000).astype(np.float32)
            for shift, scale in ((0.0, 0.01), (0.5, 1.0), (-3.0, 5.0), (0.0, 0.5), (40.0, 30.0))]


def test_streamed_bins_count_every_value_where_one_histogram_of_all_would():
    hist = Histogram()
    for part in _parts():
        hist.update(part)
    values = np.concatenate(_parts()).astype(np.float64)
    assert hist.total == values.size
    assert (hist.min, hist.max) == (values.min(), values.max())
    reference, _ = np.histogram(values, bins=hist.edges())
    # a value on a bin edge may land in the bin beside it (float32 index arithmetic), never further
    assert np.abs(np.cumsum(reference) - np.cumsum(hist.counts)).max() <= 2
    assert hist.width < (values.max() - values.min()) / (BINS / 2) * 1.0001  # widened no more than needed


@pytest.mark.parametrize("percentile", [99.0, 99.99, 99.999])
def test_the_percentile_rule_reads_numpys_percentiles_to_a_bin(percentile):
    hist = Histogram()
    for part in _parts(1):
        hist.update(part)
    low, high = RangeRule(CalibMethod.PERCENTILE, percentile).range(hist)
    # the bin that holds each order statistic: numpy's percentile of the inverted CDF, to a bin
    ref_low, ref_high = np.percentile(np.concatenate(_parts(1)), [100 - percentile, percentile], method="inverted_cdf")
    assert abs(low - ref_low) <= 1.01 * hist.width and abs(high - ref_high) <= 1.01 * hist.width


def test_minmax_is_exact_and_mse_has_the_least_error_on_the_uint8_grid():
    from edgepick.quant.ranges import _uint8_error

    hist = Histogram()
    relu = np.maximum(np.random.default_rng(2).standard_t(3, 200_000), 0).astype(np.float32)
    hist.update(relu)
    assert RangeRule(CalibMethod.MINMAX).range(hist) == (0.0, float(relu.max()))
    ranges = {m: RangeRule(m).range(hist) for m in (CalibMethod.MINMAX, CalibMethod.PERCENTILE, CalibMethod.ENTROPY,
                                                   CalibMethod.MSE)}
    for low, high in ranges.values():
        assert 0.0 <= low < high <= relu.max()  # inside the values' own range, never below the ReLU's 0
    error = {m: float(_uint8_error(hist, np.array([r[0]]), np.array([r[1]]))[0]) for m, r in ranges.items()}
    assert error[CalibMethod.MSE] == min(error.values()), error
    assert ranges[CalibMethod.PERCENTILE][1] < relu.max()  # the percentile clips the tail


def test_a_constant_tensor_and_an_empty_one():
    hist = Histogram()
    hist.update(np.full(100, 3.5, np.float32))
    hist.update(np.full(10, 3.5, np.float32))
    for method in CalibMethod:
        if method != CalibMethod.AUTO:
            assert RangeRule(method).range(hist) == (3.5, 3.5)
    assert RangeRule(CalibMethod.MINMAX).range(Histogram()) == (0.0, 0.0)
    with_nan = Histogram()
    with_nan.update(np.array([1.0, np.nan, 2.0, np.inf], np.float32))
    assert (with_nan.min, with_nan.max, with_nan.total) == (1.0, 2.0, 2.0)


def test_a_torch_observers_histogram_reads_the_same():
    values = np.random.default_rng(3).normal(0, 1, 100_000)
    counts, edges = np.histogram(values, bins=BINS)
    hist = Histogram.of(counts.astype(np.float64), float(edges[0]), float(edges[-1]))
    low, high = RangeRule(CalibMethod.PERCENTILE, 99.9).range(hist)
    ref = np.percentile(values, [0.1, 99.9])
    assert abs(low - ref[0]) <= 2.01 * hist.width and abs(high - ref[1]) <= 2.01 * hist.width


def test_auto_tries_every_rule_with_the_configured_percentile():
    rules = candidate_rules(QuantConfig(percentile=99.5))
    assert [str(r) for r in rules] == ["minmax", "percentile 99.5", "percentile 99.99", "percentile 99.999",
                                      "percentile 99.9999", "entropy", "mse"]
    assert candidate_rules(QuantConfig(calib_method="mse")) == [RangeRule(CalibMethod.MSE, 99.99)]
    with pytest.raises(ParameterError, match="calib_method"):
        RangeRule(CalibMethod.AUTO).range(Histogram.of(np.ones(BINS), 0.0, 1.0))


def test_a_large_tensor_is_counted_at_evenly_spaced_places_with_its_exact_extremes():
    from edgepick.quant.ranges import SAMPLED

    values = np.random.default_rng(4).standard_t(4, 3 * SAMPLED + 17).astype(np.float32)
    values[-1] = 500.0  # the one extreme value is never skipped by the sampling
    hist = Histogram()
    hist.update(values)
    assert SAMPLED // 2 <= hist.total <= SAMPLED and (hist.min, hist.max) == (float(values.min()), 500.0)
    assert RangeRule(CalibMethod.MINMAX).range(hist) == (float(values.min()), 500.0)
    low, high = RangeRule(CalibMethod.PERCENTILE, 99.9).range(hist)
    ref = np.percentile(values, [0.1, 99.9])
    slack = 2 * hist.width  # the bins span the one extreme value: each is wide
    assert abs(low - ref[0]) < 0.05 * abs(ref[0]) + slack and abs(high - ref[1]) < 0.05 * ref[1] + slack


def _divergence_by_loop(counts: np.ndarray, start: int, stop: int) -> float:
    """TensorRT's entropy calibration written out for one clip: the clipped counts against them spread
    over 256 levels, each level's count shared by its non-empty bins."""
    window = counts[start:stop]
    p = window.copy()
    p[-1] += counts[stop:].sum()
    bounds = np.linspace(0, len(window), 257).astype(int)[:-1]
    mass = np.add.reduceat(window, bounds)
    used = np.add.reduceat((window > 0).astype(np.float64), bounds)
    q = np.repeat(mass / np.maximum(used, 1.0), np.diff(np.append(bounds, len(window)))) * (window > 0)
    p, q = p / p.sum(), q / max(q.sum(), 1e-12)
    mask = p > 0
    return float(np.sum(p[mask] * np.log(p[mask] / np.maximum(q[mask], 1e-12))))


@pytest.mark.parametrize("kind", ["normal", "heavy tail", "outliers", "sparse"])
def test_the_entropy_clip_is_the_one_a_loop_over_every_clip_finds(kind):
    from edgepick.quant.ranges import _closest_clip

    rng = np.random.default_rng(3)
    values = {"normal": lambda: rng.standard_normal(100_000),
              "heavy tail": lambda: np.abs(rng.standard_cauchy(50_000)),
              "outliers": lambda: np.concatenate([rng.exponential(1, 50_000), rng.uniform(0, 50, 20)]),
              "sparse": lambda: np.round(rng.standard_normal(20_000) * 3)}[kind]()
    for start in (0, 300):
        counts = np.histogram(values, bins=BINS)[0].astype(np.float64)
        counts[rng.integers(0, BINS, 200)] = 0  # empty bins inside the window too
        divergences = {stop: _divergence_by_loop(counts, start, stop) for stop in range(start + 256, BINS + 1, 16)}
        least = min(divergences.values())
        first = next(stop for stop, d in divergences.items() if d <= least + 1e-9 * abs(least) + 1e-15)
        assert _closest_clip(counts, start) == first
