"""ONNX export (fp32 and int8 QDQ) per docs/contracts.md#onnx-model, and the checks run on exported files.
"""

import importlib
from typing import TYPE_CHECKING

_WHERE = {
    "export_checkpoint": "onnx_export", "export_onnx": "onnx_export", "EXPORT_PASSES": "onnx_export",
    "ExportResult": "onnx_export"
}
__all__ = ["EXPORT_PASSES", "ExportResult", "export_checkpoint", "export_onnx"]

if TYPE_CHECKING:
    from edgepick.export.onnx_export import EXPORT_PASSES, ExportResult, export_checkpoint, export_onnx


def __getattr__(name: str) -> object:
    """The public objects are imported when first asked for, so that importing one light module of
    the package (a config, an enum) does not import torch."""
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
