"""Checks on exported files: int8 conv weights in the ONNX graph, and label agreement (parity).
Imports without torch (the ONNX-in pass uses the weight check)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from edgepick.errors import ParameterError, QuantizationError
from edgepick.onnx_graph import Graph
from edgepick.runtime.session import Segmenter

if TYPE_CHECKING:
    import torch


def check_onnx_out(out: str | Path, source: str | Path | None = None) -> None:
    """Refuse an output path that does not end in .onnx, or that is the SOURCE model itself (which
    it would replace), before any work."""
    if Path(out).suffix.lower() != ".onnx":
        raise ParameterError("{out}: must name an .onnx file", out=Path(out))
    if source is not None and Path(out).resolve() == Path(source).resolve():
        raise ParameterError("{out}: is the model it is made from; write it to another file", out=Path(out))


def conv_weight_report(path: str | Path) -> dict:
    """Which of the model's convs (and transposed convs) take int8 weights (initializer [-> Slice] -> DequantizeLinear) and
    which stay float; a conv split into regions by crop_padded_convs counts once, by its regions."""
    import onnx
    from onnx import TensorProto

    from edgepick.export.crop_convs import CROP_TAG

    g = Graph(onnx.load(str(path)))
    kinds: dict[str, set[bool]] = {}
    for node in g.nodes:
        if node.op_type not in ("Conv", "ConvTranspose"):
            continue
        dq = g.producer(node.input[1])
        src = dq.input[0] if dq is not None and dq.op_type == "DequantizeLinear" else None
        sliced = g.producer(src) if src is not None else None
        if sliced is not None and sliced.op_type == "Slice":
            src = sliced.input[0]
        init = g.initializer(src) if src is not None else None
        is_int8 = init is not None and init.data_type == TensorProto.INT8
        kinds.setdefault(node.name.split(CROP_TAG)[0], set()).add(is_int8)
    int8 = [name for name, k in kinds.items() if k == {True}]
    float_ = [name for name in kinds if name not in int8]
    return {"convs": len(kinds), "int8": len(int8), "float": float_}


def require_int8_convs(path: str | Path, expected: int) -> dict:
    """conv_weight_report of the file at PATH, refused (QuantizationError) when fewer than EXPECTED
    convs got int8 weights: a pass that would otherwise hand back a model that stayed float."""
    report = conv_weight_report(path)
    if report["int8"] < expected:
        raise QuantizationError(f"only {report['int8']} of {expected} convs got int8 weights in the ONNX: "
                                f"{', '.join(report['float'])} stayed float")
    return report


def label_agreement(onnx_path: str | Path, net: torch.nn.Module, images: Iterable[np.ndarray]) -> float:
    """Share of pixels where onnxruntime's labels equal NET's argmax, NET fed [0, 255] NCHW float.

    For an int8 file NET is the converted pt2e graph (torch's simulation of the same
    quantized model); for fp32 it is the float model. Images are already at the model size.
    """
    import torch

    with torch.no_grad():
        return _label_agreement(onnx_path, net, images)


def _label_agreement(onnx_path: str | Path, net: torch.nn.Module, images: Iterable[np.ndarray]) -> float:
    import torch

    seg = Segmenter(onnx_path, threads=2)
    same = total = 0
    for rgb in images:
        ours = seg.infer(seg.prepare(rgb))
        out = net(torch.from_numpy(rgb).permute(2, 0, 1)[None].float())
        ref = (out["out"] if isinstance(out, dict) else out).argmax(1)[0].numpy().astype(np.uint8)
        same += int((ours == ref).sum())
        total += ref.size
    return same / max(total, 1)
