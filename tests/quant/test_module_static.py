"""Static PTQ of an nn.Module edgepick did not build, and the pt2e verbs on it for a loop of one's own."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from edgepick.errors import ParameterError
from edgepick.geometry import Size
from edgepick.quant import QuantConfig, convert, prepare, quantize_module_static
from tests.quant.onnx_models import calib_tensors, run, torch_net


class TinyUNet(nn.Module):
    """Not a DeepLabV3: an encoder-decoder with skip connections, BatchNorm and nn.Hardswish, giving
    a torchvision-style {"out": ...} dict."""

    def __init__(self, classes: int = 3):
        super().__init__()
        self.down = nn.Sequential(nn.Conv2d(3, 8, 3, 2, 1), nn.BatchNorm2d(8), nn.Hardswish())
        self.mid = nn.Sequential(nn.Conv2d(8, 16, 3, 2, 1), nn.BatchNorm2d(16), nn.ReLU())
        self.up = nn.ConvTranspose2d(16, 8, 2, 2)
        self.head = nn.Conv2d(16, classes, 1)

    def forward(self, x):
        skip = self.down(x)
        y = torch.cat([self.up(self.mid(skip)), skip], 1)
        return {"out": nn.functional.interpolate(self.head(y), size=x.shape[-2:], mode="bilinear")}


def _net() -> TinyUNet:
    torch.manual_seed(0)
    net = TinyUNet().eval()
    for bn in (net.down[1], net.mid[1]):
        bn.running_mean.uniform_(-0.3, 0.3)
        bn.running_var.uniform_(0.5, 2.0)
    return net


def test_a_module_of_ones_own_becomes_an_int8_onnx_and_stays_as_it_was(tmp_path):
    net = _net()
    before = {k: v.clone() for k, v in net.state_dict().items()}
    batches = [torch.from_numpy(x) for x in calib_tensors(8)]
    result = quantize_module_static(net, batches, tmp_path / "u.onnx", QuantConfig(), input_shape=(1, 3, 64, 96),
                             progress=False)
    assert result.quant["source"] == "module" and result.calib_tensors == 8 and result.opset_in is None
    # the transposed conv stays float: edgepick's quantizer marks convs, and onnxruntime has no integer
    # ConvTranspose kernel to run it on anyway
    assert result.convs == 4 and result.int8_convs == 3 and result.float_convs == ["node_convolution"]  # the ConvTranspose
    assert result.rewrites == {"gated_hardswish": 1}
    assert result.agreement_vs_fp32["output"] >= 0.97, result.agreement_vs_fp32
    assert isinstance(net.down[2], nn.Hardswish)  # the caller's module is not changed
    assert all(torch.equal(before[k], v) for k, v in net.state_dict().items())
    x = calib_tensors(1, seed=9)[0]
    assert run(tmp_path / "u.onnx", x)[0].shape == (1, 3, 64, 96)


def test_a_tensor_output_module_and_bad_batches(tmp_path):
    net = torch_net(out_channels=1, sigmoid=True)  # a one-channel probability map, as a tensor
    arrays = calib_tensors(4)  # numpy arrays without torch are taken too
    result = quantize_module_static(net, arrays, tmp_path / "s.onnx", progress=False)
    assert result.input_shape == [1, 3, 64, 96] and result.agreement_vs_fp32["output"] >= 0.97
    for bad, message in (([], "no batches"), ([arrays[0].astype(np.int32)], "float array"),
                         ([arrays[0], arrays[0][:, :, :32]], "batch 2 has shape")):
        with pytest.raises(ParameterError, match=message):
            quantize_module_static(net, bad, tmp_path / "bad.onnx", progress=False)
    assert not (tmp_path / "bad.onnx").exists()


def test_the_verbs_work_on_a_module_of_ones_own():
    """prepare -> batches of one's own through the observed graph -> convert, as a loop of one's own would."""
    net = _net()
    observed = prepare(net, QuantConfig(), Size(96, 64), qat=False)
    with torch.no_grad():
        for x in calib_tensors(4):
            observed(torch.from_numpy(x))
    int8 = convert(observed)
    x = torch.from_numpy(calib_tensors(1, seed=4)[0])
    with torch.no_grad():
        ref, ours = net(x)["out"], int8(x)
    assert (ours.argmax(1) == ref.argmax(1)).float().mean() >= 0.95
