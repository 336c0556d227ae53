"""AdaRound for static PTQ (Nagel et al. 2020, "Up or Down? Adaptive Rounding for Post-Training
Quantization"; AIMET's `apply_adaround`): each int8 conv chooses, weight by weight, whether to
round down or up, so that its output on the calibration images stays closest to the float
model's, instead of rounding every weight to its nearest grid point on its own.

The float model runs the calibration images once, and at a sample of each conv's output positions
its output is kept as the target. The int8 model then runs all the images in lockstep, node by
node, as empirical bias correction does, and each conv learns its rounding on the input the int8
model itself gives it there (im2col columns), the convs before it already rounded: what it
compensates includes the errors from upstream. The rounding is a soft variable h(V) in [0, 1] (a rectified sigmoid), trained with
Adam on the output error plus a regulariser that pushes every h to 0 or 1 (its exponent annealed
from 20 to 2 after a warm start), then hardened. The weight scales, the activation ranges and
every other conv stay as they are. A conv whose learnt rounding does not lower its output error
on the sampled positions keeps round-to-nearest, so no conv ends worse on its own data.

The time budget is shared out in proportion to each conv's weight count (its work per step), and
what one conv leaves unspent or overspends is shared again among the convs after it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable
from operator import attrgetter

import torch
import torch.nn.functional as F
from torch.fx import GraphModule, Interpreter, Node

from edgepick.quant.pt2e.bias_correction import _constant, _Means, conv_geometry, int8_convs
from edgepick.quant.pt2e.overflow import _float_weight

COLUMNS = 4096  # input columns (positions) kept per conv, spread over the calibration images
BATCH = 512  # columns per optimisation step
MAX_STEPS = 2000
MIN_STEPS = 20
LEARNING_RATE = 1e-2
REGULARIZATION = 0.01  # AIMET's default weight of the rounding regulariser
WARM_START = 0.2  # share of the steps without the regulariser
BETA = (20.0, 2.0)
_STEP_OVERHEAD = 20_000  # weights' worth of per-step cost that does not grow with the conv
_ZETA, _GAMMA = 1.1, -0.1  # the rectified sigmoid's stretch


def _h(v: torch.Tensor) -> torch.Tensor:
    return torch.clamp(torch.sigmoid(v) * (_ZETA - _GAMMA) + _GAMMA, 0.0, 1.0)


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


def _grouped(w: torch.Tensor, groups: int) -> torch.Tensor:
    """[M, C/g, kh, kw] as [g, M/g, C/g*kh*kw], the order F.unfold gives the columns of each group."""
    return w.reshape(groups, w.shape[0] // groups, -1)


def _output(w: torch.Tensor, bias: torch.Tensor, x: torch.Tensor, groups: int) -> torch.Tensor:
    """The conv's output [M, P] on columns X [C*kh*kw, P] with weights W [g, M/g, K/g]."""
    xg = x.reshape(groups, x.shape[0] // groups, -1)
    return torch.bmm(w, xg).reshape(-1, x.shape[1]) + bias.view(-1, 1)


def _error(y: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """AIMET's reconstruction loss: squared error summed over channels, mean over positions."""
    return (y - target).pow(2).sum(dim=0).mean()


def _round_conv(w: torch.Tensor, scale: torch.Tensor, lo: int, hi: int, bias: torch.Tensor, x: torch.Tensor,
                target: torch.Tensor, groups: int, seconds: float, generator: torch.Generator,
                steps: int | None = None) -> tuple[torch.Tensor, float, float, int]:
    """Learn the rounding of float weights W (scales SCALE per output channel, codes LO..HI) in the
    steps SECONDS afford (or exactly STEPS). Returns (codes, error with nearest rounding, error with
    the learnt one, steps taken)."""
    s = scale.view(-1, *[1] * (w.dim() - 1))
    floor = torch.floor(w / s)
    nearest = torch.clamp(torch.round(w / s), lo, hi)
    rest = (w / s - floor).clamp(1e-4, 1 - 1e-4)
    v = (-torch.log((_ZETA - _GAMMA) / (rest - _GAMMA) - 1)).requires_grad_(True)
    opt = torch.optim.Adam([v], lr=LEARNING_RATE)
    sg = _grouped(s.expand_as(w), groups)
    fg, wg = _grouped(floor, groups), _grouped(nearest * s, groups)
    with torch.no_grad():
        nearest_error = float(_error(_output(wg, bias, x, groups), target))
    fixed = steps is not None
    start, planned, steps = time.perf_counter(), steps or MAX_STEPS, 0
    while steps < planned:
        take = torch.randint(0, x.shape[1], (min(BATCH, x.shape[1]),), generator=generator)
        xb, tb = x[:, take], target[:, take]
        h = _h(v)
        soft = torch.clamp(fg + _grouped(h, groups), lo, hi) * sg
        loss = _error(_output(soft, bias, xb, groups), tb)
        progress = steps / planned
        if progress >= WARM_START:
            beta = BETA[1] + (BETA[0] - BETA[1]) * (1 - (progress - WARM_START) / (1 - WARM_START))
            loss = loss + REGULARIZATION * (1 - (2 * h - 1).abs().pow(beta)).sum()
        opt.zero_grad()
        loss.backward()
        opt.step()
        steps += 1
        if steps == 5 and not fixed:  # plan the steps this conv's share of the budget affords
            per_step = (time.perf_counter() - start) / steps
            planned = int(min(MAX_STEPS, max(MIN_STEPS, seconds / per_step)))
    with torch.no_grad():
        codes = torch.clamp(floor + (_h(v) >= 0.5).float(), lo, hi)
        learnt_error = float(_error(_output(_grouped(codes * s, groups), bias, x, groups), target))
    if learnt_error >= nearest_error:
        return nearest, nearest_error, nearest_error, steps
    return codes, nearest_error, learnt_error, steps


def adaround(reference: GraphModule, converted: GraphModule, inputs: Iterable[torch.Tensor], seconds: float,
             seed: int = 0, steps: int | None = None) -> dict[str, dict]:
    """Learn the weight rounding of every int8 conv of CONVERTED in place (see the module doc), with
    REFERENCE (the observed graph copied before convert) as the float model run on INPUTS (model input
    batches), in about SECONDS (or STEPS steps per conv, for a result that does not depend on the
    machine's speed). Returns per conv node name its output error on the sampled positions with
    nearest rounding and with the learnt rounding, and the steps it took."""
    if seconds <= 0:
        raise ValueError("adaround needs a positive time budget")
    inputs = list(inputs)
    if not inputs:
        raise ValueError("adaround needs at least one calibration input")
    convs = int8_convs(converted)
    missing = sorted(set(convs) - {n.name for n in reference.graph.nodes})
    if missing:
        raise ValueError(f"convs {', '.join(missing)} of the int8 graph are not in the float graph")
    targets = _Targets(convs, sum(x.shape[0] for x in inputs), seed)
    runner = _Means(reference, {}, targets.at_conv)
    with torch.no_grad():
        for x in inputs:
            runner.run(x)
    # a step costs the conv's multiplies plus a fixed overhead, which dominates the smallest convs
    cost = {name: math.prod(attrgetter(q.args[1].args[0].target)(converted).shape) + _STEP_OVERHEAD
            for name, q in convs.items()}
    left, deadline = sum(cost.values()), time.perf_counter() + seconds
    generator = torch.Generator().manual_seed(seed)
    report = {}

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
        with torch.enable_grad():
            codes, before, after, taken = _round_conv(_float_weight(reference, name).float(), scale, int(dq.args[4]),
                                                      int(dq.args[5]), bias, x, target, groups, share, generator, steps)
        codes_now.copy_(codes.to(torch.int8))
        report[name] = {"error_nearest": before, "error_adaround": after, "steps": taken}
        return _constant(converted, dq)

    _lockstep(converted, convs, inputs, at_conv)
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
