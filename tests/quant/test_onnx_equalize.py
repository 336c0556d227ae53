"""Cross-layer equalization of a float ONNX model: the planted 100x imbalance of test_equalize
exported by torch, equalized on the ONNX graph without changing its float outputs, and the int8
file onnxruntime runs closer to fp32 for it."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest

from edgepick.onnx_graph import Graph
from edgepick.quant import PtqMethods, quantize_onnx_static
from edgepick.quant.onnx.equalize import equalize_onnx
from edgepick.quant.onnx.rewrite import conv_params
from tests.quant.onnx_models import export_module, image_tensors, run
from tests.quant.test_equalize import Imbalanced


def _export(path):
    return export_module(Imbalanced(), path)


def _tensors(count=6):
    return image_tensors(count)


def test_the_onnx_graph_is_equalized_with_the_same_outputs(tmp_path):
    path = _export(tmp_path / "f.onnx")
    model = onnx.load(str(path))
    g = Graph(model)
    first = next(n for n in g.graph.node if n.op_type == "Conv")
    before = np.abs(conv_params(g, first)[0]).max(axis=(1, 2, 3))
    assert before.max() / before.min() > 30  # the exporter folded the planted BatchNorm gains into the conv
    assert equalize_onnx(model) == 2
    g = Graph(model)
    after = np.abs(conv_params(g, first)[0]).max(axis=(1, 2, 3))
    assert after.max() / after.min() < 4, after
    onnx.save(model, str(tmp_path / "e.onnx"))
    x = _tensors(1)[0]
    np.testing.assert_allclose(run(tmp_path / "e.onnx", x)[0], run(path, x)[0], atol=1e-4)


@pytest.mark.slow
def test_an_equalized_onnx_model_quantizes_closer_to_fp32(tmp_path):
    path = _export(tmp_path / "f.onnx")
    tensors = _tensors()
    error = {}
    for equalize in (False, True):
        out = tmp_path / f"int8-{equalize}.onnx"
        result = quantize_onnx_static(path, tensors, out, methods=PtqMethods(equalize=equalize), progress=False)
        error[equalize] = sum(float(((run(out, x)[0] - run(path, x)[0]) ** 2).mean()) for x in tensors)
        if equalize:
            quant = json.loads({p.key: p.value for p in onnx.load(str(out)).metadata_props}["edgepick.quant"])
            assert quant["equalize"] and quant["equalized_pairs"] == 2 and result.int8_convs == 3
    assert error[True] < error[False] / 2, error
