"""The int8 file a torch pass writes: exported from the converted graph (edgepick.export), refused
when a conv that should be int8 is not (no file is left), and compared with torch's simulation of
the same int8 model on check images."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from edgepick.errors import QuantizationError
from edgepick.export.checks import require_int8_convs
from edgepick.export.onnx_export import EXPORT_PASSES, export_onnx, label_agreement
from edgepick.geometry import Size
from edgepick.progress import stage


@dataclass(frozen=True)
class Int8File:
    """An exported int8 ONNX model and the checks run on it."""

    out: str
    size_bytes: int
    convs: int  # convs of the model (a conv split into regions counts once)
    int8_convs: int  # of them, those whose weights are int8 in the file
    float_convs: list[str]  # the names of the others (kept float on purpose)
    agreement_vs_torch: float  # share of pixels where onnxruntime's labels equal torch's simulation's


def checked_int8(path: Path, expected_convs: int) -> dict:
    """require_int8_convs of the file at PATH, which is removed when it fails."""
    try:
        return require_int8_convs(path, expected_convs)
    except QuantizationError:
        path.unlink()
        raise


def export_int8(converted: torch.fx.GraphModule, out: str | Path, metadata: dict, size: Size, expected_convs: int,
                check_images: list[np.ndarray], progress: bool = False,
                passes: tuple[str, ...] = tuple(EXPORT_PASSES)) -> Int8File:
    """Export CONVERTED to OUT with METADATA, then check its int8 conv weights (EXPECTED_CONVS of them)
    and onnxruntime-vs-torch label agreement on CHECK_IMAGES; no file on failure."""
    stage(f"export the int8 ONNX to {out} (torch.export, then onnx checks)", progress)
    path = export_onnx(converted, out, metadata, size, passes)
    stage(f"compare onnxruntime's labels with torch's on {len(check_images)} val images", progress)
    report = checked_int8(path, expected_convs)
    agreement = label_agreement(path, converted, check_images)
    return Int8File(out=str(path), size_bytes=path.stat().st_size, convs=report["convs"], int8_convs=report["int8"],
                    float_convs=report["float"], agreement_vs_torch=round(agreement, 5))
