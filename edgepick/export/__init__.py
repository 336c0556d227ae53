"""ONNX export (fp32 and int8 QDQ) per docs/contracts.md#onnx-model, and the checks run on exported files."""
