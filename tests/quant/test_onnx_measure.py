"""first-7 and empirical bias correction on a float ONNX model: the planted models of
test_overflow and test_bias_correction exported by torch, quantized through the ONNX path."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest

from edgepick.errors import ParameterError
from edgepick.quant import PtqMethods, QuantConfig, quantize_onnx_static
from edgepick.quant.onnx.lockstep import runner, segments
from edgepick.quant.onnx.measure import Values, qdq_convs, saturating_onnx_convs
from tests.quant.onnx_models import export_module, image_tensors
from tests.quant.test_bias_correction import Planted, SummedLogits
from tests.quant.test_overflow import Bright

SHAPE = (1, 3, 24, 32)


def _export(net, path):
    return export_module(net, path, SHAPE)


def _tensors(low, count=6):
    return image_tensors(count, SHAPE, low)


def _quant(path):
    return json.loads({p.key: p.value for p in onnx.load(str(path)).metadata_props}["edgepick.quant"])


def _conv_mean(path, conv, tensors):
    """Per-channel mean of the output of the node named CONV in the model at PATH over TENSORS."""
    model = onnx.load(str(path))
    out = next(n for n in model.graph.node if n.name == conv).output[0]
    run = runner(model, [out])
    return np.mean([run(x, [out])[0].mean(axis=(0, 2, 3)) for x in tensors], axis=0)


def test_empirical_correction_removes_a_planted_mean_shift(tmp_path):
    """The correction itself (the pass then keeps it only where the outputs come closer, below)."""
    from edgepick.onnx_graph import copy_model
    from edgepick.quant.onnx.measure import correct_onnx_biases
    from edgepick.quant.onnx.qdq import writes_float_output

    path = _export(Planted(), tmp_path / "f.onnx")
    tensors = _tensors(60)
    target = _conv_mean(path, "/b/Conv", tensors)
    result = quantize_onnx_static(path, tensors, tmp_path / "none.onnx", methods=PtqMethods(bias_correction="none"),
                                  progress=False)
    assert result.int8_convs == 3
    fp32, plain = onnx.load(str(path)), onnx.load(str(tmp_path / "none.onnx"))
    corrected = copy_model(plain)
    correct_onnx_biases(fp32, corrected, tensors, writes_float_output(fp32))
    onnx.save(corrected, str(tmp_path / "empirical.onnx"))
    shift = {m: float(np.abs(_conv_mean(tmp_path / f"{m}.onnx", "/b/Conv", tensors) - target).max())
             for m in ("none", "empirical")}
    assert shift["empirical"] < shift["none"] / 10, shift
    quantize_onnx_static(path, tensors, tmp_path / "pass.onnx", methods=PtqMethods(bias_correction="empirical"),
                         progress=False)
    quant = _quant(tmp_path / "pass.onnx")
    assert quant["bias_correction"] == "empirical" and quant["measured_images"] == len(tensors)
    logits = {m: qdq_convs(onnx.load(str(tmp_path / f"{m}.onnx")))["/logits/Conv"] for m in ("none", "empirical")}
    codes = {m: Values(onnx.load(str(tmp_path / f"{m}.onnx")))[c.bias_codes] for m, c in logits.items()}
    np.testing.assert_array_equal(codes["none"], codes["empirical"])  # the conv writing the float logits is left alone


def test_one_tensor_clipped_hard_does_not_set_the_bias_of_the_others(tmp_path):
    """As on torch graphs (test_bias_correction): calibrated on dark tensors, a white one is clipped
    and its conv outputs fall far below fp32's; the tensors in range keep their planted shift removed."""
    from edgepick.quant.onnx.measure import correct_onnx_biases

    path = _export(Planted(), tmp_path / "f.onnx")
    dark = [t // 2 for t in _tensors(60)]
    typical, white = dark[:5], np.full_like(dark[0], 255.0)
    quantize_onnx_static(path, dark, tmp_path / "q.onnx", methods=PtqMethods(bias_correction="none"), progress=False)
    fp32, model = onnx.load(str(path)), onnx.load(str(tmp_path / "q.onnx"))

    def gaps(tensors):  # per conv, [tensors, channels]: fp32's channel means minus the int8 model's
        means = []
        for m in (fp32, model):
            outs = [next(n for n in m.graph.node if n.name == name).output[0] for name in ("/a/Conv", "/b/Conv")]
            run = runner(m, outs)
            means.append([np.stack([y.mean(axis=(0, 2, 3)) for y in ys]) for ys in zip(*(run(x, outs) for x in tensors))])
        return {name: means[0][i] - means[1][i] for i, name in enumerate(("/a/Conv", "/b/Conv"))}

    before = gaps([*typical, white])
    plant = {k: np.abs(g[:5].mean(0)).max() for k, g in before.items()}
    clipped = {k: np.abs(g[5] - g[:5].mean(0)).max() for k, g in before.items()}
    assert all(clipped[k] / 6 > plant[k] for k in plant), (clipped, plant)  # a mean would leave more than the plant
    assert correct_onnx_biases(fp32, model, [*typical, white], {"/logits/Conv"}) == 2
    after = gaps(typical)
    for k in plant:
        assert np.abs(after[k].mean(0)).max() < plant[k] / 10, (k, plant[k], after[k].mean(0))


def test_the_convs_summed_into_the_logits_are_left_alone(tmp_path):
    from edgepick.onnx_graph import copy_model
    from edgepick.quant.onnx.measure import correct_onnx_biases
    from edgepick.quant.onnx.qdq import writes_float_output

    path = _export(SummedLogits(), tmp_path / "f.onnx")
    quantize_onnx_static(path, _tensors(60), tmp_path / "none.onnx", methods=PtqMethods(bias_correction="none"),
                         progress=False)
    fp32, plain = onnx.load(str(path)), onnx.load(str(tmp_path / "none.onnx"))
    corrected = copy_model(plain)
    correct_onnx_biases(fp32, corrected, _tensors(60), writes_float_output(fp32))
    codes = {m: {name: Values(model)[c.bias_codes] for name, c in qdq_convs(model).items()}
             for m, model in (("none", plain), ("empirical", corrected))}
    assert sorted(codes["none"]) == ["/a/Conv", "/b/Conv", "/logits/Conv", "/low/Conv"]
    changed = {name for name in codes["none"] if not np.array_equal(codes["none"][name], codes["empirical"][name])}
    assert changed == {"/a/Conv", "/b/Conv"}, changed


def test_a_correction_that_brings_the_outputs_no_closer_is_not_kept(tmp_path):
    """The pass keeps empirical bias correction only where the outputs come closer to fp32's on both
    halves of its check tensors; the record says which, and a file whose correction was dropped has
    the uncorrected file's biases (on these two small nets, with these weights, it is dropped)."""
    import torch

    for make, name in ((Planted, "planted"), (SummedLogits, "summed")):
        torch.manual_seed(0)
        path = _export(make(), tmp_path / f"{name}.onnx")
        files = {m: tmp_path / f"{name}-{m}.onnx" for m in ("none", "empirical")}
        for method, out in files.items():
            quantize_onnx_static(path, _tensors(60), out, methods=PtqMethods(bias_correction=method), progress=False)
        record = _quant(files["empirical"])["bias_correction_kept"]
        before, after = record["error_before"], record["error_after"]
        assert record["kept"] == all(a < b for a, b in zip(after, before)) and len(before) == 2
        models = {m: onnx.load(str(f)) for m, f in files.items()}
        same = all(np.array_equal(Values(models["none"])[c.bias_codes], Values(models["empirical"])[c.bias_codes])
                   for c in qdq_convs(models["empirical"]).values())
        assert same != record["kept"], name


def test_convs_are_corrected_in_waves_after_everything_they_read(tmp_path):
    from tests.quant.onnx_models import export_torch

    model = onnx.load(str(export_torch(tmp_path / "f.onnx", opset=13)))
    convs = {n.name: n for n in model.graph.node if n.op_type == "Conv"}
    cut = segments(model, convs)
    waves = [s.wave for s in cut if s.wave]
    assert sorted(sum(waves, [])) == sorted(convs)
    made = {model.graph.input[0].name}
    for s in cut:  # each segment reads only what the segments before it made
        assert set(s.inputs) <= made, set(s.inputs) - made
        made.update(s.outputs)
        made.difference_update(s.last)
    assert not any(n.op_type == "DequantizeLinear" for s in cut for n in s.nodes)  # a float model: none
    wave_of = {name: i for i, wave in enumerate(waves) for name in wave}
    assert wave_of["/c1/Conv"] == 0 and wave_of["/dw/Conv"] == 1
    assert wave_of["/se/fc1/Conv"] < wave_of["/se/fc2/Conv"] < wave_of["/pw/Conv"] < wave_of["/c2/Conv"]


@pytest.mark.slow
def test_first_7_gives_7_bit_weights_only_where_8_bit_ones_saturate(tmp_path):
    path = _export(Bright(), tmp_path / "f.onnx")
    bright = _tensors(240, 3)
    files = {}
    for bits in ("8", "first-7", "7"):
        files[bits] = tmp_path / f"{bits}.onnx"
        quantize_onnx_static(path, bright, files[bits], QuantConfig(weight_bits=bits), progress=False)
    eight = saturating_onnx_convs(onnx.load(str(files["8"])), bright, 32767)
    assert eight["/a/Conv"] > 0.5 and eight["/b/Conv"] == 0.0
    first = onnx.load(str(files["first-7"]))
    assert _quant(files["first-7"])["seven_bit_convs"] == ["/a/Conv"]
    assert all(v == 0.0 for v in saturating_onnx_convs(first, bright, 32767).values())
    codes = {name: Values(first)[c.weight_codes] for name, c in qdq_convs(first).items()}
    assert {name: int(np.abs(c).max()) for name, c in codes.items()} == {"/a/Conv": 64, "/b/Conv": 127}
    seven = onnx.load(str(files["7"]))
    a = qdq_convs(seven)["/a/Conv"]
    np.testing.assert_array_equal(codes["/a/Conv"], Values(seven)[a.weight_codes])  # onnxruntime's own 7-bit grid
    np.testing.assert_allclose(Values(first)[qdq_convs(first)["/a/Conv"].weight_scale], Values(seven)[a.weight_scale])


def test_what_the_onnx_path_cannot_do_is_refused_in_one_line(tmp_path):
    path = _export(Planted(), tmp_path / "f.onnx")
    with pytest.raises(ParameterError, match="bias_correction.*empirical"):
        quantize_onnx_static(path, _tensors(0, 1), tmp_path / "o.onnx", methods=PtqMethods(bias_correction="fast"))
    with pytest.raises(ParameterError, match="adaround_budget_s"):
        quantize_onnx_static(path, _tensors(0, 1), tmp_path / "o.onnx", methods=PtqMethods(adaround=True,
                                                                                       adaround_budget_s=-1))
    assert not (tmp_path / "o.onnx").exists()


def _pooled_chain_model(path):
    """x -> Conv -> Relu -> AveragePool -> Reshape -> Gemm: the writer gives the pool and the Reshape the
    Relu's qparams (one shared scale), so their own ranges must not set it."""
    from onnx import TensorProto, helper, numpy_helper

    rng = np.random.default_rng(0)
    inits = [numpy_helper.from_array(rng.normal(size=(4, 2, 3, 3)).astype(np.float32), "w"),
             numpy_helper.from_array(rng.normal(size=4).astype(np.float32), "b"),
             numpy_helper.from_array(np.array([1, -1], np.int64), "flat"),
             numpy_helper.from_array(rng.normal(size=(3, 64)).astype(np.float32), "fc_w"),
             numpy_helper.from_array(rng.normal(size=3).astype(np.float32), "fc_b")]
    nodes = [helper.make_node("Conv", ["x", "w", "b"], ["conv"], pads=[1, 1, 1, 1], name="conv"),
             helper.make_node("Relu", ["conv"], ["relu"], name="relu"),
             helper.make_node("AveragePool", ["relu"], ["pool"], kernel_shape=[2, 2], strides=[2, 2], name="pool"),
             helper.make_node("Reshape", ["pool", "flat"], ["rows"], name="reshape"),
             helper.make_node("Gemm", ["rows", "fc_w", "fc_b"], ["y"], transB=1, name="fc")]
    graph = helper.make_graph(nodes, "chain", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 2, 8, 8])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3])], inits)
    model = onnx.shape_inference.infer_shapes(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)]))
    onnx.save(model, str(path))
    return path


def _qparams(model):
    values = Values(model)
    return {i.name: values[i.name] for i in model.graph.initializer if i.name.endswith(("_scale", "_zero_point",
                                                                                          "_quantized"))}


def test_requantized_qparams_are_the_writers_own_for_the_same_ranges(tmp_path):
    """calib_method auto measures every rule on one written graph given each rule's qparams: they must be
    the ones the writer computes from the same ranges (a pooled chain's shared scale, the conv's bias codes)."""
    from onnxruntime.quantization.registry import QDQRegistry, QLinearOpsRegistry

    from edgepick.quant.config import Placement
    from edgepick.quant.onnx.measure import adjusted_ranges, requantize_activations
    from edgepick.quant.onnx.qdq import qdq_model
    from edgepick.quant.onnx.static import placement_ops

    path = _pooled_chain_model(tmp_path / "chain.onnx")
    float_model = onnx.load(str(path))
    ops = placement_ops(Placement.ALL, {*QDQRegistry, *QLinearOpsRegistry})
    first = {"x": (-1.0, 1.0), "conv": (-4.0, 4.0), "relu": (0.0, 4.0), "pool": (0.0, 2.0), "rows": (0.0, 2.0),
             "y": (-9.0, 9.0)}
    # the Relu's range below its pool's (a clipping rule such as entropy on a sparse map does that)
    second = {"x": (-2.0, 1.5), "conv": (-3.0, 6.0), "relu": (0.0, 1.5), "pool": (0.0, 3.0), "rows": (0.0, 3.0),
              "y": (-5.0, 7.0)}
    written = qdq_model(path, first, ops, [], False)
    requantize_activations(written, float_model, adjusted_ranges(float_model, second))
    fresh = qdq_model(path, second, ops, [], False)
    got, want = _qparams(written), _qparams(fresh)
    assert set(got) == set(want) and any(k.startswith("relu") for k in want)
    for name in want:
        np.testing.assert_allclose(got[name], want[name], rtol=1e-6, err_msg=name)
