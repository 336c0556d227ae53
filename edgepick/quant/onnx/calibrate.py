"""Activation ranges of a float ONNX model, streamed: every calibration tensor is used, whatever
their number, and memory stays bounded whatever their size.

onnxruntime's calibrators keep every intermediate output of every calibration tensor before they
reduce them (percentile and entropy: its issue 21979), and its MinMax calibrator drops each full
batch when `CalibMaxIntermediateOutputs` is set (issue 18893). Here each calibration tensor runs
once through the model with the tensors to calibrate as extra outputs, each output updates that
tensor's min, max and histogram, and is freed before the next tensor. Where the outputs of one run
would not fit the memory budget, they are fetched in groups, each run computing only what its
group needs. A run's tensors are counted on every core at once (the counting lets go of the
GIL), while onnxruntime's threads wait for the next run. The ranges (minmax, percentile, entropy,
mse) are then read off the histograms, a Concat's output spanning its inputs' (`concat_spans`).

Torch-free: numpy, OpenCV and onnxruntime.
"""

from __future__ import annotations

import math
import os
from collections.abc import Container, Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from edgepick.errors import ParameterError
from edgepick.onnx_graph import Graph, copy_model
from edgepick.quant.config import CalibMethod
from edgepick.quant.onnx.lockstep import mean_node, tensor_ranks
from edgepick.quant.ranges import CHUNK, SAMPLED, Histogram, RangeRule

OUTPUT_BUDGET = 512 << 20  # bytes of extra outputs one calibration run may fetch at once
# threads counting a run's tensors into their histograms at once (memory-bound: more gain nothing)
COUNTING_THREADS = min(os.cpu_count() or 1, 8)


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


def release_memory() -> None:
    """Hand the memory freed by a large step back to the system: glibc's allocator keeps freed blocks
    for the process, so the next step's peak would stand on the last one's (no-op elsewhere)."""
    import ctypes
    import gc

    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


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
    a run fetches, and the binning temporaries of the tensors counted at once), refused in one line naming what
    to change when this machine has less available."""
    largest = max(sizes.values(), default=0)
    need = (min(max(largest, budget), sum(sizes.values())) + min(largest, CHUNK * 4) * 3 * COUNTING_THREADS
            + input_bytes * 2)
    weights = sum(i.ByteSize() for i in model.graph.initializer)
    have = available_memory()
    if have is not None and need + 2 * weights > have:
        raise CalibrationMemoryError(
            f"{{calib:name}}: calibration needs about {(need + 2 * weights) / 2**30:.1f} GB and {have / 2**30:.1f} GB is "
            f"available (the largest activation alone is {largest / 2**20:.0f} MB): give smaller input tensors "
            "(a smaller --size or --input-shape)", calib=None)
    return need


def _shapes(model: Any) -> dict[str, list[int]]:
    """The static shape of each tensor MODEL's shape inference knows (0 for an unknown dim)."""
    return {v.name: [d.dim_value if d.HasField("dim_value") else 0 for d in v.type.tensor_type.shape.dim]
            for v in [*model.graph.value_info, *model.graph.output, *model.graph.input]}


def _spatial_step(shape: list[int]) -> int:
    """The stride along H and W that leaves a [N, C, H, W] tensor of SHAPE about SAMPLED values (1:
    all of them, as for any other tensor)."""
    if len(shape) != 4 or not all(shape) or int(np.prod(shape)) <= SAMPLED:
        return 1
    return math.ceil(math.sqrt(np.prod(shape) / SAMPLED))


def _sampled(g: Graph, name: str, step: int, k: int) -> tuple[list[Any], list[str]]:
    """The nodes that give tensor NAME's strided sample (every STEP-th row and column), its min and
    its max (their constants added to the graph G), and their output names."""
    from onnx import helper

    tag = f"edgepick_calib_{k}"
    for suffix, values in (("starts", [0, 0]), ("ends", [2 ** 62, 2 ** 62]), ("axes", [2, 3]), ("steps", [step, step])):
        g.add_initializer(f"{tag}_{suffix}", values, np.int64)
    nodes = [helper.make_node("Slice", [name, f"{tag}_starts", f"{tag}_ends", f"{tag}_axes", f"{tag}_steps"],
                              [f"{name}_sample"], name=f"{tag}_slice"),
             helper.make_node("ReduceMin", [name], [f"{name}_min"], keepdims=0, name=f"{tag}_min"),
             helper.make_node("ReduceMax", [name], [f"{name}_max"], keepdims=0, name=f"{tag}_max")]
    return nodes, [f"{name}_sample", f"{name}_min", f"{name}_max"]


def _with_samples(model: Any, group: list[str], steps: dict[str, int], means: Container[str] = (),
                  ranks: Mapping[str, int] | None = None) -> tuple[Any, list[str]]:
    """A copy of MODEL whose graph outputs are GROUP's tensors, a feature map of step > 1 as its
    sample, min and max, and those named in MEANS (of RANKS) also as their per-channel means; the
    sampling nodes right after the node that makes their tensor, so that onnxruntime, which runs
    nodes in the order given, frees the whole map as early as without them."""
    import onnx

    part = copy_model(model)
    g = Graph(part)
    del part.graph.output[:]
    fetch: list[str] = []
    after: dict[str, list[Any]] = {}
    for k, name in enumerate(group):
        nodes, names = ([], [name]) if steps[name] == 1 else _sampled(g, name, steps[name], k)
        if name in means:
            nodes.append(mean_node(part, g, name, (ranks or {}).get(name, 4)))
            names.append(nodes[-1].output[0])
        if nodes:
            after[name] = nodes
        fetch.extend(names)
    g.insert_after_producers(after)
    part.graph.output.extend(onnx.ValueInfoProto(name=n) for n in fetch)
    return part, fetch


class Collector:
    """Streams input tensors through a float model (onnxruntime, its graph optimisations off so
    that every named tensor exists) and keeps a Histogram per calibrated tensor.

    A feature map of more than SAMPLED values is fetched as a strided slice of its H and W (the
    histogram's even sample, taken in the graph) with its exact min and max: what a run fetches is
    then small whatever the input size. Each group of tensors (`output_groups`) gets a session of
    its own whose graph outputs are that group alone: onnxruntime keeps every graph output of a run
    alive to its end, fetched or not."""

    def __init__(self, model: Any, sizes: dict[str, int], budget: int = OUTPUT_BUDGET, threads: int = 0,
                 minmax_only: bool = False, means: Iterable[str] = (), mean_inputs: int = 0,
                 shared_concat_inputs: bool = False):
        self.names = list(sizes)
        # every Concat input on its output's grid, a Split's outputs on its input's (`concat_spans`, placement joins)
        self.shared_concat_inputs = shared_concat_inputs
        # per-channel means of these tensors on the inputs numbered below MEAN_INPUTS (bias correction's fp32 side)
        self.mean_inputs = mean_inputs
        self.means: dict[str, dict[int, np.ndarray]] = {n: {} for n in means if n in sizes} if mean_inputs else {}
        self.histograms = {name: Histogram() for name in self.names}
        inputs = {i.name for i in model.graph.input}
        self.inputs = [n for n in self.names if n in inputs]  # counted from the tensor itself
        shapes = _shapes(model)
        self.steps = {n: _spatial_step(shapes.get(n, [])) for n in self.names if n not in inputs}
        fetched = {n: sizes[n] // self.steps[n] ** 2 for n in self.steps}
        self.groups = output_groups(fetched, budget)
        self.model, self.threads, self.ranks = model, threads, tensor_ranks(model)
        self.counters = ThreadPoolExecutor(min(threads or COUNTING_THREADS, COUNTING_THREADS),
                                           thread_name_prefix="edgepick-calib")
        self.sessions: list[Any] = []  # opened by the first add()
        self.fetches: list[list[str]] = []
        self.input = Graph(model).inputs[0]
        self.seen = 0
        self.counts = not minmax_only  # minmax reads the extremes alone: no histogram to fill

    def _open(self) -> None:
        """One onnxruntime session per group, its graph outputs that group alone."""
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
        opts.log_severity_level = 3
        # an arena, so that a run reuses its freed blocks (without one every feature map is a fresh mmap,
        # page-faulted in), shrunk after each run and given back by close(); no planned pattern (it holds the
        # run's whole plan); nodes in priority order, so that each sampling node runs as soon as its map is
        # made (onnxruntime's default order ran them last, holding every feature map: 2.7 GB where 0.8 GB do)
        opts.enable_cpu_mem_arena, opts.enable_mem_pattern = True, False
        opts.execution_order = ort.ExecutionOrder.PRIORITY_BASED
        # its threads sleep as soon as a run ends, rather than spin on the cores the histograms are counted on
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        if self.threads:
            opts.intra_op_num_threads = self.threads
        self.run_options = ort.RunOptions()
        self.run_options.add_run_config_entry("memory.enable_memory_arena_shrinkage", "cpu:0")
        self.fetches = []
        for group in self.groups:
            part, fetch = _with_samples(self.model, group, self.steps, self.means, self.ranks)
            self.fetches.append(fetch)
            self.sessions.append(ort.InferenceSession(part.SerializeToString(), opts, providers=["CPUExecutionProvider"]))

    def close(self) -> None:
        """Let the sessions and their arenas go (the steps between calibration passes need the memory);
        the next add() opens them again."""
        self.sessions = []
        release_memory()

    def add(self, x: np.ndarray, index: int | None = None) -> None:
        """Count one input tensor in (the INDEX-th calibration tensor, for the means)."""
        if not self.sessions:
            self._open()
        for name in self.inputs:
            self.histograms[name].update(x, self.counts)
        for group, fetch, session in zip(self.groups, self.fetches, self.sessions):
            values = dict(zip(fetch, session.run(fetch, {self.input: x}, self.run_options)))
            if index is not None and index < self.mean_inputs:
                for name in group:
                    if name in self.means:
                        self.means[name][index] = values[f"{name}_channel_means"].astype(np.float64)
            # the tensors' histograms are independent and their counting lets go of the GIL: counted on
            # every core while onnxruntime's threads wait for the next run
            list(self.counters.map(self._count, group, [values] * len(group)))
            del values
        self.seen += 1

    def _count(self, name: str, values: dict[str, np.ndarray]) -> None:
        """Tensor NAME's values of one run (VALUES: the run's fetched outputs) into its histogram."""
        hist = self.histograms[name]
        if self.steps[name] == 1:
            hist.update(values[name], self.counts)
            return
        low, high = float(values[f"{name}_min"]), float(values[f"{name}_max"])
        if math.isfinite(low) and math.isfinite(high):
            hist.extend(low, high)
        if self.counts:
            hist.update(values[f"{name}_sample"])

    def channel_means(self, count: int) -> dict[str, list[np.ndarray]]:
        """Per tensor asked for, its [1, channels] means on the inputs numbered 0 to COUNT - 1, where
        every one was counted in with its number (empty otherwise)."""
        if not self.means or any(k not in got for got in self.means.values() for k in range(count)):
            return {}
        return {name: [got[k] for k in range(count)] for name, got in self.means.items()}

    def ranges(self, rule: RangeRule, exact: Iterable[str] = ()) -> dict[str, tuple[float, float]]:
        """Every calibrated tensor's range by RULE (a Concat's output the span of its inputs', see
        concat_spans); the tensors named in EXACT keep min and max."""
        exact = set(exact)
        plain = RangeRule(CalibMethod.MINMAX)
        read = {name: (plain if name in exact else rule).range(h) for name, h in self.histograms.items()}
        return concat_spans(self.model, read, self.shared_concat_inputs, exact)


def concat_spans(model: Any, ranges: dict[str, tuple[float, float]], shared_inputs: bool = False,
                 exact: Container[str] = ()) -> dict[str, tuple[float, float]]:
    """RANGES with each Concat's output given the span of its inputs' ranges (in graph order, so that
    a Concat of Concats spans the spans). Its values are its inputs' values, so the span is a range
    each input fits; an input whose own range is that span (the one with the largest values, and
    with the smallest: every Relu's input starts at 0) then gets the output's very qparams, and
    onnxruntime's QLinearConcat copies its bytes instead of requantizing them (what that is worth:
    docs/quantization.md, the conformance suite's Concat spans). SHARED_INPUTS: every input takes the
    span too, and a Split's outputs its input's, as NNCF's files for OpenVINO have them (placement
    joins; `shared_grids`): OpenVINO requantizes an input on another grid than the output's in an
    elementwise pass of its own, a full feature map each. But not where the Concat's output is EXACT
    (it reaches a graph output through no conv: a detector's head joining box and class values),
    whose inputs' own grids decide what the output holds."""
    spans = dict(ranges)
    grouped: set[str] = set()
    if shared_inputs:
        for group in shared_grids(model, ranges, exact):
            span = (min(ranges[name][0] for name in group), max(ranges[name][1] for name in group))
            spans.update({name: span for name in group})
            grouped.update(group)
    for node in model.graph.node:
        if (node.op_type == "Concat" and node.output[0] in spans and node.output[0] not in grouped and len(node.input)
                and all(name in spans for name in node.input)):
            spans[node.output[0]] = (min(spans[n][0] for n in node.input), max(spans[n][1] for n in node.input))
    return spans


def shared_grids(model: Any, ranges: Mapping[str, tuple[float, float]], exact: Container[str] = ()) -> list[set[str]]:
    """The sets of RANGES' tensors that placement joins reads on one grid: each Concat's inputs and
    output (but an EXACT output's), each Split's input and outputs (onnxruntime's writer gives the
    outputs the input's grid), joined where they share a tensor. A Concat is left out of them where
    the shared span would reach past what a Relu or Clip writing one of its inputs can write: the
    writer drops such an op after a quantized one and lets the grid clamp for it, which the wider
    grid would not."""
    writers = {o: n.op_type for n in model.graph.node for o in n.output}
    ties = {k: (n.op_type, [*n.input[:1], *n.output] if n.op_type == "Split" else [n.output[0], *n.input])
            for k, n in enumerate(model.graph.node)
            if n.op_type in ("Concat", "Split") and len(n.input) and n.output[0] not in exact
            and all(name in ranges for name in [*n.input[:1 if n.op_type == "Split" else None], *n.output])}
    while True:
        groups: list[tuple[set[str], set[int]]] = []  # the tensors, and the ties that joined them
        for key, (_, names) in ties.items():
            joined = [g for g in groups if g[0].intersection(names)]
            groups = [g for g in groups if g not in joined]
            groups.append((set(names).union(*(g[0] for g in joined)), {key}.union(*(g[1] for g in joined))))
        unclamped = [keys for names, keys in groups if not _clamps(names, ranges, writers)]
        if not unclamped:
            return [names for names, _ in groups]
        for keys in unclamped:  # the Concats that reach past such an op alone, else all of the set's, keep their own grids
            concats = [k for k in keys if ties[k][0] == "Concat"]
            alone = [k for k in concats if not _clamps(set(ties[k][1]), ranges, writers)]
            for key in alone or concats or keys:
                del ties[key]


def _clamps(group: set[str], ranges: Mapping[str, tuple[float, float]], writers: Mapping[str, str]) -> bool:
    """Whether GROUP's span stays within what every Relu or Clip writing one of its tensors writes."""
    low, high = min(ranges[n][0] for n in group), max(ranges[n][1] for n in group)
    for name in group:
        if writers.get(name) == "Relu" and low < 0:
            return False
        if writers.get(name) == "Clip" and (low < min(ranges[name][0], 0.0) or high > max(ranges[name][1], 0.0)):
            return False
    return True
