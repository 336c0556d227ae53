"""AdaRound for static PTQ (Nagel et al. 2020, "Up or Down? Adaptive Rounding for Post-Training
Quantization"; AIMET's `apply_adaround`): each int8 conv chooses, weight by weight, whether to
round down or up, so that its output on the calibration images stays closest to the float
model's, instead of rounding every weight to its nearest grid point on its own.

The float model runs the calibration images once, and at a sample of each conv's output positions
its output is kept as the target. The int8 model then runs all the images in lockstep, node by
node, as empirical bias correction does, and each conv learns its rounding on the input the int8
model itself gives it there (im2col columns), the convs before it already rounded: what it
compensates includes the errors from upstream. The rounding is a soft variable h(V) in [0, 1] (a
rectified sigmoid), trained with Adam on the output error plus a regulariser that pushes every h
to 0 or 1 (its exponent annealed from 20 to 2 after a warm start), then hardened: the solver is
numpy, shared with the ONNX pass (`edgepick.quant.methods.round_conv`). The weight scales, the activation ranges and
every other conv stay as they are. A conv whose learnt rounding does not lower its output error
on the sampled positions keeps round-to-nearest, so no conv ends worse on its own data.

Without a time budget every conv takes the same number of steps, planned from the model's size
(`methods.planned_steps`), so the same inputs give the same file whatever the machine's load. A
time budget is shared out in proportion to each conv's weight count (its work per step), and what
one conv leaves unspent or overspends is shared again among the convs after it; the file then
depends on the machine's speed and load.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from operator import attrgetter

import numpy as np
import torch
import torch.nn.functional as F
from torch.fx import GraphModule, Interpreter, Node

from edgepick.progress import progress as progress_bar
from edgepick.quant.methods import COLUMNS, STEP_OVERHEAD, planned_steps, round_conv
from edgepick.quant.pt2e.bias_correction import Means, constant_value, conv_geometry, int8_convs
from edgepick.quant.pt2e.overflow import float_weight


class _Targets:
    """Per conv, sampled output positions of each input batch and the float model's output there."""

    def __init__(self, convs: dict[str, Node], images: int, seed: int):
        self.convs = convs
        self.per_image = max(1, COLUMNS // max(images, 1))
        self.generator = torch.Generator().manual_seed(seed)
        self.positions: dict[str, list[torch.Tensor]] = {name: [] for name in convs}
        self.outputs: dict[str, list[torch.Tensor]] = {name: [] for name in convs}

    def at_conv(self, n: Node, args: tuple, out: torch.Tensor) -> None:
        if n.name in self.convs:
            take = torch.randperm(out.shape[2] * out.shape[3], generator=self.generator)[:self.per_image]
            self.positions[n.name].append(take)
            self.outputs[n.name].append(out.flatten(2)[:, :, take].permute(1, 0, 2).reshape(out.shape[1], -1).clone())

    def columns(self, conv: Node, w_shape: torch.Size, inputs: list[torch.Tensor]) -> torch.Tensor:
        """The input columns [C*kh*kw, P] of CONV at its sampled positions, from each batch's INPUTS."""
        stride, padding, dilation, _ = conv_geometry(conv)
        picked = []
        for x, take in zip(inputs, self.positions[conv.name]):
            cols = F.unfold(x, w_shape[2:], dilation=dilation, padding=padding, stride=stride)  # [N, K, L]
            picked.append(cols[:, :, take].permute(1, 0, 2).reshape(cols.shape[1], -1))
        return torch.cat(picked, dim=1)


def adaround(reference: GraphModule, converted: GraphModule, inputs: Iterable[torch.Tensor], seconds: float | None,
             seed: int = 0, steps: int | None = None, progress: bool = False) -> dict[str, dict]:
    """Learn the weight rounding of every int8 conv of CONVERTED in place (see the module doc), with
    REFERENCE (the observed graph copied before convert) as the float model run on INPUTS (model input
    batches), in about SECONDS, or in STEPS per conv [default: the model's `planned_steps`, a result
    that does not depend on the machine's speed]. Returns per conv node name its output error on the
    sampled positions with nearest rounding and with the learnt rounding, and the steps it took.
    PROGRESS: a bar over the convs."""
    if seconds is not None and seconds <= 0:
        raise ValueError("adaround needs a positive time budget")
    inputs = list(inputs)
    if not inputs:
        raise ValueError("adaround needs at least one calibration input")
    convs = int8_convs(converted)
    missing = sorted(set(convs) - {n.name for n in reference.graph.nodes})
    if missing:
        raise ValueError(f"convs {', '.join(missing)} of the int8 graph are not in the float graph")
    targets = _Targets(convs, sum(x.shape[0] for x in inputs), seed)
    runner = Means(reference, {}, targets.at_conv)
    with torch.no_grad():
        for x in inputs:
            runner.run(x)
    # a step costs the conv's multiplies plus a fixed overhead, which dominates the smallest convs
    cost = {name: math.prod(attrgetter(q.args[1].args[0].target)(converted).shape) + STEP_OVERHEAD
            for name, q in convs.items()}
    if seconds is None:
        steps = steps or planned_steps(cost.values())
    left, deadline = sum(cost.values()), time.perf_counter() + (seconds or 0.0)
    rng = np.random.default_rng(seed)
    report = {}
    bar = progress_bar(desc="AdaRound", total=len(convs), unit="conv", enabled=progress)

    def at_conv(q: Node, conv_inputs: list[torch.Tensor]) -> torch.Tensor:
        """Learn Q's rounding on the int8 model's own inputs to it; returns its new weight."""
        nonlocal left
        name, dq = q.name, q.args[1]
        share = max(deadline - time.perf_counter(), 0.0) * cost[name] / left  # what is left, shared anew
        left -= cost[name]
        codes_now = attrgetter(dq.args[0].target)(converted)
        scale = attrgetter(dq.args[1].target)(converted).float()
        bias = attrgetter(q.args[2].target)(converted).detach().float()
        groups = conv_geometry(q)[3]
        x = targets.columns(q, codes_now.shape, conv_inputs)
        target = torch.cat(targets.outputs.pop(name), dim=1)
        codes, before, after, taken = round_conv(float_weight(reference, name).float().numpy(), scale.numpy(),
                                                 int(dq.args[4]), int(dq.args[5]), bias.numpy(), x.numpy(),
                                                 target.numpy(), groups, share, rng, steps)
        codes_now.copy_(torch.from_numpy(codes).to(torch.int8))
        report[name] = {"error_nearest": before, "error_adaround": after, "steps": taken}
        bar.update(1)
        return constant_value(converted, dq)

    _lockstep(converted, convs, inputs, at_conv)
    bar.close()
    converted.recompile()
    return report


def _lockstep(converted: GraphModule, convs: dict[str, Node], inputs: list[torch.Tensor],
              at_conv: Callable[[Node, list[torch.Tensor]], torch.Tensor]) -> None:
    """Run CONVERTED on all INPUTS together, node by node; before each conv of CONVS, AT_CONV(conv,
    its input in every run) returns the conv's new weight, which every run then uses."""
    runners = []
    for x in inputs:
        run = Interpreter(converted)
        run.env, run.args_iter = {}, iter(converted.graph.process_inputs(x))
        runners.append(run)
    with torch.no_grad():
        for node in converted.graph.nodes:
            if node.op == "output":
                break
            if node.name in convs:
                weight = at_conv(node, [run.env[node.args[0]] for run in runners])
                for run in runners:
                    run.env[node.args[1]] = weight
            for run in runners:
                run.env[node] = run.run_node(node)
                for dead in run.user_to_last_uses.get(node, []):
                    del run.env[dead]
