"""Int8 passes: one verb per kind of model, each taking the configs it uses.

- edgepick's own checkpoints, on torchao's pt2e flow (quant/pt2e/): `quantize_static`,
  `quantize_qat`, `quantize_hybrid`, as onnxruntime's quantize.py has them; and torchao's verbs for
  a loop of your own (`prepare`, `calibrate`, `convert`; `QatHooks` brings a QaT graph's needs to
  edgepick's `fit`).
- an nn.Module of one's own: `quantize_module_static` (the same pt2e flow).
- a float ONNX file from any exporter: `quantize_onnx_static` (quant/onnx/, no torch).

Every pass takes a `QuantConfig` (weight bits, calibration method, percentile, what stays float);
the static passes `PtqMethods`, the ONNX pass `OnnxOptions`, the QaT passes `QatOptions`, the torch
passes `Pt2eOptions`. Calibration data is the caller's: any iterable of HxWx3 uint8 RGB images for
a checkpoint (`folder_images` draws them from a data set), the model's own input batches for a
model from elsewhere (`folder_tensors` reads them from a folder).
"""

from typing import TYPE_CHECKING

from edgepick.errors import QuantizationError
from edgepick.lazy import lazy_attributes

_WHERE = {
    "AccuracyAwareResult": "results", "BiasCorrection": "config", "CalibMethod": "config",
    "FidelityBudget": "onnx.accuracy", "GeluForm": "config", "OnnxOptions": "config", "OnnxPassResult": "results",
    "PassResult": "results", "Placement": "config", "Pt2eOptions": "config", "PtqMethods": "config",
    "QatHooks": "pt2e.qat", "QatOptions": "config", "QuantConfig": "config", "Target": "config", "Task": "fidelity",
    "WeightBits": "config", "agreement_images": "pt2e.images", "calibrate": "pt2e.graph", "convert": "pt2e.graph",
    "folder_images": "pt2e.images", "folder_tensors": "onnx.inputs", "inspect": "pt2e.inspect", "prepare": "pt2e.graph",
    "quantize_accuracy_aware": "pt2e.inspect", "quantize_hybrid": "pt2e.passes",
    "quantize_module_static": "pt2e.module_static", "quantize_onnx_static": "onnx.static",
    "quantize_qat": "pt2e.passes", "quantize_static": "pt2e.passes", "run_images": "pt2e.images",
}
__all__ = sorted([*_WHERE, "QuantizationError"])

if TYPE_CHECKING:
    from edgepick.quant.config import (
        BiasCorrection,
        CalibMethod,
        GeluForm,
        OnnxOptions,
        Placement,
        Pt2eOptions,
        PtqMethods,
        QatOptions,
        QuantConfig,
        Target,
        WeightBits,
    )
    from edgepick.quant.fidelity import Task
    from edgepick.quant.onnx.accuracy import FidelityBudget
    from edgepick.quant.onnx.inputs import folder_tensors
    from edgepick.quant.onnx.static import quantize_onnx_static
    from edgepick.quant.pt2e.graph import calibrate, convert, prepare
    from edgepick.quant.pt2e.images import agreement_images, folder_images, run_images
    from edgepick.quant.pt2e.inspect import inspect, quantize_accuracy_aware
    from edgepick.quant.pt2e.module_static import quantize_module_static
    from edgepick.quant.pt2e.passes import quantize_hybrid, quantize_qat, quantize_static
    from edgepick.quant.pt2e.qat import QatHooks
    from edgepick.quant.results import AccuracyAwareResult, OnnxPassResult, PassResult


__getattr__ = lazy_attributes(__name__, _WHERE)
