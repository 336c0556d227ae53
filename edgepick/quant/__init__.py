"""Int8 passes (static PTQ, QaT, hybrid-QaT) on torchao's pt2e flow, and the verbs they are made of.

One function per pass, as onnxruntime's quantize.py has them (`quantize_static`, `quantize_qat`,
`quantize_hybrid`, each with a `QuantConfig`); and torchao's verbs for a loop of your own
(`prepare`, `calibrate`, `convert`; `QatHooks` brings a QaT graph's needs to edgepick's `fit`).
Calibration data is the caller's: any iterable of HxWx3 uint8 RGB images (`folder_images` draws
them from a data set).
"""

from edgepick.quant.graph import QuantizationError, calibrate, convert, prepare
from edgepick.quant.inspect import inspect, quantize_accuracy_aware
from edgepick.quant.passes import (agreement_images, folder_images, quantize_hybrid, quantize_qat,
                                   quantize_static)
from edgepick.quant.qat import QatHooks
from edgepick.quant.quantizer import QuantConfig

__all__ = ["QatHooks", "QuantConfig", "QuantizationError", "agreement_images", "calibrate", "convert",
           "folder_images", "inspect", "prepare", "quantize_accuracy_aware", "quantize_hybrid", "quantize_qat",
           "quantize_static"]
