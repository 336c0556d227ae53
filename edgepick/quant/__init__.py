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
    "AccuracyAwareResult": "results", "agreement_images": "pt2e.passes", "BiasCorrection": "config",
    "CalibMethod": "config", "calibrate": "pt2e.graph", "Placement": "config",
    "convert": "pt2e.graph", "folder_images": "pt2e.passes", "inspect": "pt2e.inspect", "PassResult": "results",
    "prepare": "pt2e.graph", "QatHooks": "pt2e.qat", "QuantConfig": "config",
    "quantize_accuracy_aware": "pt2e.inspect", "quantize_hybrid": "pt2e.passes", "quantize_qat": "pt2e.passes",
    "quantize_static": "pt2e.passes", "WeightBits": "config", "quantize_onnx_static": "onnx.static",
    "folder_tensors": "onnx.inputs", "OnnxPassResult": "onnx.static"
}
__all__ = sorted([*_WHERE, "QuantizationError"])

if TYPE_CHECKING:
    from edgepick.quant.config import BiasCorrection, CalibMethod, Placement, QuantConfig, WeightBits
    from edgepick.quant.onnx.inputs import folder_tensors
    from edgepick.quant.onnx.static import OnnxPassResult, quantize_onnx_static
    from edgepick.quant.pt2e.graph import calibrate, convert, prepare
    from edgepick.quant.pt2e.inspect import inspect, quantize_accuracy_aware
    from edgepick.quant.pt2e.passes import agreement_images, folder_images, quantize_hybrid, quantize_qat, quantize_static
    from edgepick.quant.pt2e.qat import QatHooks
    from edgepick.quant.results import AccuracyAwareResult, PassResult


__getattr__ = lazy_attributes(__name__, _WHERE)
