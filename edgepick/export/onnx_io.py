"""A float ONNX model from another exporter, read and checked: one image input, at least one conv,
not quantized yet; its input dims, fixed where they are dynamic; its opset, lifted to 13 where it
is older (per-channel DequantizeLinear needs 13). Used by the int8 pass for such models and by
`model wrap`; torch-free.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from edgepick.errors import ParameterError
from edgepick.geometry import Size
from edgepick.onnx_graph import Graph
from edgepick.runtime.preprocessing import Layout

MIN_OPSET = 13
CONV_OPS = ("Conv", "ConvTranspose")


def read_onnx(path: str | Path) -> Any:
    """The ONNX ModelProto at PATH, refused in one line naming `model` when it is not a readable ONNX file."""
    import onnx

    path = Path(path)
    if not path.is_file():
        raise ParameterError("{model}: no such file", model=path)
    try:
        model = onnx.load(str(path))
    except Exception as exc:  # noqa: BLE001 - protobuf raises DecodeError, onnx its own types
        raise ParameterError(f"{{model}}: not an ONNX file ({type(exc).__name__})", model=path) from None
    if not model.graph.node:
        raise ParameterError("{model}: not an ONNX model (no graph)", model=path)
    return model


def load_float_onnx(path: str | Path) -> Any:
    """read_onnx, also refused when the model has not exactly one input, has no Conv/ConvTranspose
    or is quantized already."""
    model = read_onnx(path)
    path = Path(path)
    inputs = graph_inputs(model)
    if len(inputs) != 1:
        raise ParameterError(f"{{model}}: takes {len(inputs)} inputs ({', '.join(i.name for i in inputs)}); "
                             "edgepick quantizes models with one image input", model=path)
    if not any(n.op_type in CONV_OPS for n in model.graph.node):
        raise ParameterError("{model}: has no Conv or ConvTranspose, nothing for edgepick's int8 recipe to "
                             "quantize", model=path)
    if any(n.op_type in ("QuantizeLinear", "DequantizeLinear", "QLinearConv") for n in model.graph.node):
        raise ParameterError("{model}: is already quantized; give the float model", model=path)
    return model


def graph_inputs(model: Any) -> list:
    """The graph's real inputs (older files also list their initializers as inputs)."""
    inits = {i.name for i in model.graph.initializer}
    return [i for i in model.graph.input if i.name not in inits]


def input_dims(model: Any) -> list[int | str]:
    """The input's dims: a number where fixed, its name (or '?') where dynamic."""
    dims = graph_inputs(model)[0].type.tensor_type.shape.dim
    return [d.dim_value if d.HasField("dim_value") and d.dim_value > 0 else (d.dim_param or "?") for d in dims]


def fix_input_shape(model: Any, shape: tuple[int, ...]) -> None:
    """Give the input the static SHAPE (its fixed dims must agree) and drop the inferred shapes
    inside and at the outputs, which shape inference then fills in for SHAPE."""
    dims = graph_inputs(model)[0].type.tensor_type.shape.dim
    have = input_dims(model)
    if len(have) != len(shape) or any(isinstance(h, int) and h != s for h, s in zip(have, shape)):
        raise ParameterError(f"{{input_shape}}: does not fit the model's input {have}", input_shape=tuple(shape))
    for d, s in zip(dims, shape):
        d.Clear()
        d.dim_value = int(s)
    del model.graph.value_info[:]
    for out in model.graph.output:
        out.type.tensor_type.ClearField("shape")


def constants_to_initializers(model: Any) -> int:
    """Turn MODEL's Constant nodes that hold a tensor into initializers of the same name (Paddle's
    exporter writes every weight so): onnxruntime's quantizer finds weights among the initializers
    only, and its pre-processing fails on a model that has none. Returns how many were turned."""
    from onnx import numpy_helper

    g = Graph(model)
    turned = [n for n in g.nodes if n.op_type == "Constant" and len(n.attribute) == 1
              and n.attribute[0].name == "value"]
    for node in turned:
        g.add_initializer(node.output[0], numpy_helper.to_array(node.attribute[0].t))
    g.remove(*turned)
    return len(turned)


def drop_unused_initializers(model: Any) -> int:
    """Remove the initializers no node (nor a subgraph) reads, and their graph-input entries;
    onnxruntime warns about each one on every load. Returns how many went."""
    return Graph(model).drop_unused_initializers()


def opset(model: Any) -> int:
    """The model's version of the default ONNX domain."""
    return next((o.version for o in model.opset_import if o.domain in ("", "ai.onnx")), 1)


def lift_opset(model: Any, path: str | Path) -> Any:
    """MODEL at opset 13 when it is older (onnx's version converter), else MODEL itself."""
    import onnx
    from onnx import version_converter

    if opset(model) >= MIN_OPSET:
        return model
    try:
        lifted = version_converter.convert_version(model, MIN_OPSET)
        onnx.checker.check_model(lifted)
    except Exception as exc:  # noqa: BLE001 - the converter raises several types
        first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
        raise ParameterError(f"{{model}}: opset {opset(model)} could not be converted to {MIN_OPSET} ({first}); "
                             f"per-channel int8 needs opset {MIN_OPSET}: export the model again with opset "
                             f">= {MIN_OPSET}", model=Path(path)) from None
    return lifted


def describe(path: str | Path) -> dict:
    """What an ONNX file is (`edgepick model info`): its inputs and outputs, opset, producer,
    precision and int8 conv count, its metadata, and whether the runtime takes it as an edgepick
    model (and if not, why)."""
    from edgepick.export.checks import conv_weight_report
    from edgepick.runtime.session import ModelError, check_model

    model = read_onnx(path)

    def tensors(values: Any) -> list[dict]:
        import onnx

        return [{"name": v.name, "dtype": onnx.helper.tensor_dtype_to_np_dtype(v.type.tensor_type.elem_type).name,
                 "shape": [d.dim_value if d.HasField("dim_value") else (d.dim_param or "?")
                           for d in v.type.tensor_type.shape.dim]} for v in values]

    report = conv_weight_report(path)
    try:
        check_model(path)
        runtime, why = True, None
    except ModelError as exc:
        runtime, why = False, str(exc)
    return {"file": str(path), "inputs": tensors(graph_inputs(model)), "outputs": tensors(model.graph.output),
            "opset": opset(model), "producer": f"{model.producer_name} {model.producer_version}".strip(),
            "precision": "int8" if report["int8"] else "fp32", "convs": report["convs"], "int8_convs": report["int8"],
            "float_convs": report["float"], "nodes": len(model.graph.node),
            "metadata": {p.key: p.value for p in model.metadata_props},
            "edgepick_model": runtime, **({"why_not": why} if why else {})}


def image_size(model: Any, layout: Layout) -> Size | None:
    """The image size a model with fixed spatial dims takes, else None."""
    dims = input_dims(model)
    hw = [d for d in (dims[2:4] if layout == Layout.NCHW else dims[1:3]) if isinstance(d, int)]
    return Size(hw[1], hw[0]) if len(dims) == 4 and len(hw) == 2 else None
