"""ONNX export (fp32 and int8 QDQ) per docs/contracts.md#onnx-model, and the checks run on exported files.
"""

from typing import TYPE_CHECKING

from edgepick.lazy import lazy_attributes

_WHERE = {
    "export_checkpoint": "onnx_export", "export_onnx": "onnx_export", "EXPORT_PASSES": "onnx_export",
    "ExportResult": "onnx_export"
}
__all__ = sorted(_WHERE)

if TYPE_CHECKING:
    from edgepick.export.onnx_export import EXPORT_PASSES, ExportResult, export_checkpoint, export_onnx


__getattr__ = lazy_attributes(__name__, _WHERE)
