"""Rewrites for int8: the gated hardswish computes what hardswish does and quantizes both halves;
conv biases snapped to onnxruntime's int32 grid."""

from __future__ import annotations

import pytest

from edgepick.geometry import Size


@pytest.mark.slow
def test_gated_hardswish_is_the_same_function_and_quantizes_both_halves():
    """hardswish -> x * hardsigmoid(x): the float outputs do not move, and pt2e then sees a
    hardsigmoid and a mul (both with their own uint8 grid) where it saw one hardswish."""
    import torch

    from edgepick.models import ModelConfig, build_model
    from edgepick.quant.config import Pt2eOptions, QuantConfig
    from edgepick.quant.pt2e.graph import prepare
    from edgepick.quant.pt2e.rewrites import GatedHardswish, gate_hardswish

    torch.manual_seed(0)
    model = build_model(ModelConfig(num_classes=3)).eval()
    x = torch.rand(1, 3, 64, 96) * 255
    with torch.no_grad():
        before = model(x)["out"]
        assert gate_hardswish(model) == 20
        after = model(x)["out"]
    assert torch.allclose(before, after, atol=1e-5)
    assert not any(isinstance(m, torch.nn.Hardswish) for m in model.modules())
    assert sum(isinstance(m, GatedHardswish) for m in model.modules()) == 20
    ops = [str(n.target) for n in prepare(build_model(ModelConfig(num_classes=3)), QuantConfig(), Size(96, 64),
                                          qat=False).graph.nodes]
    assert not any("hardswish" in o for o in ops)
    assert sum("hardsigmoid" in o for o in ops) == 20 + 8  # the gates and the SE blocks
    old = prepare(build_model(ModelConfig(num_classes=3)), QuantConfig(), Size(96, 64), qat=False,
                  pt2e=Pt2eOptions(hardswish_gate=False))
    assert sum("hardswish" in str(n.target) for n in old.graph.nodes) == 20


def test_conv_biases_lie_on_onnxruntimes_int32_grid(trained_run, small_data):
    """convert() snaps each int8 conv's bias to input scale x weight scale, the int32 grid that
    onnxruntime's QLinearConv fusion rounds it to, so that torch simulates the same sums."""
    import torch

    from edgepick.quant.config import QuantConfig
    from edgepick.quant.pt2e.graph import as_input, convert, prepare
    from edgepick.quant.pt2e.images import model_images
    from edgepick.train.checkpoint import load_model

    model, ckpt = load_model(trained_run)
    size = ckpt.input_size
    prepared = prepare(model, QuantConfig(), size, qat=False)
    with torch.no_grad():
        for rgb in model_images(small_data, "train", 2, size):
            prepared(as_input(rgb))
    converted = convert(prepared)
    qd, checked = torch.ops.quantized_decomposed, 0
    params = dict(converted.named_parameters()) | dict(converted.named_buffers())
    for node in converted.graph.nodes:
        if node.target == torch.ops.aten.conv2d.default and node.args[0].target == qd.dequantize_per_tensor.default:
            w_scale = params[node.args[1].args[1].target]
            steps = params[node.args[2].target] / (torch.tensor(node.args[0].args[1]) * w_scale)
            assert torch.allclose(steps, steps.round(), atol=1e-3), node.name
            checked += 1
    assert checked == 70
