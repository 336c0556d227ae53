"""AdaRound on an int8 QDQ ONNX graph written by onnxruntime's quantizer, as quant/pt2e/adaround.py
does it on a torch graph: the float model gives each conv's output at sampled positions of the
calibration images (taken in its graph, kept on disk until the conv's turn); the int8 model runs
on all of them together, segment by segment (`lockstep.segments`), and each conv learns its
up/down rounding (`methods.round_conv`) on the input the int8 model gives it there, the convs
before it already rounded. Only the weight codes
change: the scales, the activation ranges and the graph stay as onnxruntime wrote them. numpy only.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from edgepick.onnx_graph import attr
from edgepick.progress import progress as progress_bar
from edgepick.quant.methods import COLUMNS, STEP_OVERHEAD, conv_taps, planned_steps, round_conv
from edgepick.quant.onnx.lockstep import position_sampler, segment_session, segments
from edgepick.quant.onnx.measure import SEVEN_BIT, QdqConv, Values, qdq_convs


@dataclasses.dataclass(frozen=True)
class Geometry:
    """A Conv's pads (top, bottom, left, right), strides, dilations and groups."""

    pads: tuple[int, int, int, int]
    stride: tuple[int, int]
    dilation: tuple[int, int]
    groups: int

    @classmethod
    def of(cls, node: Any) -> Geometry:
        top, left, bottom, right = attr(node, "pads", [0, 0, 0, 0])
        return cls((top, bottom, left, right), tuple(attr(node, "strides", [1, 1])),  # type: ignore[arg-type]
                   tuple(attr(node, "dilations", [1, 1])), int(attr(node, "group", 1)))  # type: ignore[arg-type]

    def pad(self, x: np.ndarray) -> np.ndarray:
        top, bottom, left, right = self.pads
        return np.pad(x, ((0, 0), (0, 0), (top, bottom), (left, right)))


def sampled_rows(x: np.ndarray, kernel: tuple[int, int], geometry: Geometry, take: np.ndarray) -> np.ndarray:
    """The im2col rows [N*P, C*kh*kw] (columns in channel, kernel-row, kernel-column order) of the
    padded input X [N, C, H, W] at the output positions TAKE (flat indices, P of them)."""
    taps = {(i, j): t.reshape(*t.shape[:2], -1)[:, :, take] for i, j, t in
            conv_taps(x, kernel, geometry.stride, geometry.dilation)}
    cols = np.stack([taps[i, j] for i in range(kernel[0]) for j in range(kernel[1])], axis=2)  # [N, C, kh*kw, P]
    return cols.transpose(0, 3, 1, 2).reshape(x.shape[0] * take.size, -1)


def conv2d(x: np.ndarray, w: np.ndarray, geometry: Geometry) -> np.ndarray:
    """A Conv of the padded input X [N, C, H, W] with the weights W [M, C/groups, kh, kw], no bias."""
    groups, (m, c_group, kh, kw) = geometry.groups, w.shape
    wg = w.reshape(groups, m // groups, c_group, kh, kw)
    out = None
    for i, j, t in conv_taps(x, (kh, kw), geometry.stride, geometry.dilation):
        tg = t.reshape(t.shape[0], groups, c_group, *t.shape[2:])
        part = np.einsum("gmc,ngchw->ngmhw", wg[..., i, j], tg, optimize=True)
        if out is None:
            out = part
        else:
            out += part  # in place: a large map's sum held once
    assert out is not None
    return out.reshape(x.shape[0], m, *out.shape[3:])


class SpilledTargets:
    """fp32's outputs at each conv's sampled positions, [M, P] per conv, written to files in FOLDER
    as they are made and read back once, when the conv's turn comes: every conv's at once would stand
    under the lockstep's peak (on a large model some 300 MB)."""

    def __init__(self, folder: Path):
        self.folder = folder
        self.files: dict[str, Path] = {}
        self.shapes: dict[str, list[tuple[int, int]]] = {}

    def add(self, name: str, rows: np.ndarray) -> None:
        """Append ROWS [M, p] to conv NAME's outputs."""
        path = self.files.setdefault(name, self.folder / f"{len(self.files)}.f32")
        with open(path, "ab") as f:
            f.write(np.ascontiguousarray(rows, np.float32).tobytes())
        self.shapes.setdefault(name, []).append(rows.shape)

    def pop(self, name: str) -> np.ndarray:
        """Conv NAME's outputs [M, P] (its parts side by side); its file is deleted."""
        path, shapes = self.files.pop(name), self.shapes.pop(name)
        flat = np.fromfile(path, np.float32)
        path.unlink()
        offsets = np.cumsum([0, *(m * p for m, p in shapes)])
        return np.concatenate([flat[a:b].reshape(shape) for a, b, shape in zip(offsets, offsets[1:], shapes)], axis=1)


def _targets(float_model: Any, convs: dict[str, QdqConv], by_name: dict[str, Any], tensors: list[np.ndarray],
             rng: np.random.Generator, folder: Path) -> tuple[dict[str, list[np.ndarray]], SpilledTargets]:
    """Per conv, the output positions sampled in each tensor and fp32's outputs there (spilled to
    FOLDER), taken in the float graph (`position_sampler`): one image's every conv output held at
    once would be the pass's peak on a large input."""
    per_image = max(1, COLUMNS // len(tensors))
    names = list(convs)
    sizes, sample = position_sampler(float_model, [by_name[name].output[0] for name in names])
    positions: dict[str, list[np.ndarray]] = {name: [] for name in names}
    targets = SpilledTargets(folder)
    for x in tensors:
        takes = [None if size is None else rng.permutation(size)[:per_image] for size in sizes]
        for name, take, y in zip(names, takes, sample(x, takes), strict=True):
            if take is None:  # a map shape inference did not size: returned whole
                take = rng.permutation(y.shape[2])[:per_image]
                y = y[:, :, take]
            positions[name].append(take)
            targets.add(name, y.transpose(1, 0, 2).reshape(y.shape[1], -1))
    return positions, targets


def adaround_onnx(float_model: Any, model: Any, tensors: list[np.ndarray], seconds: float | None,
                  seven_bit: set[str], seed: int = 0, steps: int | None = None, progress: bool = False) -> dict[str, dict]:
    """Learn the weight rounding of the int8 convs of MODEL (QDQ) in place, against the same convs
    of FLOAT_MODEL on TENSORS (model inputs), in about SECONDS, or in STEPS per conv [default: the
    model's `planned_steps`, the same on every machine]; SEVEN_BIT names the convs on the 7-bit grid;
    PROGRESS: a bar over the convs. Returns per conv its output error on the sampled positions with
    nearest rounding and with the learnt one, and the steps it took."""
    if seconds is not None and seconds <= 0:
        raise ValueError("adaround needs a positive time budget")
    if not tensors:
        raise ValueError("adaround needs at least one calibration input")
    by_name = {n.name: n for n in float_model.graph.node}
    convs = {name: c for name, c in qdq_convs(model).items()
             if name in by_name and attr(c.node, "auto_pad", b"NOTSET") in (b"NOTSET", "NOTSET")}
    values, floats = Values(model), Values(float_model)
    rng = np.random.default_rng(seed)
    with tempfile.TemporaryDirectory(prefix="edgepick-adaround-") as folder:
        positions, targets = _targets(float_model, convs, by_name, tensors, rng, Path(folder))
        cost = {name: math.prod(values[c.weight_codes].shape) + STEP_OVERHEAD for name, c in convs.items()}
        if seconds is None:
            steps = steps or planned_steps(cost.values())
        budget = {"left": sum(cost.values()), "deadline": time.perf_counter() + (seconds or 0.0)}
        report: dict[str, dict] = {}
        bar = progress_bar(desc="AdaRound", total=len(convs), unit="conv", enabled=progress)
        image = model.graph.input[0].name
        env = [{image: x} for x in tensors]
        for segment in segments(model, convs):
            if not segment.outputs:
                break
            inputs = [convs[name].node.input[0] for name in segment.wave]
            outputs = list(dict.fromkeys([*segment.outputs, *inputs]))
            session = segment_session(model, dataclasses.replace(segment, outputs=outputs), env[0])
            for e in env:
                e.update(zip(outputs, session.run(outputs, {i: e[i] for i in segment.inputs}), strict=True))
                for name in segment.last:
                    del e[name]
            for name in segment.wave:
                share = max(budget["deadline"] - time.perf_counter(), 0.0) * cost[name] / budget["left"]
                budget["left"] -= cost[name]
                w = floats[by_name[name].input[1]].astype(np.float32)
                report[name] = _round(convs[name], w, values, env, positions[name], targets.pop(name),
                                      SEVEN_BIT if name in seven_bit else 127, share, rng, steps)
                bar.update(1)
            for e in env:
                for name in inputs:
                    if name not in segment.outputs:
                        e.pop(name, None)
        bar.close()
        return report


def _round(c: QdqConv, w: np.ndarray, values: Values, env: list[dict[str, np.ndarray]], positions: list[np.ndarray],
           target: np.ndarray, top: int, seconds: float, rng: np.random.Generator, steps: int | None) -> dict:
    """Learn the rounding of the conv C (float weights W, codes -TOP..TOP) on the inputs the int8
    model gives it in ENV, write its codes, and move its output in ENV by what they change."""
    geometry = Geometry.of(c.node)
    codes_now = values[c.weight_codes].astype(np.float32)
    scale = values[c.weight_scale].astype(np.float32)
    # the solver's rows filled one image at a time, from one image's padded input at a time: on a large input
    # every image's at once, or the rows held twice, would be the pass's peak (a wide depthwise conv's rows:
    # channels x 25 x 4096 floats)
    rows = np.empty((sum(take.size * e[c.node.input[0]].shape[0] for e, take in zip(env, positions, strict=True)),
                     math.prod(w.shape[1:]) * geometry.groups), np.float32)
    filled = 0
    for e, take in zip(env, positions, strict=True):
        part = sampled_rows(geometry.pad(e[c.node.input[0]]), codes_now.shape[2:], geometry, take)
        rows[filled:filled + len(part)], filled = part, filled + len(part)
    bias = ((values[c.bias_codes] * values[c.bias_scale]).astype(np.float32)
            if c.bias_codes is not None and c.bias_scale is not None else np.zeros(codes_now.shape[0], np.float32))
    codes, before, after, taken = round_conv(w, scale, -top, top, bias, rows.T, target, geometry.groups, seconds,
                                             rng, steps)
    delta = ((codes - codes_now) * scale.reshape(-1, 1, 1, 1)).astype(np.float32)
    if delta.any():
        values[c.weight_codes] = codes.astype(np.int8)
        out = c.node.output[0]
        for e in env:  # the conv's output with its new weights, for what follows
            e[out] += conv2d(geometry.pad(e[c.node.input[0]]), delta, geometry)
    return {"error_nearest": before, "error_adaround": after, "steps": taken}
