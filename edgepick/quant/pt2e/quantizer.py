"""A pt2e quantizer shaped for onnxruntime's QDQ fusions, and the calibration observers.

torchao's X86InductorQuantizer leaves conv outputs float (Inductor fuses them), which in
onnxruntime leaves every Conv unfused. This quantizer puts Q/DQ where onnxruntime's
QDQ transformer turns them into QLinear* kernels: on every conv input and output (after
a fused BN and ReLU), around elementwise add/mul, pooling, concat and activations, with
uint8 affine activations and int8 per-channel symmetric weights (U8S8). Resize shares its
input's quantization, so onnxruntime runs it on uint8 without Q/DQ around it.

The configs live in edgepick/quant/config.py (no torch, for the command line).
"""

from __future__ import annotations

import torch
from torch.fx import GraphModule, Node
from torchao.quantization.pt2e import (
    FakeQuantize,
    FusedMovingAvgObsFakeQuantize,
    HistogramObserver,
    MinMaxObserver,
    MovingAveragePerChannelMinMaxObserver,
    PerChannelMinMaxObserver,
)
from torchao.quantization.pt2e.quantizer import (
    QuantizationAnnotation,
    QuantizationSpec,
    Quantizer,
    SharedQuantizationSpec,
)

from edgepick.quant.config import CalibMethod, Pt2eOptions, QatOptions, QuantConfig
from edgepick.quant.ranges import Histogram, RangeRule

aten = torch.ops.aten
CONV_OPS = {aten.conv2d.default}
BN_OPS = {aten.batch_norm.default, aten._native_batch_norm_legit_no_training.default}
FUSED_ACT_OPS = {aten.relu.default, aten.relu_.default, aten.hardtanh.default, aten.hardtanh_.default}
# ops whose tensor inputs and output are quantized with their own parameters
QUANT_OPS = {aten.hardswish.default, aten.hardswish_.default, aten.hardsigmoid.default, aten.hardsigmoid_.default,
             aten.relu.default, aten.relu_.default, aten.add.Tensor, aten.add_.Tensor, aten.mul.Tensor,
             aten.mul_.Tensor, aten.adaptive_avg_pool2d.default, aten.mean.dim, aten.avg_pool2d.default,
             aten.cat.default}
# ops that keep their input's quantization (onnxruntime runs them on uint8 directly)
SHARED_OPS = {aten.upsample_bilinear2d.vec, aten.upsample_nearest2d.vec, aten.max_pool2d.default}


class RuleObserver(HistogramObserver):
    """Activation range read off the observer's histogram by a `RangeRule` (quant/ranges.py, the rules
    the ONNX path uses too). The rule can change after calibration: with calib_method auto each
    candidate is measured (quant/pt2e/graph.py `choose_rule`). While `observing` is off the observer
    passes values through without counting them (held-out inputs), or, given `simulated` qparams,
    puts them on that uint8 grid: the graph then computes its activations as the int8 model will."""

    def __init__(self, rule: RangeRule | None = None, **kwargs):
        super().__init__(**kwargs)
        self.rule = rule or RangeRule(CalibMethod.PERCENTILE)
        self.observing = True
        self.simulated: tuple[float, int] | None = None  # (scale, zero point) to fake-quantize with

    def forward(self, x_orig: torch.Tensor) -> torch.Tensor:
        if self.observing:
            return super().forward(x_orig)
        if self.simulated is not None:
            scale, zero = self.simulated
            return torch.fake_quantize_per_tensor_affine(x_orig, scale, zero, self.quant_min, self.quant_max)
        return x_orig

    def simulate(self, rule: RangeRule | None) -> None:
        """Fake-quantize with RULE's qparams from now on (None: pass values through)."""
        self.simulated = None
        if rule is not None:
            self.rule = rule
            scale, zero = self.calculate_qparams()
            self.simulated = (float(scale.reshape(-1)[0]), int(zero.reshape(-1)[0]))

    def _non_linear_param_search(self) -> tuple[torch.Tensor, torch.Tensor]:
        hist = Histogram.of(self.histogram.double().cpu().numpy(), float(self.min_val), float(self.max_val))
        low, high = self.rule.range(hist)
        return torch.tensor(low, dtype=self.min_val.dtype), torch.tensor(high, dtype=self.max_val.dtype)


class WeightObserver(PerChannelMinMaxObserver):
    """Per-channel weight ranges, observed once per weight: static PTQ's weights stay as they are while
    it calibrates, so the min/max over every channel would be taken again on each calibration input
    and on each rule calib_method auto measures. A weight changed in place or replaced is observed again."""

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        # the weight last observed and its in-place version: held, not its id, which a later tensor could reuse
        self._seen: tuple[torch.Tensor, int] | None = None

    def forward(self, x_orig: torch.Tensor) -> torch.Tensor:
        if self._seen is None or self._seen[0] is not x_orig or self._seen[1] != x_orig._version:
            super().forward(x_orig)
            self._seen = (x_orig, x_orig._version)
        return x_orig


def activation_spec(config: QuantConfig, qat: bool) -> QuantizationSpec:
    """uint8 per-tensor activations: fake-quant for QaT, else the observer CONFIG's calibration method reads."""
    if qat:  # the fused kernel's affine scales are the observer's to the last bit (unlike its symmetric ones)
        ctr = FusedMovingAvgObsFakeQuantize.with_args(eps=2 ** -12)
    elif config.calib_method == CalibMethod.MINMAX:
        ctr = MinMaxObserver.with_args(eps=2 ** -12)
    else:  # with auto, the configured percentile until a rule is chosen
        method = CalibMethod.PERCENTILE if config.calib_method == CalibMethod.AUTO else config.calib_method
        ctr = RuleObserver.with_args(rule=RangeRule(method, config.percentile), eps=2 ** -12)
    return QuantizationSpec(torch.uint8, ctr, 0, 255, torch.per_tensor_affine)


def weight_spec(config: QuantConfig, qat: QatOptions | None) -> QuantizationSpec:
    """int8 per-channel symmetric weights (7-bit as CONFIG says): with QAT's options, fake-quant whose
    ranges follow training; else the observed weights."""
    qmin, qmax = (-64, 63) if config.reduce_range else (-127, 127)
    if qat is not None:
        # Not the fused kernel: it computes its own scales (no eps floor; on CPU a channel of one sign gets an
        # asymmetric grid), while torchao 0.18's convert_pt2e deploys the observer's (pytorch/ao#4824 later made
        # convert read the kernel's). The unfused FakeQuantize trains on the very scales that are exported
        # (tests/quant/test_qat.py checks QaT-graph-vs-converted label agreement).
        ctr = FakeQuantize.with_args(observer=MovingAveragePerChannelMinMaxObserver, eps=2 ** -12,
                                     averaging_constant=qat.weight_averaging)
    else:
        ctr = WeightObserver.with_args(eps=2 ** -12)
    return QuantizationSpec(torch.int8, ctr, qmin, qmax, torch.per_channel_symmetric, ch_axis=0)


def module_path(node: Node) -> str:
    """Dotted name of the innermost module a node came from ('' for the top level)."""
    stack = node.meta.get("nn_module_stack") or {}
    if not stack:
        return ""
    path = list(stack.values())[-1][0]
    return path.removeprefix("L['self'].").removeprefix("L__self__.")


def under(path: str, prefixes: tuple[str, ...]) -> bool:
    return any(path == p or path.startswith(p + ".") for p in prefixes)


def _feeds_output(node: Node) -> bool:
    """True for the logits' final upsample: logits stay float, uint8 logits would tie in the ArgMax."""
    return any(u.op == "output" for u in node.users)


def _single_user(node: Node) -> Node | None:
    users = list(node.users)
    return users[0] if len(users) == 1 else None


class EdgeQuantizer(Quantizer):
    """Annotates an exported DeepLabV3 for onnxruntime's QDQ kernels (see the module doc)."""

    def __init__(self, config: QuantConfig, qat: QatOptions | None = None, pt2e: Pt2eOptions | None = None,
                 prefix: str = ""):
        super().__init__()
        self.config, self.pt2e = config, pt2e or Pt2eOptions()
        self.qat = qat is not None  # QaT (fake-quant, trained with QAT's options) or static PTQ (observers)
        self.prefix = prefix  # the wrapper attribute in front of module names (e.g. 'model.')
        self.act = activation_spec(config, self.qat)
        self.weight = weight_spec(config, qat)

    def _skipped(self, node: Node) -> bool:
        path = module_path(node).removeprefix(self.prefix)
        return under(path, self.pt2e.skip) or under(path, self.config.keep_float)

    def annotate(self, model: GraphModule) -> GraphModule:
        for node in model.graph.nodes:
            if node.op != "call_function" or "quantization_annotation" in node.meta or self._skipped(node):
                continue
            if node.target in CONV_OPS:
                self._annotate_conv(node)
            elif node.target in QUANT_OPS:
                inputs = {a: self.act for a in node.args[:2] if isinstance(a, Node)}
                if node.target == aten.cat.default:
                    inputs = {a: self.act for a in node.args[0]}
                node.meta["quantization_annotation"] = QuantizationAnnotation(inputs, self.act, _annotated=True)
            elif node.target in SHARED_OPS and isinstance(node.args[0], Node) and not _feeds_output(node):
                src = node.args[0]
                node.meta["quantization_annotation"] = QuantizationAnnotation(
                    {src: self.act}, SharedQuantizationSpec((src, node)), _annotated=True)
        return model

    def _annotate_conv(self, conv: Node) -> None:
        x, w = conv.args[0], conv.args[1]
        chain = [conv]
        nxt = _single_user(conv)
        if nxt is not None and nxt.target in BN_OPS:
            chain.append(nxt)
            nxt = _single_user(nxt)
        if nxt is not None and nxt.target in FUSED_ACT_OPS and not self._skipped(nxt):
            chain.append(nxt)
        conv.meta["quantization_annotation"] = QuantizationAnnotation({x: self.act, w: self.weight},
                                                                      None, _annotated=True)
        for node in chain[1:]:
            node.meta["quantization_annotation"] = QuantizationAnnotation({}, None, _annotated=True)
        if not any(_feeds_output(u) or u.op == "output" for u in chain[-1].users):  # logits stay float
            chain[-1].meta["quantization_annotation"].output_qspec = self.act

    def validate(self, model: GraphModule) -> None:
        pass


def count_quant_nodes(model: GraphModule) -> int:
    """Observers / fake-quant modules inserted by prepare (0 means nothing will be quantized)."""
    from torchao.quantization.pt2e import FakeQuantizeBase, ObserverBase

    return sum(isinstance(m, (ObserverBase, FakeQuantizeBase)) for m in model.modules())
