"""runtime/readings.py: on distinct readings and their counts, numpy's histogram, median and 25th
percentile of every pixel's value, to the last bit, in float64 and (the histogram) float32."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from edgepick.runtime.readings import histogram, median, percentile_25, readings


@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 3000), spread=st.sampled_from([0, 1, 3, 8, 40, 400, 5000]),
       scale=st.sampled_from([0.001, 0.0001, 0.000125, 0.00025]))
def test_the_counted_statistics_are_numpys_on_every_pixel(seed, n, spread, scale):
    rng = np.random.default_rng(seed)
    units = (int(rng.integers(1, 9000)) + rng.integers(0, spread + 1, n)).astype(np.uint16)
    for dtype in (np.float64, np.float32):
        vals, counts = readings(units, scale, dtype)
        pixels = units.astype(dtype) * scale
        assert np.array_equal(np.repeat(vals, counts), np.sort(pixels))
        for bins in (1, 2, 7, int(rng.integers(1, 500)), int((pixels.max() - pixels.min()) / (0.008 / 2)) + 1):
            hist, edges = histogram(vals, counts, bins)
            expected = np.histogram(pixels, bins=bins)
            assert np.array_equal(hist, expected[0]) and np.array_equal(edges, expected[1])
            assert edges.dtype == expected[1].dtype
    vals, counts = readings(units, scale)
    pixels = units.astype(np.float64) * scale
    assert median(vals, counts) == float(np.median(pixels))
    assert percentile_25(vals, counts) == float(np.percentile(pixels, 25.0))
    some = rng.random(vals.size) < 0.5
    if some.any():
        assert median(vals[some], counts[some]) == float(np.median(np.repeat(vals[some], counts[some])))
        assert percentile_25(vals[some], counts[some]) == float(np.percentile(np.repeat(vals[some], counts[some]), 25.0))
