"""Checks on exported files, torch-free (the ONNX pass uses them too): the output path, and which
convs have int8 weights in the file."""

from __future__ import annotations

from pathlib import Path

from edgepick.errors import ParameterError, QuantizationError
from edgepick.onnx_graph import Graph


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
