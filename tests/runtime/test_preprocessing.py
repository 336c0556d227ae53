"""Preprocessing: a camera image as a foreign model's float input."""

from __future__ import annotations

import numpy as np
import pytest

from edgepick.errors import ParameterError
from edgepick.geometry import Size
from edgepick.runtime.preprocessing import Preprocessing


def test_channels_scale_mean_std_and_layout_in_that_order():
    rgb = np.zeros((2, 4, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 255, 51, 0  # red, a little green, no blue
    prep = Preprocessing(channels="bgr", scale=1 / 255, mean=(0.5, 0.2, 0.0), std=(0.5, 0.1, 1.0), layout="nchw")
    x = prep.tensor(rgb, Size(4, 2))
    assert x.shape == (1, 3, 2, 4) and x.dtype == np.float32
    # channel 0 is blue now: (0 - 0.5) / 0.5; channel 1 green: (0.2 - 0.2) / 0.1; channel 2 red: (1 - 0) / 1
    np.testing.assert_allclose(x[0, :, 0, 0], [-1.0, 0.0, 1.0], atol=1e-6)
    nhwc = Preprocessing(layout="nhwc").tensor(rgb, Size(2, 1))  # area-resized to 2x1
    assert nhwc.shape == (1, 1, 2, 3) and Preprocessing(layout="nhwc").input_shape(Size(2, 1)) == (1, 1, 2, 3)
    np.testing.assert_allclose(nhwc[0, 0, 0], [1.0, 0.2, 0.0], atol=1e-6)


@pytest.mark.parametrize("kwargs, name", [({"scale": 0.0}, "scale"), ({"std": (1, 0, 1)}, "std"),
                                          ({"mean": (0, 0)}, "mean"), ({"channels": "rgba"}, "channels"),
                                          ({"layout": "chw"}, "layout"), ({"mean": (0, float("nan"), 0)}, "mean")])
def test_a_bad_value_is_refused_naming_its_parameter(kwargs, name):
    with pytest.raises(ParameterError, match=f"^{name}="):
        Preprocessing(**kwargs)
