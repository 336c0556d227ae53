"""ONNX pass (opt-in): GELU on onnxruntime's integer kernels, as c * x * sigmoid(alpha * x).

onnxruntime has no integer kernel for Erf. In a QDQ graph a GELU, x * Phi(x) written with Erf (Div,
Erf, Add, Mul, and the Mul by 0.5 unless a conv took it), therefore dequantizes its map, runs each step
in float, and quantizes again between the steps. On a GELU network such as PP-OCRv5/v6 or a
ConvNeXt-style block, these chains take a large share of the int8 run. An exact lookup table of the
256 input codes is the natural replacement, but onnxruntime's Gather copies one element at a time and
is slower than the float chain. QLinearSigmoid is a lookup table of its own, so this pass writes each
GELU as

    DequantizeLinear(x; scale * alpha) -> Sigmoid -> QuantizeLinear(1/256)    (QLinearSigmoid)
    Mul(DequantizeLinear(x), the sigmoid) -> QuantizeLinear(scale / c)         (QLinearMul)

x * sigmoid(1.702 x) differs from GELU by up to 0.02. For each layer, alpha is fitted to its 256
input codes: the fit minimises the mean error in output codes against the float chain, computed
without the rounding between its steps. It is an approximation, so QuantConfig.gelu chooses it;
benchmarks/peers_onnx.py (`--edgepick-methods 7/empirical/gelu-sigmoid`) times both forms and
measures their agreement with fp32.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from edgepick.onnx_graph import Graph

ELEMENTWISE = frozenset({"Add", "Sub", "Mul", "Div", "Erf", "Tanh", "Pow", "Sqrt", "Neg", "Identity",
                         "QuantizeLinear", "DequantizeLinear"})
ANCHORS = frozenset({"Erf", "Tanh"})  # GELU with erf, or its tanh approximation
ALPHAS = np.arange(1.2, 2.4, 0.002)
MAX_FIT_ERROR = 0.03  # of the output's range: beyond it the chain is not a GELU, and is left as it is
TAG = "_sigmoid_gelu"


def sigmoid_gelu(model) -> int:
    """Rewrite each uint8 QDQ GELU chain of MODEL (onnx ModelProto, in place) as above; returns how many."""
    g = Graph(model)
    const = _constants(g)
    removed: set[int] = set()  # ids of the nodes taken out
    inserted: dict[int, list] = {}  # id of a chain's final Q -> the nodes put in its place
    for anchor in [n for n in g.nodes if n.op_type in ANCHORS]:
        if id(anchor) in removed:
            continue
        dq = _source_dequantize(g, anchor, const)
        if dq is None or id(dq) in removed or (x_params := _uint8_qparams(g, dq)) is None:
            continue
        chain = _closed_chain(g, dq, anchor, const)
        if chain is None:
            continue
        members, q, (y_scale, y_zero) = chain
        x_scale, x_zero = x_params
        x = (np.arange(256) - x_zero) * x_scale
        f = _float_chain(g, members, dq, q, const, x)
        fit = fit_sigmoid_gelu(x, f, y_scale, y_zero)
        if fit is None:
            continue
        alpha, c = fit
        inserted[id(q)] = _replacement(g, dq, q, x_scale * alpha, y_scale / c)
        removed |= {id(n) for n in members if n is not dq}
    kept = []
    for n in g.nodes:
        kept += inserted.get(id(n), [])
        if id(n) not in removed:
            kept.append(n)
    g.set_nodes(kept)
    return len(inserted)


def fit_sigmoid_gelu(x: np.ndarray, f: np.ndarray, y_scale: float, y_zero: int) -> tuple[float, float] | None:
    """(alpha, c) with c * x * q(sigmoid(alpha * x)) closest to F in uint8 output codes, where q is
    QLinearSigmoid's 1/256 grid; None when F (on the codes X) is no GELU-like curve c * x * Phi(x)."""
    if not np.all(np.isfinite(f)):
        return None
    gate = np.clip(np.round(256.0 / (1.0 + np.exp(-np.outer(ALPHAS, x)))), 0, 255) / 256.0
    g = gate * x  # one row per alpha
    c = (g @ f) / np.maximum((g * g).sum(axis=1), 1e-12)
    codes = lambda v: np.clip(np.round(v / y_scale) + y_zero, 0, 255)  # noqa: E731
    error = np.abs(codes(c[:, None] * g) - codes(f)[None]).mean(axis=1)
    best = int(np.argmin(error))
    span = float(f.max() - f.min())
    if c[best] <= 0 or span <= 0 or np.abs(c[best] * g[best] - f).max() > MAX_FIT_ERROR * span:
        return None
    return float(ALPHAS[best]), float(c[best])


def _constants(g: Graph) -> set[str]:
    """Tensors that do not depend on the model's input: initializers, Constant outputs, and the
    outputs of nodes that read only those."""
    const = {i.name for i in g.graph.initializer}
    grew = True
    while grew:
        grew = False
        for n in g.nodes:
            if all(i in const for i in n.input if i) and not set(n.output) <= const:
                const.update(n.output)
                grew = True
    return const


def _uint8_qparams(g: Graph, node) -> tuple[float, int] | None:
    """The per-tensor scale and uint8 zero point of a Q/DQ node, or None."""
    scale = g.array(node.input[1]) if g.is_initializer(node.input[1]) else None
    zero = g.array(node.input[2]) if len(node.input) > 2 and g.is_initializer(node.input[2]) else None
    if scale is None or zero is None or scale.size != 1 or zero.size != 1 or zero.dtype != np.uint8:
        return None
    return float(scale.ravel()[0]), int(zero.ravel()[0])


def _live(node, const) -> list[str]:
    return [i for i in node.input if i and i not in const]


def _source_dequantize(g: Graph, anchor, const):
    """The DequantizeLinear the anchor's input comes from, through elementwise ops with one live input."""
    node = anchor
    while True:
        live = _live(node, const)
        source = g.producer(live[0]) if len(live) == 1 else None
        if source is None:
            return None
        node = source
        if node.op_type == "DequantizeLinear":
            return node
        if node.op_type not in ELEMENTWISE:
            return None


def _scalar(g: Graph, name: str) -> bool:
    """Whether the constant NAME holds one value (an initializer, or a Q/DQ of one)."""
    while (init := g.initializer(name)) is None:
        node = g.producer(name)
        if node is None or node.op_type not in ("DequantizeLinear", "QuantizeLinear", "Identity", "Cast"):
            return False
        name = node.input[0]
    return int(np.prod(init.dims)) == 1


def _region(g: Graph, dq, const) -> list:
    """The elementwise nodes reachable from DQ that read only DQ's map (or each other's outputs) and
    scalar constants, DQ among them."""
    region, names, grew = [dq], set(dq.output), True
    while grew:
        grew = False
        for node in list(region):
            for name in node.output:
                for c in g.consumers(name):
                    if any(c is r for r in region) or c.op_type not in ELEMENTWISE:
                        continue
                    if all(i in names for i in _live(c, const)) and all(_scalar(g, i) for i in c.input if i in const):
                        region.append(c)
                        names.update(c.output)
                        grew = True
    return region


def _closed_chain(g: Graph, dq, anchor, const) -> tuple[list, object, tuple[float, int]] | None:
    """(members in graph order, final Q, its scale and zero point): the largest set of elementwise
    nodes from DQ to a uint8 QuantizeLinear that reads only DQ's map and scalar constants, contains
    ANCHOR, and that nothing outside reads but through the final Q; None if there is none."""
    region = _region(g, dq, const)
    place = {id(n): k for k, n in enumerate(g.nodes)}
    inside = {id(n) for n in region}
    for q in sorted((n for n in region if n.op_type == "QuantizeLinear"), key=lambda n: -place[id(n)]):
        members: dict[int, Any] = {}
        todo = [q]
        while todo:
            node = todo.pop()
            if id(node) not in members:
                members[id(node)] = node
                todo += [p for i in _live(node, const) if (p := g.producer(i)) is not None and id(p) in inside]
        if id(dq) not in members or id(anchor) not in members:
            continue
        y_params = _uint8_qparams(g, q)
        if y_params is not None and all(o not in g.outputs and all(id(c) in members for c in g.consumers(o))
                                        for key, n in members.items() if key != id(q) for o in n.output):
            return sorted(members.values(), key=lambda n: place[id(n)]), q, y_params
    return None


def _float_chain(g: Graph, members: list, dq, q, const, x: np.ndarray) -> np.ndarray:
    """The chain's value for the inputs X, computed in float: the Q -> DQ pairs inside it skipped
    and its final Q left out (onnxruntime runs the nodes, so every op means what the file says)."""
    import onnx
    import onnxruntime as ort
    from onnx import helper

    inner = [n for n in members if n is not dq and n is not q]
    alias = {}
    for n in inner:
        source = g.producer(n.input[0]) if n.op_type == "DequantizeLinear" else None
        if source is not None and any(source is m for m in members):
            alias[n.output[0]] = source.input[0]
    body = []
    for n in inner:
        if n.op_type == "QuantizeLinear" or n.output[0] in alias:
            continue
        copy = onnx.NodeProto()
        copy.CopyFrom(n)
        copy.input[:] = [alias.get(i, i) for i in n.input]
        body.append(copy)
    needed = {i for n in body for i in n.input if i in const and not g.is_initializer(i)}
    setup: list = []
    while needed:
        node = g.producer(needed.pop())
        assert node is not None, "a constant that is no initializer is made by a node"
        setup.insert(0, node)
        needed |= {i for i in node.input if i in const and not g.is_initializer(i)}
    used = {i for n in [*setup, *body] for i in n.input if g.is_initializer(i)}
    source, result = dq.output[0], q.input[0]
    graph = helper.make_graph(
        [*setup, *body], "chain", [helper.make_tensor_value_info(source, onnx.TensorProto.FLOAT, [x.size])],
        [helper.make_tensor_value_info(result, onnx.TensorProto.FLOAT, [x.size])],
        [g.initializer(i) for i in sorted(used)])
    chain = helper.make_model(graph, opset_imports=g.model.opset_import, ir_version=g.model.ir_version)
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    opts.log_severity_level = 3
    session = ort.InferenceSession(chain.SerializeToString(), opts, providers=["CPUExecutionProvider"])
    return session.run([result], {source: x.astype(np.float32)})[0].astype(np.float64).ravel()


def _replacement(g: Graph, dq, q, gate_scale: float, out_scale: float) -> list:
    """The gate DequantizeLinear -> Sigmoid -> Q/DQ on the 1/256 grid, and Mul -> the final Q's output."""
    from onnx import helper

    tag = f"{q.name or q.output[0]}{TAG}"

    def constant(suffix: str, value, dtype) -> str:
        return g.add_initializer(f"{tag}_{suffix}", value, dtype)
    gate_s, step, zero = constant("gate_scale", gate_scale, np.float32), constant("step", 1 / 256, np.float32), \
        constant("zero", 0, np.uint8)
    return [
        helper.make_node("DequantizeLinear", [dq.input[0], gate_s, dq.input[2]], [f"{tag}_gate_in"], name=f"{tag}_dq"),
        helper.make_node("Sigmoid", [f"{tag}_gate_in"], [f"{tag}_gate"], name=f"{tag}_sigmoid"),
        helper.make_node("QuantizeLinear", [f"{tag}_gate", step, zero], [f"{tag}_gate_q"], name=f"{tag}_gate_q"),
        helper.make_node("DequantizeLinear", [f"{tag}_gate_q", step, zero], [f"{tag}_gate_dq"], name=f"{tag}_gate_dq"),
        helper.make_node("Mul", [dq.output[0], f"{tag}_gate_dq"], [f"{tag}_product"], name=f"{tag}_mul"),
        helper.make_node("QuantizeLinear", [f"{tag}_product", constant("out_scale", out_scale, np.float32), q.input[2]],
                         [q.output[0]], name=f"{tag}_q"),
    ]
