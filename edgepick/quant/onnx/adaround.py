"""AdaRound on an int8 QDQ ONNX graph written by onnxruntime's quantizer, as quant/pt2e/adaround.py
does it on a torch graph: the float model gives each conv's output at sampled positions of the
calibration images; the int8 model runs on all of them together, segment by segment
(`onnx_measure._segments`), and each conv learns its up/down rounding (`adaround._round_conv`) on
the input the int8 model gives it there, the convs before it already rounded. Only the weight
codes change: the scales, the activation ranges and the graph stay as onnxruntime wrote them.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from edgepick.onnx_graph import attr
from edgepick.quant.onnx.measure import SEVEN_BIT, Values, _runner, _segment_session, _segments, qdq_convs
from edgepick.quant.pt2e.adaround import _STEP_OVERHEAD, COLUMNS, _round_conv


def _geometry(node: Any) -> tuple[tuple[int, int, int, int], tuple[int, int], tuple[int, int], int]:
    """(pads as F.pad takes them: left, right, top, bottom), strides, dilations, groups of a Conv."""
    top, left, bottom, right = attr(node, "pads", [0, 0, 0, 0])
    return ((left, right, top, bottom), tuple(attr(node, "strides", [1, 1])), tuple(attr(node, "dilations", [1, 1])),
            int(attr(node, "group", 1)))


def adaround_onnx(float_model: Any, model: Any, tensors: list[np.ndarray], seconds: float, seven_bit: set[str],
                  seed: int = 0, steps: int | None = None) -> dict[str, dict]:
    """Learn the weight rounding of the int8 convs of MODEL (QDQ) in place, against the same convs
    of FLOAT_MODEL on TENSORS (model inputs), in about SECONDS (or STEPS per conv); SEVEN_BIT names
    the convs on the 7-bit grid. Returns per conv its output error on the sampled positions with
    nearest rounding and with the learnt one, and the steps it took."""
    if seconds <= 0:
        raise ValueError("adaround needs a positive time budget")
    if not tensors:
        raise ValueError("adaround needs at least one calibration input")
    by_name = {n.name: n for n in float_model.graph.node}
    convs = {name: c for name, c in qdq_convs(model).items()
             if name in by_name and attr(c.node, "auto_pad", b"NOTSET") in (b"NOTSET", "NOTSET")}
    values, floats = Values(model), Values(float_model)
    generator = torch.Generator().manual_seed(seed)
    per_image = max(1, COLUMNS // len(tensors))
    names = list(convs)
    wanted = [by_name[name].output[0] for name in names]
    fp32 = _runner(float_model, wanted)
    positions: dict[str, list[torch.Tensor]] = {name: [] for name in names}
    targets: dict[str, list[torch.Tensor]] = {name: [] for name in names}
    for x in tensors:
        for name, y in zip(names, fp32(x, wanted), strict=True):
            out = torch.from_numpy(y)
            take = torch.randperm(out.shape[2] * out.shape[3], generator=generator)[:per_image]
            positions[name].append(take)
            targets[name].append(out.flatten(2)[:, :, take].permute(1, 0, 2).reshape(out.shape[1], -1).clone())
    cost = {name: math.prod(values[c.weight_codes].shape) + _STEP_OVERHEAD for name, c in convs.items()}
    left, deadline = sum(cost.values()), time.perf_counter() + seconds
    report: dict[str, dict] = {}
    image = model.graph.input[0].name
    env = [{image: x} for x in tensors]
    for segment in _segments(model, convs):
        if not segment.outputs:
            break
        inputs = [convs[name].node.input[0] for name in segment.wave]
        outputs = list(dict.fromkeys([*segment.outputs, *inputs]))
        session = _segment_session(model, dataclasses.replace(segment, outputs=outputs), env[0])
        for e in env:
            e.update(zip(outputs, session.run(outputs, {i: e[i] for i in segment.inputs}), strict=True))
            for name in segment.last:
                del e[name]
        for name in segment.wave:
            c = convs[name]
            pads, stride, dilation, groups = _geometry(c.node)
            codes_now = torch.from_numpy(values[c.weight_codes].astype(np.float32))
            scale = torch.from_numpy(values[c.weight_scale].astype(np.float32))
            xs = [F.pad(torch.from_numpy(e[c.node.input[0]]), pads) for e in env]
            columns = torch.cat([F.unfold(x, codes_now.shape[2:], dilation=dilation, stride=stride)[:, :, take]
                                 .permute(1, 0, 2).reshape(-1, take.numel() * x.shape[0])
                                 for x, take in zip(xs, positions[name], strict=True)], dim=1)
            bias = (torch.from_numpy((values[c.bias_codes] * values[c.bias_scale]).astype(np.float32))
                    if c.bias_codes is not None and c.bias_scale is not None else torch.zeros(codes_now.shape[0]))
            top = SEVEN_BIT if name in seven_bit else 127
            share = max(deadline - time.perf_counter(), 0.0) * cost[name] / left
            left -= cost[name]
            w = torch.from_numpy(floats[by_name[name].input[1]].astype(np.float32))
            with torch.enable_grad():
                codes, before, after, taken = _round_conv(w, scale, -top, top, bias, columns,
                                                          torch.cat(targets.pop(name), dim=1), groups, share,
                                                          generator, steps)
            report[name] = {"error_nearest": before, "error_adaround": after, "steps": taken}
            delta = (codes - codes_now) * scale.view(-1, 1, 1, 1)
            if delta.any():
                values[c.weight_codes] = codes.numpy().astype(np.int8)
                out = c.node.output[0]
                for e, x in zip(env, xs, strict=True):  # the conv's output with its new weights, for what follows
                    e[out] = e[out] + F.conv2d(x, delta, stride=stride, dilation=dilation, groups=groups).numpy()
        for e in env:
            for name in inputs:
                if name not in segment.outputs:
                    e.pop(name, None)
    return report
