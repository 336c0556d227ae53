"""Bias correction for static PTQ: shift each int8 conv's bias so that the per-channel mean of its
output matches the float model's on the calibration images.

Rounding a conv's weights to int8, and clipping its input to a calibrated range, moves the mean of
its output; a ReLU or an ArgMax downstream turns that shift into wrong decisions. Two forms, as the
tools people use instead have them (docs/quantization.md, "Bias correction"):

- FAST (NNCF's default, `fast_bias_correction`): each conv is fed the float model's own input,
  quantized to its int8 grid, and the mean of its output is compared with the float conv-BN's. It
  corrects the layer's own error only; one pass over the images.
- EMPIRICAL (AIMET's empirical bias correction): the int8 model runs all the images in lockstep,
  node by node, so each conv sees the int8 inputs the deployed model gives it, with the errors of
  the layers before it included and those layers already corrected. Correcting every conv from one
  ordinary pass instead would correct an upstream error twice: in its own layer and again in every
  layer after it. The shift is the median over the images of each image's mean error, not the
  mean over all pixels: an image whose activations the calibrated ranges clip hard can carry a
  per-channel error a hundred times the others', and a mean would hand its error to every image.

Both act on the converted pt2e graph (BatchNorm folded, each int8 conv reading
dequantize_per_tensor(x) and dequantize_per_channel(w) with a float bias), and leave every other
number of the model as it was.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from operator import attrgetter
from typing import Any

import torch
from torch.fx import GraphModule, Interpreter, Node
from torchao.quantization.pt2e import ObserverBase

from edgepick.quant.config import BiasCorrection
from edgepick.quant.methods import bias_shift

_qd = torch.ops.quantized_decomposed
_CONV = torch.ops.aten.conv2d.default


# what may stand between a logits conv's quantized output and the model's output: LR-ASPP's two
# logits convs are summed by a quantized add, then upsampled
_LOGIT_SUMS = {_qd.quantize_per_tensor.default, _qd.dequantize_per_tensor.default, torch.ops.aten.add.Tensor,
               torch.ops.aten.add_.Tensor, torch.ops.aten.sub.Tensor, torch.ops.aten.upsample_bilinear2d.vec,
               torch.ops.aten.upsample_nearest2d.vec}


def _feeds_float_output(conv: Node) -> bool:
    """True for a conv that writes the logits: its output reaches a graph output without being
    quantized again, or through nothing but _LOGIT_SUMS once it is."""
    todo, seen = [(user, False) for user in conv.users], set()
    while todo:
        node, requantized = todo.pop()
        if node.op == "output":
            return True
        if (node, requantized) in seen or (requantized and node.target not in _LOGIT_SUMS):
            continue
        seen.add((node, requantized))
        requantized = requantized or node.target == _qd.quantize_per_tensor.default
        todo.extend((user, requantized) for user in node.users)
    return False


def conv_geometry(conv: Node) -> tuple[tuple[int, int], tuple[int, int], tuple[int, int], int]:
    """(stride, padding, dilation, groups) of an aten.conv2d node, the defaults filled in."""
    stride, padding, dilation, groups = (list(conv.args[3:7]) + [None] * 4)[:4]
    return (tuple(stride or (1, 1)), tuple(padding or (0, 0)), tuple(dilation or (1, 1)),  # type: ignore[return-value]
            int(groups or 1))


def int8_convs(converted: GraphModule) -> dict[str, Node]:
    """The convs of CONVERTED with an int8 input, int8 per-channel weights and a float bias, by node name."""
    found = {}
    for node in converted.graph.nodes:
        if node.target != _CONV or len(node.args) < 3:
            continue
        x, w, b = node.args[:3]
        if (isinstance(x, Node) and x.target == _qd.dequantize_per_tensor.default
                and isinstance(w, Node) and w.target == _qd.dequantize_per_channel.default
                and isinstance(b, Node) and b.op == "get_attr"):
            found[node.name] = node
    return found


class Means(Interpreter):
    """Runs a graph and sums, per channel, the outputs of the nodes in WATCH (node name -> key);
    AT_CONV(node, inputs, output), when given, is called at each conv and may add sums of its own."""

    def __init__(self, graph: GraphModule, watch: dict[str, str],
                 at_conv: Callable[[Node, tuple, torch.Tensor], None] | None = None):
        super().__init__(graph)
        self.watch, self.at_conv = watch, at_conv
        self.sums: dict[str, torch.Tensor] = {}
        self.counts: dict[str, int] = {}

    def add(self, key: str, y: torch.Tensor) -> None:
        s = y.detach().double().sum(dim=(0, 2, 3))
        self.sums[key] = self.sums[key] + s if key in self.sums else s
        self.counts[key] = self.counts.get(key, 0) + y.numel() // y.shape[1]

    def call_module(self, target: Any, args: tuple, kwargs: dict) -> Any:
        if isinstance(self.fetch_attr(target), ObserverBase):  # the float reference: no histograms to fill
            return args[0]
        return super().call_module(target, args, kwargs)

    def run_node(self, n: Node) -> Any:
        out = super().run_node(n)
        if n.name in self.watch:
            self.add(self.watch[n.name], out)
        if self.at_conv is not None and n.target == _CONV:
            self.at_conv(n, self.map_nodes_to_values(n.args, n), out)
        return out

    def means(self) -> dict[str, torch.Tensor]:
        return {k: (s / self.counts[k]).float() for k, s in self.sums.items()}


def _run(interpreter: Means, inputs: Iterable[torch.Tensor]) -> int:
    seen = 0
    with torch.no_grad():
        for x in inputs:
            interpreter.run(x)
            seen += 1
    if not seen:
        raise ValueError("bias correction needs at least one calibration input")
    return seen


class ImageMeans(Means):
    """Runs a graph and keeps, for the nodes in WATCH (node names), each image's per-channel mean."""

    def __init__(self, graph: GraphModule, watch: Iterable[str]):
        super().__init__(graph, {name: name for name in watch})
        self.rows: dict[str, list[torch.Tensor]] = {}

    def add(self, key: str, y: torch.Tensor) -> None:
        self.rows.setdefault(key, []).append(_image_means([y]))


def _image_means(outputs: list[torch.Tensor]) -> torch.Tensor:
    """[images, channels]: each image's per-channel mean of OUTPUTS (batches)."""
    return torch.cat([y.detach().double().mean(dim=(2, 3)) for y in outputs])


def _empirical(converted: GraphModule, convs: dict[str, Node], target: dict[str, torch.Tensor],
               inputs: list[torch.Tensor]) -> dict[str, float]:
    """Run CONVERTED on all INPUTS in lockstep, node by node; at each conv of CONVS add the median
    over the images of TARGET ([images, channels], fp32's image means) - its own image means to its
    bias and to the outputs already computed, before the next node reads them."""
    runners = []
    for x in inputs:
        runner = Interpreter(converted)
        runner.env, runner.args_iter = {}, iter(converted.graph.process_inputs(x))
        runners.append(runner)
    moved = {}
    with torch.no_grad():
        for node in converted.graph.nodes:
            if node.op == "output":
                break
            outs = [runner.run_node(node) for runner in runners]
            if node.name in convs:
                delta = torch.from_numpy(bias_shift(target[node.name].numpy(), _image_means(outs).numpy())).float()
                attrgetter(node.args[2].target)(converted).add_(delta)
                outs = [y + delta.view(1, -1, 1, 1) for y in outs]
                moved[node.name] = float(delta.abs().max())
            for runner, y in zip(runners, outs):
                runner.env[node] = y
                for dead in runner.user_to_last_uses.get(node, []):
                    del runner.env[dead]
    return moved


def _quantized_input(x: torch.Tensor, dq: Node) -> torch.Tensor:
    """X on the int8 grid of the dequantize node DQ (its scale, zero point and range)."""
    scale, zero, lo, hi, dtype = dq.args[1:6]
    return _qd.dequantize_per_tensor(_qd.quantize_per_tensor(x, scale, zero, lo, hi, dtype),
                                     scale, zero, lo, hi, dtype)


def constant_value(converted: GraphModule, node: Node) -> torch.Tensor:
    """The value of a node made of get_attr inputs only (a dequantized weight)."""
    args = [attrgetter(a.target)(converted) if isinstance(a, Node) else a for a in node.args]
    return node.target(*args)


def correct_biases(prepared: GraphModule, converted: GraphModule, inputs: list[torch.Tensor],
                   method: BiasCorrection) -> dict[str, float]:
    """Correct the biases of CONVERTED's int8 convs in place (see the module doc) on INPUTS (the
    model's input batches), with PREPARED as the float reference: a copy of the observed graph
    taken before `convert` (which rewrites the graph it is given). Returns, per conv, the largest
    change of one of its biases."""
    method = BiasCorrection(method)
    # not the convs writing the float logits: matching the logits' means moved labels away from fp32's
    # (benchmarks/results/ptq-methods/)
    convs = {name: node for name, node in int8_convs(converted).items() if not _feeds_float_output(node)}
    if method == BiasCorrection.NONE or not convs:
        return {}
    if not inputs:
        raise ValueError("bias correction needs at least one calibration input")
    watch = {name: name for name in convs}
    missing = sorted(set(convs) - {n.name for n in prepared.graph.nodes})
    if missing:
        raise ValueError(f"convs {', '.join(missing)} of the int8 graph are not in the float graph")
    if method == BiasCorrection.EMPIRICAL:
        images = ImageMeans(prepared, convs)
        _run(images, inputs)
        return _empirical(converted, convs, {k: torch.cat(v) for k, v in images.rows.items()}, inputs)
    weights = {name: constant_value(converted, node.args[1]) for name, node in convs.items()}
    shadow = Means(prepared, {})

    def at_conv(n: Node, args: tuple, out: torch.Tensor) -> None:
        if n.name in convs:  # the int8 conv on the float model's input
            q = convs[n.name]
            bias = attrgetter(q.args[2].target)(converted)
            x = _quantized_input(args[0], q.args[0])
            shadow.add(n.name, torch.ops.aten.conv2d.default(x, weights[n.name], bias, *q.args[3:]))

    reference = Means(prepared, watch, at_conv)
    _run(reference, inputs)
    target, got = reference.means(), shadow.means()
    moved = {}
    with torch.no_grad():
        for name, node in convs.items():
            delta = target[name] - got[name]
            attrgetter(node.args[2].target)(converted).add_(delta)
            moved[name] = float(delta.abs().max())
    return moved

