"""Activation ranges read off histograms, shared by the torch and the ONNX paths: a `Histogram` of a
tensor's values over every calibration input (exact bins, widened as values arrive), and the
rules that read a range off it (`RangeRule`: minmax, percentile, entropy, mse). Numpy, and
OpenCV to count values into bins."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from edgepick.errors import ParameterError
from edgepick.quant.config import CalibMethod, QuantConfig

BINS = 2048  # per histogram; a range that grows merges bins pairwise, so 1024-2048 of them span the values
CHUNK = 1 << 22  # values binned at once: bounds numpy's temporaries for a large tensor
# values of one tensor counted per input: a larger tensor (a feature map of a megapixel input) is counted at evenly
# spaced places, a million of its values, which still resolves a 99.9999th percentile over a few inputs; its min and
# max stay exact. (Sparser samples miss thin structures: on a text detector, a quarter million per map moved the
# 99.99th and 99.999th percentiles' output SQNR by 2 dB.)
SAMPLED = 1 << 20
UINT8_LEVELS = 255
AUTO_PERCENTILES = (99.99, 99.999, 99.9999)  # with calib_method auto, beside minmax, entropy and mse


def _bin_counts(index: np.ndarray) -> np.ndarray:
    """How many of INDEX (uint16 bin numbers below BINS, at most 2**24 of them) fall in each bin. OpenCV
    counts them as the 2-D histogram of their high and low bytes: a table lookup per byte, faster than
    np.bincount's loop."""
    import cv2

    high_bins = BINS >> 8
    pairs = np.ascontiguousarray(index, dtype="<u2").reshape(1, -1).view(np.uint8).reshape(1, -1, 2)  # low byte first
    counts = cv2.calcHist([pairs], [1, 0], None, [high_bins, 256], [0, high_bins, 0, 256])
    return counts.reshape(-1).astype(np.float64)


def _finite(values: np.ndarray) -> np.ndarray:
    return values if np.isfinite(values).all() else values[np.isfinite(values)]


class Histogram:
    """Min, max and counts of one tensor's values over all calibration tensors. The bins have one
    width; when new values fall outside, the width doubles (neighbouring bins merge exactly)
    until the span holds them, so a widening never moves a value to another bin."""

    __slots__ = ("counts", "lo", "max", "min", "width")

    def __init__(self) -> None:
        self.counts = np.zeros(BINS, np.float64)
        self.lo, self.width = 0.0, 0.0
        self.min, self.max = math.inf, -math.inf

    @classmethod
    def of(cls, counts: np.ndarray, low: float, high: float) -> Histogram:
        """A histogram of len(COUNTS) equal bins from LOW to HIGH (as torch's HistogramObserver keeps one),
        resampled onto BINS bins."""
        hist = cls()
        hist.min, hist.max, hist.lo = low, high, low
        if not np.isfinite([low, high]).all() or high <= low:
            hist.width = 1.0
            hist.counts[0] = counts.sum()
            hist.max = hist.min = low if np.isfinite(low) else 0.0
            return hist
        hist.width = (high - low) / BINS
        source = np.linspace(0.0, BINS, len(counts) + 1)[:-1].astype(int)
        hist.counts = np.bincount(source, weights=counts, minlength=BINS)[:BINS].astype(np.float64)
        return hist

    def even(self) -> Histogram:
        """The same counts on BINS equal bins from min to max (each bin's count spread evenly over
        its width): a grid that depends on the values alone, not on how they arrived."""
        if self.total == 0 or self.max <= self.min:
            return self
        targets = np.linspace(self.min, self.max, BINS + 1)
        cumulative = np.interp(targets, self.edges(), np.concatenate([[0.0], np.cumsum(self.counts)]))
        return Histogram.of(np.diff(cumulative), self.min, self.max)

    @property
    def total(self) -> float:
        return float(self.counts.sum())

    def edges(self) -> np.ndarray:
        return self.lo + self.width * np.arange(BINS + 1, dtype=np.float64)

    def update(self, values: np.ndarray, counts: bool = True) -> None:
        """Count VALUES (any shape) in: all of them, or SAMPLED evenly spaced ones of a larger tensor
        (with its exact min and max); without COUNTS, only their min and max (all minmax needs)."""
        flat = values.reshape(-1)
        if flat.size > SAMPLED or not counts:
            mn, mx = float(flat.min()), float(flat.max())
            if not np.isfinite([mn, mx]).all():
                kept = _finite(flat)
                mn, mx = (float(kept.min()), float(kept.max())) if kept.size else (mn, mx)
            if np.isfinite([mn, mx]).all():
                self.extend(mn, mx)
            if not counts:
                return
            flat = flat[::-(-flat.size // SAMPLED)]
        for start in range(0, flat.size, CHUNK):
            chunk = flat[start:start + CHUNK]
            mn, mx = float(chunk.min()), float(chunk.max())  # NaN or an infinity shows in them
            if not (math.isfinite(mn) and math.isfinite(mx)):
                chunk = _finite(chunk)
                if not chunk.size:
                    continue
                mn, mx = float(chunk.min()), float(chunk.max())
            self._add(chunk, mn, mx)

    def extend(self, mn: float, mx: float) -> None:
        """Widen the bins to hold [MN, MX] and take them as seen extremes."""
        if self.width == 0.0:
            span = mx - mn
            self.width = span / BINS if span > 0 else max(abs(mn), 1.0) * 2.0 ** -30
            self.lo = mn
        self._cover(mn, mx)
        self.min, self.max = min(self.min, mn), max(self.max, mx)

    def _add(self, x: np.ndarray, mn: float, mx: float) -> None:
        """Count the finite values X (whose extremes are MN and MX) into their bins; in float32, as
        they come, a value within its rounding of a bin edge may count in the bin beside it."""
        self.extend(mn, mx)
        index = x - np.float32(self.lo)
        index *= np.float32(1.0 / self.width)
        np.clip(index, 0, BINS - 1, out=index)
        self.counts += _bin_counts(index.astype(np.uint16))

    def _cover(self, mn: float, mx: float) -> None:
        """Widen the bins (by powers of two, old bins merging whole) until [mn, mx] fits."""
        lo, width = self.lo, self.width
        top = lo + BINS * width
        if mn >= lo and mx <= top:  # a value on the top edge counts in the last bin
            return
        want_lo, want_hi = min(mn, lo), max(mx, top)
        shift = 0
        while True:
            wide = width * (1 << shift)
            before = math.ceil((lo - want_lo) / wide)  # new bins in front of the old first one
            if lo - before * wide + BINS * wide >= want_hi:
                break
            shift += 1
        merged = np.bincount(before + (np.arange(BINS) >> shift), weights=self.counts, minlength=BINS)
        self.counts = merged[:BINS].astype(np.float64)
        self.lo, self.width = lo - before * wide, wide


@dataclass(frozen=True)
class RangeRule:
    """How a range is read off a histogram: METHOD, with PERCENTILE for the percentile method."""

    method: CalibMethod
    percentile: float = 99.99

    def __str__(self) -> str:
        return f"percentile {self.percentile:g}" if self.method == CalibMethod.PERCENTILE else str(self.method.value)

    @classmethod
    def parse(cls, text: str) -> RangeRule:
        """The rule str(rule) wrote ("mse", "percentile 99.999")."""
        method, _, percentile = text.partition(" ")
        return cls(CalibMethod(method), float(percentile)) if percentile else cls(CalibMethod(method))

    def pinned(self, config: QuantConfig) -> QuantConfig:
        """CONFIG with this rule as its calibration method: what calib_method auto chose, to make the
        same model again without measuring the candidates again."""
        return replace(config, calib_method=self.method, percentile=self.percentile if
                       self.method == CalibMethod.PERCENTILE else config.percentile)

    def range(self, hist: Histogram) -> tuple[float, float]:
        """The (low, high) range of HIST's tensor by this rule (never beyond its min and max)."""
        if hist.min > hist.max:  # nothing seen
            return 0.0, 0.0
        if self.method == CalibMethod.MINMAX or hist.max == hist.min:
            return hist.min, hist.max
        if self.method == CalibMethod.PERCENTILE:
            return _percentile_range(hist, self.percentile)
        if self.method == CalibMethod.ENTROPY:
            return _entropy_range(hist)
        if self.method == CalibMethod.MSE:
            return _mse_range(hist)
        raise ParameterError("{calib_method}: has no histogram rule", calib_method=self.method)


def _percentile_range(hist: Histogram, percentile: float) -> tuple[float, float]:
    """The PERCENTILE-th value on top and the (100 - PERCENTILE)-th at the bottom (bin edges that
    hold them), as edgepick's torch observers read them."""
    cdf = np.cumsum(hist.counts) / hist.total
    tail = (100.0 - percentile) / 100.0
    edges = hist.edges()
    low = edges[int(np.searchsorted(cdf, tail, side="right"))]
    high = edges[min(int(np.searchsorted(cdf, 1.0 - tail)) + 1, BINS)]
    return max(hist.min, float(low)), min(hist.max, float(high))


def _uint8_error(hist: Histogram, lows: np.ndarray, highs: np.ndarray) -> np.ndarray:
    """Per candidate range, the mean squared error of HIST's values on the uint8 grid onnxruntime
    makes of that range (widened to hold 0, the zero point rounded), clipping included."""
    centres = (hist.edges()[:-1] + hist.width / 2)[None, :]
    weights = hist.counts / hist.total
    lo, hi = np.minimum(lows, 0.0)[:, None], np.maximum(highs, 0.0)[:, None]
    scale = np.maximum((hi - lo) / UINT8_LEVELS, 1e-12)
    zero = np.clip(np.round(-lo / scale), 0, UINT8_LEVELS)
    codes = np.clip(np.round(centres / scale) + zero, 0, UINT8_LEVELS)
    return ((centres - (codes - zero) * scale) ** 2 * weights).sum(axis=1)


def _mse_range(hist: Histogram) -> tuple[float, float]:
    """The range, among tails clipped at 0 to 8% of each end's values, whose uint8 grid gives the
    values the least squared error: the high end first (with the low end at the minimum), then the
    low end with that high end."""
    cdf = np.cumsum(hist.counts) / hist.total
    edges = hist.edges()
    tails = np.geomspace(1e-7, 0.08, 48)
    lows = np.array([hist.min, *(max(hist.min, edges[int(np.searchsorted(cdf, t, side="right"))]) for t in tails)])
    highs = np.array([hist.max, *(min(hist.max, edges[min(int(np.searchsorted(cdf, 1 - t)) + 1, BINS)])
                                  for t in tails)])
    highs = highs[highs > hist.min]
    high = float(highs[int(np.argmin(_uint8_error(hist, np.full(len(highs), hist.min), highs)))])
    lows = lows[lows < high]
    low = float(lows[int(np.argmin(_uint8_error(hist, lows, np.full(len(lows), high))))])
    return low, high


def _entropy_range(hist: Histogram) -> tuple[float, float]:
    """TensorRT's entropy calibration on 256 levels: the clip of the histogram's far end (the upper
    one when the values are mostly positive, else the larger of |low| and high, folded) whose
    quantized distribution is closest to the clipped one in KL divergence."""
    hist = hist.even()  # the KL search steps through bins: the same grid whatever order the values came in
    counts, edges = hist.counts, hist.edges()
    signed = hist.min < 0 and -hist.min > 0.1 * hist.max
    if signed:  # fold |x| onto bins from 0
        top = max(-hist.min, hist.max)
        counts, _ = np.histogram(np.abs(edges[:-1] + hist.width / 2), bins=BINS, range=(0.0, top), weights=counts)
        edges = np.linspace(0.0, top, BINS + 1)
    start = 0 if signed else max(int(np.searchsorted(edges, max(hist.min, 0.0), side="right")) - 1, 0)
    best = _closest_clip(counts, start)
    high = float(edges[min(best, BINS)])
    if signed:
        return max(hist.min, -high), min(hist.max, high)
    return hist.min, min(hist.max, high)


def _closest_clip(counts: np.ndarray, start: int) -> int:
    """The bin, 256 or more past START and in steps of 16, at which COUNTS[START:] clipped (the rest
    piled into its last bin) and spread over 256 levels is closest to the clipped counts in KL
    divergence (the first such bin on a tie; BINS when nothing is counted). Each level spreads its
    count over its non-empty bins, so the divergence needs only cumulative sums per level: every
    candidate clip at once, in a tenth of the time of a loop over them."""
    levels = UINT8_LEVELS + 1
    stops = np.arange(start + levels, BINS + 1, 16)
    rest = counts[start:]
    filled = rest > 0
    cumulative = np.concatenate([[0.0], np.cumsum(rest)])
    total = float(cumulative[-1])
    if not len(stops) or total <= 0:
        return BINS
    nonempty = np.concatenate([[0.0], np.cumsum(filled)])
    xlogx = np.concatenate([[0.0], np.cumsum(np.where(filled, rest * np.log(np.where(filled, rest, 1.0)), 0.0))])
    lengths = stops - start
    bounds = (np.arange(levels + 1)[None, :] * lengths[:, None]) // levels  # each level's first bin, per clip
    mass, used = np.diff(cumulative[bounds], axis=1), np.diff(nonempty[bounds], axis=1)
    log_share = np.where(used > 0, np.log(np.where(mass > 0, mass, 1.0) / np.maximum(used, 1.0)), 0.0)
    window = cumulative[lengths]  # the counts the levels spread; the tail beyond piles into the last bin
    last, tail = rest[lengths - 1], total - window
    end = last + tail
    p_log_p = (xlogx[lengths - 1] + np.where(end > 0, end * np.log(np.where(end > 0, end, 1.0)), 0.0)) / total \
        - math.log(total)
    on_level = last > 0  # the tail shares the last bin's level; on an empty last bin, q is 0 there (1e-12)
    p_log_q = ((mass * log_share).sum(axis=1) + np.where(on_level, tail * log_share[:, -1], 0.0)
               - np.log(np.maximum(window, 1e-12)) * (window + np.where(on_level, tail, 0.0))
               + np.where(~on_level & (tail > 0), tail * math.log(1e-12), 0.0)) / total
    divergence = p_log_p - p_log_q
    least = divergence.min()
    return int(stops[int(np.flatnonzero(divergence <= least + 1e-9 * abs(least) + 1e-15)[0])])


def candidate_rules(config: QuantConfig) -> list[RangeRule]:
    """The rules CONFIG asks for: its own method, or for auto every rule edgepick has (its
    percentile among them)."""
    if config.calib_method != CalibMethod.AUTO:
        return [RangeRule(config.calib_method, config.percentile)]
    percentiles = sorted({*AUTO_PERCENTILES, config.percentile})
    return [RangeRule(CalibMethod.MINMAX), *(RangeRule(CalibMethod.PERCENTILE, p) for p in percentiles),
            RangeRule(CalibMethod.ENTROPY), RangeRule(CalibMethod.MSE)]
