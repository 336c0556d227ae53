"""Streaming calibration of an ONNX model (quant/onnx/calibrate.py): every tensor counted, whatever
their number, memory bounded, and the ranges the int8 file is written with."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest

from edgepick.quant.config import CalibMethod, PtqMethods, QuantConfig
from edgepick.quant.onnx.calibrate import (
    CalibrationMemoryError,
    Collector,
    calibrated_tensors,
    check_memory,
    concat_spans,
    output_groups,
)
from edgepick.quant.onnx.static import OnnxOptions, quantize_onnx_static
from edgepick.quant.ranges import RangeRule
from tests.quant.onnx_models import conv_relu_model, helper_model, optimized_ops


def _inputs(count: int) -> list[np.ndarray]:
    """COUNT inputs whose range grows with each one: the last tensor holds values no other has."""
    rng = np.random.default_rng(count)
    return [(rng.normal(0, 1, (1, 2, 32, 32)) * (1 + k)).astype(np.float32) for k in range(count)]


def _activations(xs: list[np.ndarray], w: np.ndarray, b: np.ndarray) -> dict[str, np.ndarray]:
    """Every value each calibrated tensor takes over XS (the conv in float64: onnxruntime's float32
    sums round differently, a value at the very end of a range may differ in its last bit)."""
    conv = [np.einsum("oc,nchw->nohw", w[:, :, 0, 0].astype(np.float64), x) + b[None, :, None, None] for x in xs]
    return {"input": np.concatenate([x.ravel() for x in xs]), "conv_out": np.concatenate([c.ravel() for c in conv]),
            "output": np.concatenate([np.maximum(c, 0).ravel() for c in conv])}


@pytest.mark.parametrize("count", [1, 4, 5, 33])
@pytest.mark.parametrize("method", [CalibMethod.MINMAX, CalibMethod.PERCENTILE, CalibMethod.ENTROPY, CalibMethod.MSE])
def test_every_method_uses_every_tensor_whatever_their_number(tmp_path, method, count):
    path, w, b = conv_relu_model(tmp_path / "m.onnx")
    model = onnx.shape_inference.infer_shapes(onnx.load(str(path)))
    sizes = calibrated_tensors(model, ["Conv", "Relu"])
    assert list(sizes) == ["input", "conv_out", "output"] and sizes["input"] == 2 * 1024 * 4
    collector = Collector(model, sizes, budget=sizes["input"])  # one tensor per run: two runs per input
    assert collector.groups == [["conv_out"], ["output"]] and collector.inputs == ["input"]
    xs = _inputs(count)
    for x in xs:
        collector.add(x)
    rule = RangeRule(method, 99.9)
    ranges = collector.ranges(rule)
    for name, values in _activations(xs, w, b).items():
        hist = collector.histograms[name]
        assert hist.total == values.size  # every value of every tensor counted once, in its bin
        edges = hist.edges()
        edges[0], edges[-1] = min(edges[0], values.min()), max(edges[-1], values.max())  # float32's last bit
        reference = np.histogram(values, bins=edges)[0]
        assert np.abs(np.cumsum(reference) - np.cumsum(hist.counts)).max() <= 2
        low, high = ranges[name]
        if method == CalibMethod.MINMAX:
            assert (low, high) == (pytest.approx(values.min(), abs=1e-5), pytest.approx(values.max(), abs=1e-5))
        elif method == CalibMethod.PERCENTILE:
            ref = np.percentile(values, [0.1, 99.9], method="inverted_cdf")
            # to a bin, or to the next value where the tail holds a few (a value within float32 rounding of an edge)
            slack = 2 * hist.width + 0.02 * (ref[1] - ref[0])
            assert abs(low - ref[0]) <= slack and abs(high - ref[1]) <= slack, (name, low, high, ref)
        else:  # the rule reads the same histogram (tests/quant/test_ranges.py): a range inside the values'
            assert values.min() - 1e-5 <= low <= high <= values.max() + 1e-5


def test_the_int8_file_takes_its_input_range_from_the_last_of_33_tensors(tmp_path):
    """onnxruntime's MinMax calibrator with CalibMaxIntermediateOutputs drops each full batch of
    outputs (its issue 18893): with 33 tensors the range would miss the last one's values."""
    path, _, _ = conv_relu_model(tmp_path / "m.onnx")
    xs = _inputs(33)
    first_32 = np.concatenate([x.ravel() for x in xs[:32]])
    xs[-1][0, 0, 0, 0] = 2 * first_32.max()  # only the last tensor reaches this far
    result = quantize_onnx_static(path, xs, tmp_path / "int8.onnx", QuantConfig(calib_method="minmax"),
                                  PtqMethods(bias_correction="none"), progress=False)
    assert result.calib_tensors == 33
    model = onnx.load(result.out)
    scale = next(onnx.numpy_helper.to_array(i) for i in model.graph.initializer if i.name == "input_scale")
    values = np.concatenate([x.ravel() for x in xs])
    assert float(scale) == pytest.approx((values.max() - min(values.min(), 0.0)) / 255, rel=1e-5)
    assert float(scale) > 1.3 * (first_32.max() - values.min()) / 255
    quant = json.loads({p.key: p.value for p in model.metadata_props}["edgepick.quant"])
    assert quant["calib_images"] == 33 and quant["ranges"] == {"rule": "minmax", "exact_tensors": 2}


def test_outputs_are_fetched_in_groups_within_the_budget():
    sizes = {"a": 100, "b": 300, "c": 50, "d": 400, "e": 10}
    assert output_groups(sizes, 400) == [["a", "b"], ["c"], ["d"], ["e"]]
    assert output_groups(sizes, 10_000) == [list(sizes)]
    assert output_groups({"big": 900, "small": 1}, 100) == [["big"], ["small"]]  # a tensor over budget runs alone


def test_a_calibration_that_cannot_fit_is_refused_in_one_line(tmp_path, monkeypatch):
    path, _, _ = conv_relu_model(tmp_path / "m.onnx")
    model = onnx.shape_inference.infer_shapes(onnx.load(str(path)))
    sizes = calibrated_tensors(model, ["Conv", "Relu"])
    monkeypatch.setattr("edgepick.quant.onnx.calibrate.available_memory", lambda: 100)
    with pytest.raises(CalibrationMemoryError, match=r"^calib: calibration needs about .* GB and 0.0 GB is "
                                                     r"available .*: give smaller input tensors"):
        check_memory(model, sizes, input_bytes=512)
    monkeypatch.setattr("edgepick.quant.onnx.calibrate.available_memory", lambda: None)  # unknown: no refusal
    assert check_memory(model, sizes, input_bytes=512) > 0


def test_a_large_feature_map_is_fetched_as_a_strided_sample_with_its_exact_extremes(tmp_path):
    path, w, b = conv_relu_model(tmp_path / "big.onnx", shape=(1, 2, 1024, 1024))
    model = onnx.shape_inference.infer_shapes(onnx.load(str(path)))
    sizes = calibrated_tensors(model, ["Conv", "Relu"])
    collector = Collector(model, sizes)
    assert collector.steps == {"conv_out": 2, "output": 2}  # 3 x 1024 x 1024 values: every 2nd row and column
    x = np.random.default_rng(0).normal(0, 1, (1, 2, 1024, 1024)).astype(np.float32)
    x[0, 0, 511, 511] = 40.0  # on a row and column the sample skips: only the extremes see it
    collector.add(x)
    acts = _activations([x], w, b)
    for name in ("conv_out", "output"):
        hist = collector.histograms[name]
        assert hist.total == 3 * 512 * 512
        assert hist.min == pytest.approx(acts[name].min(), abs=1e-4) and hist.max == pytest.approx(acts[name].max(), abs=1e-4)


def test_the_conv_output_means_are_counted_on_the_first_inputs_whole_or_sampled(tmp_path):
    """Bias correction's fp32 side comes from the calibration pass: per channel, the mean of the whole
    conv output (not of its strided sample), on the inputs numbered below mean_inputs."""
    path, w, b = conv_relu_model(tmp_path / "big.onnx", shape=(1, 2, 1024, 1024))
    model = onnx.shape_inference.infer_shapes(onnx.load(str(path)))
    collector = Collector(model, calibrated_tensors(model, ["Conv", "Relu"]), means=["conv_out"], mean_inputs=2)
    assert collector.steps["conv_out"] == 2
    rng = np.random.default_rng(1)
    xs = [rng.normal(0.5 * k, 1, (1, 2, 1024, 1024)).astype(np.float32) for k in range(3)]
    for k in (1, 2, 0):  # the held-out first one last, as calib_method auto counts them
        collector.add(xs[k], k)
    got = collector.channel_means(2)
    assert list(got) == ["conv_out"] and len(got["conv_out"]) == 2
    for k in range(2):
        want = _activations([xs[k]], w, b)["conv_out"].reshape(3, -1).mean(axis=1)
        np.testing.assert_allclose(got["conv_out"][k][0], want, rtol=1e-4, atol=1e-4)
    assert collector.channel_means(3) == {}  # the third was counted past mean_inputs


def test_bias_correction_from_the_calibration_pass_gives_the_file_its_own_pass_gives(tmp_path, monkeypatch):
    path, _, _ = conv_relu_model(tmp_path / "m.onnx")
    xs = _inputs(12)
    with monkeypatch.context() as patched:
        patched.setattr("edgepick.quant.onnx.measure.channel_means", lambda *a: pytest.fail("fp32 run again"))
        quantize_onnx_static(path, xs, tmp_path / "counted.onnx", progress=False)
    monkeypatch.setattr(Collector, "channel_means", lambda self, count: {})  # bias correction runs fp32 itself
    quantize_onnx_static(path, xs, tmp_path / "own.onnx", progress=False)
    counted, own = (onnx.load(str(tmp_path / f"{n}.onnx")) for n in ("counted", "own"))
    biases = [i for i in counted.graph.initializer if i.data_type == onnx.TensorProto.INT32]
    assert biases and json.loads(dict((p.key, p.value) for p in counted.metadata_props)["edgepick.quant"]
                                 )["measured_images"] > 0
    for mine, theirs in zip(counted.graph.initializer, own.graph.initializer, strict=True):
        assert onnx.numpy_helper.to_array(mine).tobytes() == onnx.numpy_helper.to_array(theirs).tobytes(), mine.name


def _concat_model(path):
    """Two Relu branches of one input, one about four times the other's size, joined by a Concat
    that a 1x1 conv reads."""
    from onnx import helper

    rng = np.random.default_rng(3)
    w1, w2 = rng.normal(0, 1, (3, 2, 1, 1)), rng.normal(0, 4, (3, 2, 1, 1))
    w3 = rng.normal(0, 0.3, (2, 6, 1, 1))
    nodes = [helper.make_node("Conv", ["input", "w1"], ["a"], name="conv_a"),
             helper.make_node("Relu", ["a"], ["relu_a"], name="relu_a"),
             helper.make_node("Conv", ["input", "w2"], ["b"], name="conv_b"),
             helper.make_node("Relu", ["b"], ["relu_b"], name="relu_b"),
             helper.make_node("Concat", ["relu_a", "relu_b"], ["joined"], name="concat", axis=1),
             helper.make_node("Conv", ["joined", "w3"], ["output"], name="conv_out")]
    return helper_model(nodes, [("input", [1, 2, 32, 32])], [("output", [1, 2, 32, 32])],
                        {"w1": w1, "w2": w2, "w3": w3}, path)


def test_a_concats_range_spans_its_inputs_and_the_wider_one_shares_its_qparams(tmp_path):
    model = _concat_model(tmp_path / "concat.onnx")
    xs = _inputs(6)
    proto = onnx.shape_inference.infer_shapes(onnx.load(str(model)))
    collector = Collector(proto, calibrated_tensors(proto, ["Conv", "Relu", "Concat"]))
    for x in xs:
        collector.add(x)
    ranges = collector.ranges(RangeRule(CalibMethod.PERCENTILE, 99.9))
    (a_low, a_high), (b_low, b_high) = ranges["relu_a"], ranges["relu_b"]
    assert b_high > 2 * a_high  # the second branch is the wider
    assert ranges["joined"] == (min(a_low, b_low), max(a_high, b_high)) == ranges["relu_b"]
    # in the int8 file the wider input's bytes are the Concat's own: onnxruntime copies them
    out = tmp_path / "int8.onnx"
    quantize_onnx_static(model, xs, out, config=QuantConfig(calib_method=CalibMethod.PERCENTILE), progress=False)
    int8 = onnx.load(str(out))
    dq = {n.output[0]: n for n in int8.graph.node if n.op_type == "DequantizeLinear"}
    concat = next(n for n in int8.graph.node if n.op_type == "Concat")
    after = next(n for n in int8.graph.node if n.op_type == "QuantizeLinear" and n.input[0] == concat.output[0])
    shared = [_same_qparams(int8, dq[i].input[1:], after.input[1:]) for i in concat.input]
    assert shared == [False, True]
    assert optimized_ops(out)["QLinearConcat"] == 1


def test_placement_joins_reads_every_concat_input_on_the_concats_own_grid(tmp_path):
    """For OpenVINO (placement joins) each Concat input takes the span too, as NNCF's files have it:
    OpenVINO would requantize an input on another grid in a pass of its own."""
    model = _concat_model(tmp_path / "concat.onnx")
    xs = _inputs(6)
    proto = onnx.shape_inference.infer_shapes(onnx.load(str(model)))
    collector = Collector(proto, calibrated_tensors(proto, ["Conv", "Relu", "Concat"]), shared_concat_inputs=True)
    for x in xs:
        collector.add(x)
    ranges = collector.ranges(RangeRule(CalibMethod.PERCENTILE, 99.9))
    assert ranges["relu_a"] == ranges["relu_b"] == ranges["joined"]
    out = tmp_path / "int8.onnx"
    quantize_onnx_static(model, xs, out, config=QuantConfig(calib_method=CalibMethod.PERCENTILE),
                         options=OnnxOptions(placement="joins"), progress=False)
    int8 = onnx.load(str(out))
    dq = {n.output[0]: n for n in int8.graph.node if n.op_type == "DequantizeLinear"}
    concat = next(n for n in int8.graph.node if n.op_type == "Concat")
    after = next(n for n in int8.graph.node if n.op_type == "QuantizeLinear" and n.input[0] == concat.output[0])
    assert [_same_qparams(int8, dq[i].input[1:], after.input[1:]) for i in concat.input] == [True, True]
    # each Relu reads its conv's float output, nothing between them: OpenVINO fuses it into the conv
    writer = {o: n for n in int8.graph.node for o in n.output}
    assert [writer[n.input[0]].op_type for n in int8.graph.node if n.op_type == "Relu"] == ["Conv", "Conv"]


def _split_model(path):
    """A C2f-like block: a conv's Relu output split in two, one half through another conv and Relu,
    both halves and that joined by a Concat that a 1x1 conv reads."""
    from onnx import helper

    rng = np.random.default_rng(4)
    w1, w2, w3 = rng.normal(0, 1, (4, 2, 1, 1)), rng.normal(0, 3, (2, 2, 1, 1)), rng.normal(0, 0.3, (2, 6, 1, 1))
    nodes = [helper.make_node("Conv", ["input", "w1"], ["a"], name="conv_a"),
             helper.make_node("Relu", ["a"], ["relu_a"], name="relu_a"),
             helper.make_node("Split", ["relu_a", "halves"], ["s0", "s1"], name="split", axis=1),
             helper.make_node("Conv", ["s1", "w2"], ["b"], name="conv_b"),
             helper.make_node("Relu", ["b"], ["relu_b"], name="relu_b"),
             helper.make_node("Concat", ["s0", "s1", "relu_b"], ["joined"], name="concat", axis=1),
             helper.make_node("Conv", ["joined", "w3"], ["output"], name="conv_out")]
    return helper_model(nodes, [("input", [1, 2, 32, 32])], [("output", [1, 2, 32, 32])],
                        {"w1": w1, "w2": w2, "w3": w3, "halves": np.array([2, 2], np.int64)}, path)


def test_placement_joins_runs_a_split_on_the_grid_its_concat_reads(tmp_path):
    """A Split's outputs are its input's bytes: under joins it runs on the int8 grid, and that grid is
    the Concat's its halves join (NNCF's files for OpenVINO: one fake-quant before the Split)."""
    model = _split_model(tmp_path / "split.onnx")
    xs = _inputs(6)
    out = tmp_path / "int8.onnx"
    quantize_onnx_static(model, xs, out, config=QuantConfig(calib_method=CalibMethod.PERCENTILE),
                         options=OnnxOptions(placement="joins"), progress=False)
    int8 = onnx.load(str(out))
    writer = {o: n for n in int8.graph.node for o in n.output}
    split = next(n for n in int8.graph.node if n.op_type == "Split")
    concat = next(n for n in int8.graph.node if n.op_type == "Concat")
    after = next(n for n in int8.graph.node if n.op_type == "QuantizeLinear" and n.input[0] == concat.output[0])
    assert writer[split.input[0]].op_type == "DequantizeLinear"
    assert _same_qparams(int8, writer[split.input[0]].input[1:], after.input[1:])
    assert all(writer[i].op_type == "DequantizeLinear" and _same_qparams(int8, writer[i].input[1:], after.input[1:])
               for i in concat.input)


def test_a_shared_grid_never_reaches_below_what_a_relu_writes():
    """The writer drops a Relu after a quantized op and lets the grid clamp for it; a Concat whose
    shared span would reach below 0 keeps its inputs' own grids, or the dropped Relu would not clamp."""
    from onnx import helper

    nodes = [helper.make_node("Add", ["x", "y"], ["sum"]), helper.make_node("Relu", ["sum"], ["r"]),
             helper.make_node("Concat", ["r", "signed"], ["rs"], axis=1),
             helper.make_node("Relu", ["x"], ["q"]), helper.make_node("Concat", ["r", "q"], ["rq"], axis=1)]
    model = helper.make_model(helper.make_graph(nodes, "g", [], []))
    ranges = {"r": (0.0, 4.0), "q": (0.0, 9.0), "signed": (-2.0, 1.0), "rs": (-2.0, 4.0), "rq": (0.0, 9.0)}
    spans = concat_spans(model, ranges, shared_inputs=True)
    assert spans["r"] == spans["q"] == spans["rq"] == (0.0, 9.0)
    assert spans["signed"] == (-2.0, 1.0) and spans["rs"] == (-2.0, 9.0)


def test_concats_of_concats_share_one_grid_but_a_heads():
    from onnx import helper

    nodes = [helper.make_node("Concat", ["a", "b"], ["ab"], axis=1),
             helper.make_node("Concat", ["ab", "c"], ["abc"], axis=1),
             helper.make_node("Concat", ["a", "d"], ["ad"], axis=1)]
    graph = helper.make_graph(nodes, "g", [], [])
    ranges = {"a": (0.0, 1.0), "b": (-1.0, 2.0), "c": (0.0, 5.0), "d": (-3.0, 0.5), "ab": (0, 0), "abc": (0, 0), "ad": (0, 0)}
    shared = concat_spans(helper.make_model(graph), ranges, shared_inputs=True)
    assert len(set(shared.values())) == 1 and shared["a"] == (-3.0, 5.0)
    alone = concat_spans(helper.make_model(graph), ranges)
    assert alone["ab"] == (-1.0, 2.0) and alone["abc"] == (-1.0, 5.0) and alone["a"] == (0.0, 1.0)
    # a Concat reaching an output through no conv (a detector's head) keeps its inputs' own grids
    head = concat_spans(helper.make_model(graph), ranges, shared_inputs=True, exact={"abc"})
    assert head["c"] == (0.0, 5.0) and head["abc"] == (-3.0, 5.0)
    assert head["a"] == head["b"] == head["ab"] == head["d"] == head["ad"] == (-3.0, 2.0)


def _same_qparams(model, one, other) -> bool:
    from onnx import numpy_helper

    values = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    return all(np.array_equal(values[a], values[b]) for a, b in zip(one, other))
