"""ONNX export (fp32 and int8 QDQ) per docs/contracts.md#onnx-model, and the checks run on exported files."""

from edgepick.export.onnx_export import EXPORT_PASSES, export_checkpoint, export_onnx

__all__ = ["EXPORT_PASSES", "export_checkpoint", "export_onnx"]
