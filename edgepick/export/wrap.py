"""`model wrap`: a segmentation model from elsewhere (float, or int8 from `quantize static
MODEL.onnx`) made into an edgepick model (docs/contracts.md#onnx-model), so that eval, bench,
grasp and pick run it as one of their own.

In front, the preprocessing goes into the graph: uint8 [1, H, W, 3] RGB `image` -> float ->
channel order -> x * scale / std - mean / std (one Mul and one Add, per channel) -> the model's
layout. Behind, the label step: the chosen output resized to H x W where it is smaller (bilinear,
on the logits), then the ArgMax over its channels, or for a one-channel map a threshold (0.5
after a Sigmoid, else 0), as uint8 `labels` [1, H, W]. The model's other outputs are dropped.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.errors import ParameterError
from edgepick.export.checks import check_onnx_out, conv_weight_report
from edgepick.export.onnx_io import fix_input_shape, graph_inputs, image_size, input_dims, lift_opset, read_onnx
from edgepick.files import atomic_path, sha256_of
from edgepick.geometry import Size
from edgepick.onnx_graph import Graph
from edgepick.runtime.model_info import ModelInfo
from edgepick.runtime.preprocessing import ChannelOrder, Layout, Preprocessing

TAG = "edgepick_wrap"


@dataclass(frozen=True)
class WrapResult:
    """A wrapped model (the JSON `edgepick model wrap` prints)."""

    out: str
    size_bytes: int
    input_size: list[int]  # [H, W], as the model's metadata has it
    classes: list[str]
    precision: str
    output: str  # the model output the labels are taken from
    label_step: str  # argmax, or "threshold T"

    def to_dict(self) -> dict:
        return asdict(self)


def _output_shapes(model: Any, input_shape: tuple[int, ...]) -> dict[str, list[int]]:
    """The outputs' shapes, from one onnxruntime run on zeros (shape inference cannot follow an
    exporter's Shape -> Resize arithmetic)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.log_severity_level = 3
    try:
        session = ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
        outs = session.run(None, {session.get_inputs()[0].name: np.zeros(input_shape, np.float32)})
    except Exception as exc:  # noqa: BLE001 - onnxruntime raises several types
        first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
        raise ParameterError(f"{{model:name}}: onnxruntime cannot run it at input {list(input_shape)} ({first})",
                             model=None) from None
    return {o.name: list(y.shape) for o, y in zip(session.get_outputs(), outs)}


def _preprocessing_nodes(g: Graph, into: str, prep: Preprocessing) -> list:
    """uint8 NHWC RGB `image` -> the model input INTO, as PREP says."""
    from onnx import TensorProto, helper

    scale = np.float32(prep.scale) / np.asarray(prep.std, np.float32)
    shift = -np.asarray(prep.mean, np.float32) / np.asarray(prep.std, np.float32)
    nodes = [helper.make_node("Cast", ["image"], [f"{TAG}_float"], to=TensorProto.FLOAT, name=f"{TAG}_cast")]
    x = f"{TAG}_float"
    if prep.channels == ChannelOrder.BGR:
        nodes.append(helper.make_node("Gather", [x, g.add_initializer(f"{TAG}_bgr", [2, 1, 0], np.int64)], [f"{TAG}_bgr_x"],
                                      axis=3, name=f"{TAG}_bgr"))
        x = f"{TAG}_bgr_x"
    nodes += [helper.make_node("Mul", [x, g.add_initializer(f"{TAG}_scale", scale.reshape(1, 1, 1, 3), np.float32)], [f"{TAG}_scaled"],
                               name=f"{TAG}_mul"),
              helper.make_node("Add", [f"{TAG}_scaled", g.add_initializer(f"{TAG}_shift", shift.reshape(1, 1, 1, 3), np.float32)],
                               [f"{TAG}_normed" if prep.layout == Layout.NCHW else into], name=f"{TAG}_add")]
    if prep.layout == Layout.NCHW:
        nodes.append(helper.make_node("Transpose", [f"{TAG}_normed"], [into], perm=[0, 3, 1, 2], name=f"{TAG}_nchw"))
    return nodes


def _label_nodes(g: Graph, out: str, dims: list[int], size: Size, nhwc: bool, threshold: float | None) -> list:
    """The model output OUT (DIMS) -> uint8 `labels` [1, H, W]."""
    from onnx import TensorProto, helper

    nodes, x = [], out
    if nhwc:
        nodes.append(helper.make_node("Transpose", [x], [f"{TAG}_nchw_out"], perm=[0, 3, 1, 2], name=f"{TAG}_to_nchw"))
        x, dims = f"{TAG}_nchw_out", [dims[0], dims[3], dims[1], dims[2]]
    if dims[2:] != list(size.hw):
        sizes = g.add_initializer(f"{TAG}_sizes", [1, dims[1], *size.hw], np.int64)
        nodes.append(helper.make_node("Resize", [x, "", "", sizes], [f"{TAG}_resized"], mode="linear",
                                      name=f"{TAG}_resize"))
        x = f"{TAG}_resized"
    if threshold is None:
        nodes.append(helper.make_node("ArgMax", [x], [f"{TAG}_ids"], axis=1, keepdims=0, name=f"{TAG}_argmax"))
    else:
        nodes += [helper.make_node("Greater", [x, g.add_initializer(f"{TAG}_threshold", threshold, np.float32)], [f"{TAG}_above"],
                                   name=f"{TAG}_threshold"),
                  helper.make_node("Squeeze", [f"{TAG}_above", g.add_initializer(f"{TAG}_axis", [1], np.int64)],
                                   [f"{TAG}_ids"], name=f"{TAG}_squeeze")]
    nodes.append(helper.make_node("Cast", [f"{TAG}_ids"], ["labels"], to=TensorProto.UINT8, name=f"{TAG}_labels"))
    return nodes


def _prune(g: Graph) -> None:
    """Drop the nodes no longer on the way to `labels` (the model's other outputs)."""
    needed, todo = set(), ["labels"]
    while todo:
        node = g.producer(todo.pop())
        if node is None or id(node) in needed:
            continue
        needed.add(id(node))
        todo.extend(node.input)
    g.remove(*[n for n in g.nodes if id(n) not in needed])


def _checked_input(proto: Any, model: str | Path) -> Any:
    """The model's one 4-d float image input, refused in one line naming `model` otherwise."""
    from onnx import TensorProto

    inputs = graph_inputs(proto)
    if len(inputs) != 1 or len(input_dims(proto)) != 4:
        raise ParameterError("{model}: must take one 4-d image input, takes "
                             f"{[(i.name, input_dims(proto)) for i in inputs]}", model=Path(model))
    if inputs[0].type.tensor_type.elem_type != TensorProto.FLOAT:
        raise ParameterError("{model}: its input is not float32; wrap takes a model that expects normalised float "
                             "images (an edgepick model is wrapped already)", model=Path(model))
    return inputs[0]


def _threshold(g: Graph, chosen: str, channels: int, classes: list[str], threshold: float | None) -> float | None:
    """The label step's threshold for the output CHOSEN of CHANNELS channels (None: its ArgMax),
    CLASSES and THRESHOLD checked against it."""
    if channels == 1:
        made_by = g.producer(chosen)
        threshold = threshold if threshold is not None else 0.5 if made_by and made_by.op_type == "Sigmoid" else 0.0
        if len(classes) != 2:
            raise ParameterError(f"{{classes}}: a one-channel output needs two names (below, above the threshold), "
                                 f"got {len(classes)}", classes=list(classes))
    elif len(classes) != channels:
        raise ParameterError(f"{{classes}}: {len(classes)} names for an output of {channels} channels",
                             classes=list(classes))
    elif threshold is not None:
        raise ParameterError("{threshold}: is for a one-channel output; this one has "
                             f"{channels} channels (labels are their ArgMax)", threshold=threshold)
    return threshold


def _metadata(proto: Any, path: Path, model: str | Path, classes: list[str], size: Size, prep: Preprocessing) -> bool:
    """Write edgepick's metadata into PROTO (the model's own keys kept, `edgepick.quant` of an
    edgepick int8 file too), from the file at PATH; returns whether it is int8."""
    meta = {p.key: p.value for p in proto.metadata_props if not p.key.startswith("edgepick.")}
    old = {p.key: p.value for p in proto.metadata_props}
    int8 = conv_weight_report(path)["int8"] > 0
    quant = {"mode": "foreign" if int8 else "none"}
    if "edgepick.quant" in old:
        try:
            quant = json.loads(old["edgepick.quant"])
        except ValueError:
            raise ParameterError("{model}: its edgepick.quant metadata is not JSON", model=Path(model)) from None
    info = ModelInfo(list(classes), size, "rgb", "int8" if int8 else "fp32", quant=quant,
                     source_sha256=sha256_of(Path(model)), arch="foreign", preprocessing=prep.to_dict())
    meta.update(info.to_metadata())
    del proto.metadata_props[:]
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    return int8


def wrap_model(model: str | Path, out: str | Path, classes: list[str], preprocessing: Preprocessing | None = None,
               output: str | None = None, threshold: float | None = None) -> WrapResult:
    """MODEL with PREPROCESSING and the label step in its graph and edgepick's metadata, written to
    OUT: CLASSES name the chosen OUTPUT's channels (two for a one-channel map: below and above
    THRESHOLD, by default 0.5 after a Sigmoid, else 0). A float or int8 file alike."""
    import onnx
    from onnx import TensorProto, helper

    from edgepick.runtime.session import Segmenter

    prep = preprocessing or Preprocessing()
    check_onnx_out(out, model)
    proto = read_onnx(model)
    if len(classes) < 2 or len(set(classes)) != len(classes) or not all(c.strip() for c in classes):
        raise ParameterError("{classes}: at least two different, non-empty class names", classes=list(classes))
    image_input = _checked_input(proto, model)
    size = prep.size or image_size(proto, prep.layout)
    if size is None:
        raise ParameterError("{size:name} is needed: the model's input has no fixed size", size=None)
    fix_input_shape(proto, prep.input_shape(size))
    proto = lift_opset(proto, model)
    shapes = _output_shapes(proto, prep.input_shape(size))
    outputs = [o.name for o in proto.graph.output]
    chosen = output or outputs[0]
    if chosen not in outputs:
        raise ParameterError(f"{{output}}: the model has no such output; it has {', '.join(outputs)}", output=chosen)
    shape = shapes[chosen]
    nhwc = prep.layout == Layout.NHWC
    if len(shape) != 4 or 0 in shape:
        raise ParameterError(f"{{output}}: is not a [1, C, H, W] map (shape {shape})", output=chosen)
    g = Graph(proto)
    threshold = _threshold(g, chosen, shape[3] if nhwc else shape[1], classes, threshold)
    g.insert(0, _preprocessing_nodes(g, image_input.name, prep))
    g.append(_label_nodes(g, chosen, shape, size, nhwc, threshold))
    g.graph.input.remove(image_input)
    g.graph.input.insert(0, helper.make_tensor_value_info("image", TensorProto.UINT8, [1, *size.hw, 3]))
    del g.graph.output[:]
    g.graph.output.append(helper.make_tensor_value_info("labels", TensorProto.UINT8, [1, *size.hw]))
    _prune(g)
    with atomic_path(out) as path:
        onnx.save(proto, str(path))
        int8 = _metadata(proto, path, model, classes, size, prep)
        onnx.save(proto, str(path))
        onnx.checker.check_model(str(path), full_check=True)
        Segmenter(path, threads=1)  # the runtime's own contract check
    out = Path(out)
    return WrapResult(out=str(out), size_bytes=out.stat().st_size, input_size=list(size.hw), classes=list(classes),
                      precision="int8" if int8 else "fp32", output=chosen,
                      label_step="argmax" if threshold is None else f"threshold {threshold:g}")
