"""How many inputs the checks of an .onnx model's int8 file run on (quant/config.py)."""

from __future__ import annotations

import pytest

from edgepick.quant.config import ACCURACY_CHECK_INPUTS, HELD_OUT_INPUTS, accuracy_check_inputs, check_inputs


@pytest.mark.parametrize(("hw", "expected"), [((48, 320), HELD_OUT_INPUTS), ((480, 640), 8), ((960, 1280), 2),
                                              ((2048, 2048), 2)])
def test_the_fidelity_check_inputs_are_bounded_by_pixels(hw, expected):
    assert check_inputs(*hw) == expected


@pytest.mark.parametrize(("hw", "total", "fitting", "expected"), [
    ((48, 320), 64, 32, ACCURACY_CHECK_INPUTS),  # text lines: enough for the decisions a 99.5% budget needs
    ((48, 320), None, 32, ACCURACY_CHECK_INPUTS),  # an iterator of unknown length
    ((48, 320), 48, 32, 16),  # what the fitting leaves
    ((48, 320), 32, 32, HELD_OUT_INPUTS),  # never fewer than the plain check
    ((800, 608), 64, 5, 20),  # large inputs: bounded by pixels
    ((1024, 1024), 64, 4, 9),
    ((2048, 2048), 64, 4, 2),
])
def test_the_accuracy_aware_mode_checks_on_more_inputs_where_they_are_small(hw, total, fitting, expected):
    assert accuracy_check_inputs(*hw, total, fitting) == expected
