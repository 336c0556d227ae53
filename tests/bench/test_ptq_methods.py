"""benchmarks/ptq_methods.py: the cases it compares, each a QuantConfig."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import ptq_methods  # noqa: E402

from edgepick.quant.config import QuantConfig  # noqa: E402


@pytest.mark.parametrize("text, equalize, adaround, percentile", [
    ("7/none", False, False, QuantConfig.percentile),
    ("7/empirical/cle+ada", True, True, QuantConfig.percentile),
    ("first-7/none/p99.999", False, False, 99.999),
    ("8/fast/ada+p99.9", False, True, 99.9),
])
def test_a_case_names_its_methods_and_percentile(text, equalize, adaround, percentile, tmp_path):
    out, configs = ptq_methods.start_case(0, ptq_methods.case(text), tmp_path, 5.0)
    config, methods = configs["config"], configs["methods"]
    assert (methods.equalize, methods.adaround, config.percentile) == (equalize, adaround, percentile)
    assert config.weight_bits == text.split("/")[0] and methods.bias_correction == text.split("/")[1]
    assert out.parent == tmp_path


@pytest.mark.parametrize("text", ["7/none/x", "7/none/cle/ada", "7/none/cle+cle", "7/none/p", "9/none", "7/odd"])
def test_a_bad_case_is_refused(text):
    with pytest.raises((SystemExit, ValueError)):
        ptq_methods.case(text)
