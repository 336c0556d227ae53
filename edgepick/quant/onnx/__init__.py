"""The ONNX pass: a float ONNX model from any exporter quantized on its own graph (onnxruntime's
QDQ writer, edgepick's ranges, rewrites and measurements). Torch-free: nothing here imports torch
or `edgepick.quant.pt2e`. The public verbs are named in `edgepick.quant`."""
