"""Int8 passes (static PTQ, QaT, hybrid-QaT) on torchao's pt2e flow, and the verbs they are made of.

One function per pass, as onnxruntime's quantize.py has them (`quantize_static`, `quantize_qat`,
`quantize_hybrid`, each with a `QuantConfig`); and torchao's verbs for a loop of your own
(`prepare`, `calibrate`, `convert`; `QatHooks` brings a QaT graph's needs to edgepick's `fit`).
Calibration data is the caller's: any iterable of HxWx3 uint8 RGB images (`folder_images` draws
them from a data set). A model edgepick did not make, a float ONNX file from any exporter or an
nn.Module of one's own, goes through `quantize_static` too, calibrated on its own input batches
(`folder_tensors` reads them from a folder).
"""

from typing import TYPE_CHECKING

from edgepick.errors import QuantizationError
from edgepick.lazy import lazy_attributes

_WHERE = {
    "AccuracyAwareResult": "results", "agreement_images": "passes", "BiasCorrection": "config",
    "CalibMethod": "config", "calibrate": "graph", "Placement": "config",
    "convert": "graph", "folder_images": "passes", "inspect": "inspect", "PassResult": "results",
    "prepare": "graph", "QatHooks": "qat", "QuantConfig": "config",
    "quantize_accuracy_aware": "inspect", "quantize_hybrid": "passes", "quantize_qat": "passes",
    "quantize_static": "passes", "WeightBits": "config", "quantize_onnx_static": "onnx_static", "folder_tensors": "onnx_inputs",
    "OnnxPassResult": "onnx_static"
}
__all__ = ["AccuracyAwareResult", "BiasCorrection", "CalibMethod", "OnnxPassResult", "PassResult", "Placement", "QatHooks",
           "QuantConfig",
           "QuantizationError", "agreement_images", "calibrate", "convert", "folder_images", "folder_tensors",
           "inspect", "prepare", "quantize_accuracy_aware", "quantize_hybrid", "quantize_onnx_static", "quantize_qat",
           "quantize_static", "WeightBits"]

if TYPE_CHECKING:
    from edgepick.quant.config import BiasCorrection, CalibMethod, Placement, QuantConfig, WeightBits
    from edgepick.quant.graph import calibrate, convert, prepare
    from edgepick.quant.inspect import inspect, quantize_accuracy_aware
    from edgepick.quant.onnx_inputs import folder_tensors
    from edgepick.quant.onnx_static import OnnxPassResult, quantize_onnx_static
    from edgepick.quant.passes import agreement_images, folder_images, quantize_hybrid, quantize_qat, quantize_static
    from edgepick.quant.qat import QatHooks
    from edgepick.quant.results import AccuracyAwareResult, PassResult


__getattr__ = lazy_attributes(__name__, _WHERE)
