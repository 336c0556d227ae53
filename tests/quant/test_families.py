"""Every model family through edgepick's passes (models/zoo.py): trained by edgepick's own loop for
one step (a batch of 4 images), exported in fp32 and as static int8 with every conv int8, the int8
file's labels agreeing with torch's simulation of it, and both files run by the runtime like any
edgepick model. DeepLabV3 on MobileNetV3 takes the same paths in test_passes.py. The two ResNet-101
families are the documented exceptions: they differ from the ResNet-50 ones in their block count
only (the same modules, so the same quantizer patterns; models/test_zoo.py builds and trains them)."""

from __future__ import annotations

import numpy as np
import pytest

from edgepick.evaluation import evaluate
from edgepick.export.onnx_export import export_checkpoint
from edgepick.geometry import Size
from edgepick.quant.pt2e.images import folder_images
from edgepick.quant.pt2e.passes import quantize_static
from edgepick.runtime.session import Segmenter
from edgepick.train.loop import TrainConfig, train

FAMILIES = ["lraspp-mobilenetv3", "fcn-resnet50", "deeplabv3-resnet50", "unet", "segnet", "ddrnet23-slim"]


@pytest.mark.slow
@pytest.mark.parametrize("arch", FAMILIES)
def test_a_family_trains_exports_and_quantizes_with_every_conv_int8(arch, small_data, tmp_path):
    run = tmp_path / "run"
    train(TrainConfig(data=str(small_data), out=str(run), arch=arch, epochs=1, batch_size=4, size=Size(64, 48),
                      lr=3e-3, device="cpu", epoch_images=4, val_images=4), progress=False)
    fp32 = export_checkpoint(run, tmp_path / "fp32.onnx")
    images = folder_images(small_data, count=8)
    result = quantize_static(run, images, tmp_path / "int8.onnx", progress=False)
    assert result.int8_convs == result.convs > 0 and result.float_convs == []
    assert result.agreement_vs_torch >= 0.995
    for path in (fp32.out, result.out):
        labels = Segmenter(path, threads=1).labels(images[0])
        assert labels.shape == images[0].shape[:2] and labels.dtype == np.uint8
    assert 0 <= evaluate(result.out, small_data, "val", progress=False)["miou"] <= 1
