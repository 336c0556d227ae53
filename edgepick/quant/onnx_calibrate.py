"""Activation ranges of a float ONNX model, streamed: every calibration tensor is used, whatever
their number, and memory stays bounded whatever their size.

onnxruntime's calibrators keep every intermediate output of every calibration tensor before they
reduce them (percentile and entropy: its issue 21979), and its MinMax calibrator drops each full
batch when `CalibMaxIntermediateOutputs` is set (issue 18893). Here each calibration tensor runs
once through the model with the tensors to calibrate as extra outputs, each output updates that
tensor's min, max and histogram, and is freed before the next tensor. Where the outputs of one run
would not fit the memory budget, they are fetched in groups, each run computing only what its
group needs. The ranges (minmax, percentile, entropy, mse) are then read off the histograms.

Torch-free: numpy and onnxruntime.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from typing import Any

import numpy as np

from edgepick.errors import ParameterError
from edgepick.quant.config import CalibMethod
from edgepick.quant.ranges import CHUNK, Histogram, RangeRule

OUTPUT_BUDGET = 512 << 20  # bytes of extra outputs one calibration run may fetch at once


class CalibrationMemoryError(ParameterError):
    """Calibration would not fit this machine's memory."""


def calibrated_tensors(model: Any, op_types: Iterable[str]) -> dict[str, int]:
    """The float tensors (not initializers) that nodes of OP_TYPES read or write in MODEL (shapes
    inferred), as onnxruntime's quantizer asks ranges for them, with their size in bytes (0 when
    a dim is unknown)."""
    import onnx

    ops = set(op_types)
    infos = {v.name: v for v in [*model.graph.value_info, *model.graph.output, *model.graph.input]}
    inits = {i.name for i in model.graph.initializer}
    found: dict[str, int] = {}
    for node in model.graph.node:
        if node.op_type not in ops:
            continue
        for name in [*node.input, *node.output]:
            info = infos.get(name)
            if not name or name in inits or name in found or info is None:
                continue
            tensor = info.type.tensor_type
            if tensor.elem_type != onnx.TensorProto.FLOAT:
                continue
            dims = [d.dim_value if d.HasField("dim_value") else 0 for d in tensor.shape.dim]
            found[name] = int(np.prod(dims)) * 4 if dims and all(dims) else 0
    return found


def available_memory() -> int | None:
    """Bytes this machine can still give a process (Linux's MemAvailable), None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def output_groups(sizes: dict[str, int], budget: int) -> list[list[str]]:
    """SIZES' tensors (in graph order) in consecutive groups of at most BUDGET bytes each (a tensor
    larger than BUDGET alone)."""
    groups: list[list[str]] = [[]]
    used = 0
    for name, size in sizes.items():
        if groups[-1] and used + size > budget:
            groups.append([])
            used = 0
        groups[-1].append(name)
        used += size
    return [g for g in groups if g]


def check_memory(model: Any, sizes: dict[str, int], input_bytes: int, budget: int = OUTPUT_BUDGET) -> int:
    """The bytes calibration will need beyond the float model itself (the largest group of outputs
    a run fetches, and a calibration tensor's binning temporaries), refused in one line naming what
    to change when this machine has less available."""
    largest = max(sizes.values(), default=0)
    need = min(max(largest, budget), sum(sizes.values())) + min(largest, CHUNK * 4) * 3 + input_bytes * 2
    weights = sum(i.ByteSize() for i in model.graph.initializer)
    have = available_memory()
    if have is not None and need + 2 * weights > have:
        raise CalibrationMemoryError(
            f"{{calib:name}}: calibration needs about {(need + 2 * weights) / 2**30:.1f} GB and {have / 2**30:.1f} GB is "
            f"available (the largest activation alone is {largest / 2**20:.0f} MB): give smaller input tensors "
            "(a smaller --size or --input-shape)", calib=None)
    return need


class Collector:
    """Streams input tensors through a float model (onnxruntime, its graph optimisations off so
    that every named tensor exists) and keeps a Histogram per calibrated tensor."""

    def __init__(self, model: Any, sizes: dict[str, int], budget: int = OUTPUT_BUDGET, threads: int = 0,
                 minmax_only: bool = False):
        import onnx
        import onnxruntime as ort

        self.names = list(sizes)
        self.histograms = {name: Histogram() for name in self.names}
        self.groups = output_groups(sizes, budget)
        self.outputs = [o.name for o in model.graph.output]
        augmented = onnx.ModelProto()
        augmented.CopyFrom(model)
        known = set(self.outputs)
        augmented.graph.output.extend(onnx.ValueInfoProto(name=n) for n in self.names if n not in known)
        opts = ort.SessionOptions()
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
        opts.log_severity_level = 3
        if threads:
            opts.intra_op_num_threads = threads
        self.session = ort.InferenceSession(augmented.SerializeToString(), opts, providers=["CPUExecutionProvider"])
        self.input = self.session.get_inputs()[0].name
        self.seen = 0
        self.counts = not minmax_only  # minmax reads the extremes alone: no histogram to fill

    def add(self, x: np.ndarray) -> list[np.ndarray]:
        """Count one input tensor in; returns the model's own outputs for it."""
        outputs: list[np.ndarray] = []
        for k, group in enumerate(self.groups):
            wanted = group + (self.outputs if k == 0 else [])
            values = self.session.run(wanted, {self.input: x})
            for name, value in zip(group, values):
                self.histograms[name].update(value, self.counts)
            if k == 0:
                outputs = values[len(group):]
            del values
        self.seen += 1
        return outputs

    def ranges(self, rule: RangeRule, exact: Iterable[str] = ()) -> dict[str, tuple[float, float]]:
        """Every calibrated tensor's range by RULE; the tensors named in EXACT keep min and max."""
        exact = set(exact)
        plain = RangeRule(CalibMethod.MINMAX)
        return {name: (plain if name in exact else rule).range(h) for name, h in self.histograms.items()}
